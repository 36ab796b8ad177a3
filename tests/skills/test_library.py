"""The shipped library is registered in a new skill space once, and never forced back."""

from __future__ import annotations

import json
import sqlite3
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from itskill.rl import load_policy
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.skills import ManifestEntry, open_skill_space, read_manifest, write_manifest
from itskill.skills.library import ShippedLibraryWarning, shipped_budgets
from itskill.skills.manifest import REFINED_KEY
from itskill.skills.store import OFFERED_MARKER_SUFFIX
from itskill.skills.store import SHIPPED_LIBRARY as SHIPPED
from itskill.tasks import all_tasks


def _ship(
    shipped: Path,
    tasks: tuple[str, ...],
    success: float = 0.9,
    actions: tuple[str, ...] = ("approach",),
    seed: int = 0,
) -> None:
    """Write a shipped library of ``tasks`` (placeholder weights) with its manifest."""
    entries = []
    for task in tasks:
        (shipped / task).mkdir(parents=True, exist_ok=True)
        (shipped / task / "policy.safetensors").write_bytes(b"weights")
        entries.append(
            ManifestEntry(
                name=task,
                task=task,
                description=f"command of {task}",
                actions=actions,
                checkpoint=f"{task}/policy.safetensors",
                success=success,
                steps=1000,
                algo="ppo",
                seed=seed,
            )
        )
    write_manifest(shipped, entries)


def test_fresh_skill_space_gets_the_shipped_library_once(tmp_path, monkeypatch, home) -> None:
    shipped = tmp_path / "shipped"
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12"))
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)

    with open_skill_space() as space:
        skills = {s.name: s for s in space.list()}
        assert sorted(skills) == ["pick_nut_m12", "reach_nut_m12"]
        assert skills["pick_nut_m12"].success_rate == 0.9
        space.remove("pick_nut_m12")
    # A user's removal sticks: the library is not installed a second time.
    with open_skill_space() as space:
        assert [s.name for s in space.list()] == ["reach_nut_m12"]
    # An upgrade that ships a new skill adds it, and only it.
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12", "grasp_nut_m12"))
    with open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["grasp_nut_m12", "reach_nut_m12"]


def _given_both_removed_pick(tmp_path: Path, monkeypatch) -> tuple[Path, Path]:
    """A space given reach_nut_m12 and pick_nut_m12 whose user removed the pick: the shipped
    library's directory and the database's path."""
    shipped = tmp_path / "shipped"
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12"))
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    with open_skill_space() as space:
        space.remove("pick_nut_m12")
        return shipped, space.path


def test_a_new_database_gets_the_whole_library_again(tmp_path, monkeypatch, home) -> None:
    # What the message on a corrupt database advises (move it aside), or deleting it to start
    # over: the new database used to get nothing, as a file beside it said all was given.
    _, path = _given_both_removed_pick(tmp_path, monkeypatch)
    path.rename(path.with_name("skills.sqlite.bad"))
    # As an older release left it: the marker beside the database it has lost.
    path.with_name(path.name + OFFERED_MARKER_SUFFIX).write_text(
        json.dumps(["pick_nut_m12", "reach_nut_m12"])
    )
    with open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["pick_nut_m12", "reach_nut_m12"]
        space.remove("pick_nut_m12")
    path.unlink()
    with open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["pick_nut_m12", "reach_nut_m12"]


@pytest.mark.parametrize(
    ("damage", "problem"),
    [
        (lambda shipped: (shipped / "manifest.json").write_text("{"), "not valid JSON"),
        (lambda shipped: (shipped / "manifest.json").write_bytes(b"\xff\xfe"), "not UTF-8"),
        (lambda shipped: (shipped / "grasp_nut_m12" / "policy.safetensors").unlink(), "grasp"),
    ],
)
def test_a_damaged_shipped_library_leaves_the_space_usable(
    tmp_path, monkeypatch, home, damage, problem
) -> None:
    shipped = tmp_path / "shipped"
    _ship(shipped, ("reach_nut_m12",))
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    with open_skill_space() as space:
        space.add(replace(space.get("reach_nut_m12"), name="mine"))
    # A release that ships a new skill, installed damaged.
    _ship(shipped, ("reach_nut_m12", "grasp_nut_m12"))
    damage(shipped)
    with pytest.warns(ShippedLibraryWarning, match=problem), open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["mine", "reach_nut_m12"]
    # Mended (reinstalled), the space gets the new skill it was not given.
    _ship(shipped, ("reach_nut_m12", "grasp_nut_m12"))
    with open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["grasp_nut_m12", "mine", "reach_nut_m12"]


def _as_an_older_release_left_it(path: Path, marker: str) -> None:
    """Make the database at ``path`` one of schema version 2, with ``marker`` in the file that
    listed the shipped skills given to it."""
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE shipped_offered")
    conn.execute("PRAGMA user_version = 2")
    conn.commit()
    conn.close()
    path.with_name(path.name + OFFERED_MARKER_SUFFIX).write_text(marker)


def test_an_upgraded_space_keeps_the_removals_its_marker_file_recorded(
    tmp_path, monkeypatch, home
) -> None:
    shipped, path = _given_both_removed_pick(tmp_path, monkeypatch)
    _as_an_older_release_left_it(path, json.dumps(["pick_nut_m12", "reach_nut_m12"]))
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12", "lift_nut_m12"))
    with open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["lift_nut_m12", "reach_nut_m12"]


def test_a_space_marked_by_an_older_release_gets_the_skills_it_lacks(
    tmp_path, monkeypatch, home
) -> None:
    shipped = tmp_path / "shipped"
    _ship(shipped, ("reach_nut_m12",))
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    with open_skill_space() as space:
        path = space.path
    _as_an_older_release_left_it(path, f"{shipped}\n")  # the oldest marker: the library's path
    _ship(shipped, ("reach_nut_m12", "lift_nut_m12"))
    with open_skill_space() as space:
        assert sorted(s.name for s in space.list()) == ["lift_nut_m12", "reach_nut_m12"]
        space.remove("reach_nut_m12")
    with open_skill_space() as space:
        assert [s.name for s in space.list()] == ["lift_nut_m12"]


def test_an_upgrade_that_retrained_a_shipped_skill_updates_its_measurements(
    tmp_path, monkeypatch, home
) -> None:
    shipped = tmp_path / "shipped"
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12"), success=0.5)
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    own = tmp_path / "own.safetensors"
    own.write_bytes(b"weights")
    with open_skill_space() as space:
        assert space.get("reach_nut_m12").success_rate == 0.5
        # The user replaces the shipped pick skill with one of their own.
        mine = space.get("pick_nut_m12")
        space.remove("pick_nut_m12")
        space.add(replace(mine, checkpoint=str(own), success_rate=0.3, id=None))
    # The next release ships retrained weights for both, measured at 96%, from another seed
    # (which the record kept from the old run beside the new measurements).
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12"), success=0.96, seed=3)
    with open_skill_space() as space:
        assert space.get("reach_nut_m12").success_rate == 0.96
        assert space.get("reach_nut_m12").seed == 3
        assert space.get("pick_nut_m12").success_rate == 0.3


def test_an_upgrade_that_changed_a_shipped_skills_actions_updates_them(
    tmp_path, monkeypatch, home
) -> None:
    # Retrieval and the choice of transfer sources read a skill's text and actions: a space kept
    # from an older release must not go on choosing by what that release said.
    shipped = tmp_path / "shipped"
    _ship(shipped, ("place_peg_rect",), actions=("approach", "align"))
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    with open_skill_space() as space:
        assert space.get("place_peg_rect").actions == ("approach", "align")
    _ship(shipped, ("place_peg_rect",), actions=("approach", "place"))
    with open_skill_space() as space:
        skill = space.get("place_peg_rect")
        assert skill.actions == ("approach", "place")
        assert skill.embedding is None  # embedded again from the new text by the next search


def test_shipped_skills_follow_the_package_when_it_is_reinstalled_elsewhere(
    tmp_path, monkeypatch, home
) -> None:
    first = tmp_path / "venv1" / "itskill" / "skills" / "library"
    _ship(first, ("reach_nut_m12", "pick_nut_m12"))
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", first)
    with open_skill_space() as space:
        assert space.get("pick_nut_m12").checkpoint == "package:pick_nut_m12/policy.safetensors"
        # An entry as releases before ``package:`` paths wrote it: the install's absolute path.
        space.set_checkpoint("reach_nut_m12", str(first / "reach_nut_m12/policy.safetensors"))
    # The old install is deleted; itskill now lives in another virtualenv.
    second = tmp_path / "venv2" / "itskill" / "skills" / "library"
    first.rename(tmp_path / "gone")
    _ship(second, ("reach_nut_m12", "pick_nut_m12"), success=0.97)
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", second)
    with open_skill_space() as space:
        for name in ("reach_nut_m12", "pick_nut_m12"):
            skill = space.get(name)
            assert space.checkpoint_path(skill) == second / name / "policy.safetensors"
            assert space.checkpoint_path(skill).is_file()
            assert skill.success_rate == 0.97
    # A new install missing a shipped policy is a damaged one: the space still opens (every
    # command failed, naming the missing file) and the skill keeps the path it had.
    with open_skill_space() as space:
        space.set_checkpoint("reach_nut_m12", str(second / "reach_nut_m12/policy.safetensors"))
    third = tmp_path / "venv3" / "itskill" / "skills" / "library"
    _ship(third, ("reach_nut_m12", "pick_nut_m12"))
    (third / "reach_nut_m12" / "policy.safetensors").unlink()
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", third)
    with open_skill_space() as space:
        kept = space.get("reach_nut_m12").checkpoint
        assert kept == str(second / "reach_nut_m12/policy.safetensors")


def test_pretraining_budgets_are_those_the_shipped_library_records(tmp_path, monkeypatch) -> None:
    shipped = tmp_path / "shipped"
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    assert shipped_budgets() == {}  # no library shipped: every task gets the default
    _ship(shipped, ("reach_nut_m12", "pick_nut_m12"))
    entries = read_manifest(shipped)
    write_manifest(shipped, [replace(entries[0], steps=50_176), replace(entries[1], steps=None)])
    assert shipped_budgets() == {"reach_nut_m12": 50_176}
    # A refined skill is rebuilt from scratch with its first round's budget, then refined.
    refined = replace(entries[1], steps=400_384, extra={REFINED_KEY: {"steps": 300_032}})
    write_manifest(shipped, [replace(entries[0], steps=50_176), refined])
    assert shipped_budgets() == {"reach_nut_m12": 50_176, "pick_nut_m12": 300_032}


def test_every_shipped_skill_loads_and_acts() -> None:
    # A checkpoint whose saved policy description the current code cannot build (a field that
    # was since removed) would only fail when transfer picks it as a source.
    entries = read_manifest(SHIPPED)
    assert len(entries) >= 30, "the package ships fewer than 30 skills"
    tasks = all_tasks()
    for entry in entries:
        # Retrieval embeds the description and actions: they must be the task's own.
        assert entry.description == tasks[entry.task].command, entry.name
        assert tuple(entry.actions) == tasks[entry.task].actions, entry.name
    obs = np.zeros((1, OBSERVATION_LAYOUT.size), dtype=np.float32)
    for entry in entries:
        policy = load_policy((SHIPPED / entry.checkpoint).parent)
        actions, _ = policy.predict(obs, deterministic=True)
        assert actions.shape == (1, 5), entry.name
        assert entry.success is not None and 0.0 <= entry.success <= 1.0, entry.name
