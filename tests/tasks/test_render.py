"""Videos of a task: the episodes filmed are those of the spec given."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio

from itskill.tasks import get_task
from itskill.tasks.render import record


def test_a_spec_outside_the_registry_is_filmed_from_its_own_definition(tmp_path: Path) -> None:
    # A spec read from a starts file keeps the task's id but not its start; one of a user's own
    # tasks is not registered at all. The video rebuilt the task by id: the registry's start,
    # or UnknownTaskError.
    spec = replace(get_task("reach_nut_m12"), id="my_reach")
    video = record(spec, "scripted", tmp_path / "v.mp4", width=64, height=48)
    assert video.path.stat().st_size > 0 and video.frames > 0


def test_a_video_larger_than_the_default_offscreen_buffer_is_made_at_its_size(
    tmp_path: Path,
) -> None:
    # The scene's buffer is 640 x 480: a 1280 x 720 video failed at its first frame, with
    # MuJoCo's advice to edit a model XML the scene, built in code, does not have.
    spec = replace(get_task("reach_nut_m12"), max_steps=3)
    video = record(spec, "scripted", tmp_path / "v.mp4", width=1280, height=720)
    assert iio.improps(video.path).shape[1:3] == (720, 1280)
