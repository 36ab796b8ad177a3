"""Videos of a task: the episodes filmed are those of the spec given."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

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


class _Interrupted:
    """A policy stopped by Ctrl-C after a few steps of the rollout."""

    def __init__(self, steps: int) -> None:
        self.steps = steps

    def reset(self, env_ids=None) -> None:
        pass

    def __call__(self, ctx):
        self.steps -= 1
        if self.steps < 0:
            raise KeyboardInterrupt
        return np.zeros((len(ctx["ee_pos"]), 5))


def test_an_interrupted_video_leaves_the_one_before_it_whole(tmp_path: Path) -> None:
    # Written in place, a Ctrl-C left a short clip where the earlier video was (with --force),
    # or a partial file that the rerun then refused to overwrite.
    spec = replace(get_task("reach_nut_m12"), max_steps=3)
    out = tmp_path / "v.mp4"
    before = record(spec, "scripted", out, width=64, height=48)
    kept = out.read_bytes()
    with pytest.raises(KeyboardInterrupt):
        record(spec, lambda spec, n: _Interrupted(5), out, episodes=3, width=64, height=48)
    assert out.read_bytes() == kept and before.frames > 0
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]  # no temporary left behind
