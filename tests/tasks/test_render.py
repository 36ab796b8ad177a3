"""Videos of a task: the episodes filmed are those of the spec given."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from itskill.tasks import get_task
from itskill.tasks.render import record


def test_a_spec_outside_the_registry_is_filmed_from_its_own_definition(tmp_path: Path) -> None:
    # A spec read from a starts file keeps the task's id but not its start; one of a user's own
    # tasks is not registered at all. The video rebuilt the task by id: the registry's start,
    # or UnknownTaskError.
    spec = replace(get_task("reach_nut_m12"), id="my_reach")
    video = record(spec, "scripted", tmp_path / "v.mp4", width=64, height=48)
    assert video.path.stat().st_size > 0 and video.frames > 0
