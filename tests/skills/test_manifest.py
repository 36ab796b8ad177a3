from __future__ import annotations

import json
import multiprocessing
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from itskill.skills import (
    ManifestEntry,
    ManifestError,
    SkillSpace,
    install_library,
    read_manifest,
    update_manifest,
    write_manifest,
)
from itskill.skills.store import SHIPPED_LIBRARY


def entries() -> list[ManifestEntry]:
    return [
        ManifestEntry(
            name="pick_nut_m12",
            task="pick_nut_m12",
            description="Pick up the M12 nut",
            actions=("approach", "grasp", "lift"),
            checkpoint="pick_nut_m12/policy.safetensors",
            success=0.97,
            success_ci=(0.92, 0.99),
            steps=200_000,
            wall_s=900.0,
            algo="ppo",
            seed=0,
        ),
        ManifestEntry(
            name="insert_peg_round",
            task="insert_peg_round",
            description="Insert the round peg into the round hole",
            actions=("insert",),
            checkpoint="sub/insert_peg_round/policy.safetensors",
        ),
    ]


def test_manifest_round_trip(tmp_path):
    path = write_manifest(tmp_path, entries())
    assert json.loads(path.read_text())["format"] == 1
    assert read_manifest(tmp_path) == entries()


def _record_many(library: str, prefix: str, count: int) -> None:
    template = entries()[0]
    for i in range(count):
        update_manifest(library, replace(template, name=f"{prefix}{i}", task=f"{prefix}{i}"))


def test_concurrent_writers_keep_every_entry(tmp_path):
    """Two processes recording skills into one library at once (two pretraining commands)."""
    update_manifest(tmp_path, entries()[1])
    ctx = multiprocessing.get_context("spawn")
    workers = [
        ctx.Process(target=_record_many, args=(str(tmp_path), prefix, 150)) for prefix in "ab"
    ]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=120)
    assert [w.exitcode for w in workers] == [0, 0]
    names = sorted(e.name for e in read_manifest(tmp_path))
    assert names == sorted(["insert_peg_round", *(f"{p}{i}" for p in "ab" for i in range(150))])
    # A name already there is replaced, not repeated.
    update_manifest(tmp_path, replace(entries()[1], success=0.5))
    again = [e for e in read_manifest(tmp_path) if e.name == "insert_peg_round"]
    assert [e.success for e in again] == [0.5]


def test_bad_manifest_names_file(tmp_path):
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(ManifestError, match=r"manifest\.json"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"skills": [{"name": "x"}]}')
    with pytest.raises(ManifestError, match=r"skills\[0\]"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"skills": ["pick_nut_m12"]}')
    with pytest.raises(ManifestError, match=r"skills\[0\].*expected an object"):
        read_manifest(tmp_path)
    # A budget that is not an object was an AttributeError traceback from `skills install`.
    entry = {**entries()[0].to_json(), "budget": 5}
    (tmp_path / "manifest.json").write_text(json.dumps({"skills": [entry]}))
    with pytest.raises(
        ManifestError, match=r"skills\[0\] \(skill 'pick_nut_m12'\): budget: expected"
    ):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"format": "1", "skills": []}')
    with pytest.raises(ManifestError, match="'format' must be a whole number"):
        read_manifest(tmp_path)


@pytest.mark.parametrize(
    ("field", "value", "problem"),
    [
        # A string was read as a list of letters: eight actions, "a → p → p → r → o → ...".
        ("actions", "approach", "actions: a skill needs at least one action"),
        ("actions", [], "actions: a skill needs at least one action"),
        ("actions", ["approach", 3], "actions: expected action names"),
        # Both were stored as they were, a success of 500% and an interval upside down.
        ("success", 5, "success: 5.0 is not a rate in [0, 1]"),
        ("success", "0.9", "success: expected a finite number, got '0.9'"),
        ("success_ci", [0.9, 0.1], "success_ci: low 0.9 is above high 0.1"),
        ("success_ci", [0.1, 1.5], "success_ci: [0.1, 1.5] is not an interval of rates"),
        ("success_ci", [0.1], "success_ci: expected [low, high]"),
        ("budget", {"steps": -1}, "budget.steps: expected a whole number from 0 to"),
        # Past SQLite's integers: an OverflowError traceback when the skill was installed.
        ("seed", 10**23, "seed: expected a whole number from 0 to 9,223,372,036,854,775,807"),
        ("budget", {"steps": 1.5}, "budget.steps: expected a whole number"),
        ("budget", {"wall_s": float("nan")}, "budget.wall_s: expected a finite number"),
        ("seed", True, "seed: expected a whole number"),
        ("algo", 3, "algo: expected a string"),
        ("task", None, "task: expected a string"),
    ],
)
def test_a_field_of_the_wrong_type_or_range_names_the_manifest_skill_and_field(
    tmp_path, field, value, problem
):
    entry = {**entries()[0].to_json(), field: value}
    (tmp_path / "manifest.json").write_text(json.dumps({"skills": [entry]}))
    with pytest.raises(ManifestError) as err:
        read_manifest(tmp_path)
    where = f"{tmp_path / 'manifest.json'}: skills[0] (skill 'pick_nut_m12'): "
    assert str(err.value).startswith(where) and problem in str(err.value)


@pytest.mark.parametrize(
    ("name", "problem"), [("  ", "is blank"), (" pick", "whitespace around it"), (5, "a string")]
)
def test_a_name_no_command_could_look_up_is_refused(tmp_path, name, problem):
    entry = {**entries()[0].to_json(), "name": name}
    (tmp_path / "manifest.json").write_text(json.dumps({"skills": [entry]}))
    with pytest.raises(ManifestError, match=r"skills\[0\]: name: ") as err:
        read_manifest(tmp_path)
    assert problem in str(err.value)


def put_policy(lib: Path, entry: ManifestEntry, task: str | None = None) -> None:
    """A trained policy of ``task`` (default: the entry's) where ``entry`` puts its checkpoint."""
    shutil.copytree(SHIPPED_LIBRARY / (task or entry.task), (lib / entry.checkpoint).parent)


def test_install_requires_every_checkpoint(home, tmp_path):
    lib = tmp_path / "lib"
    pick, insert = entries()
    write_manifest(lib, [pick, insert])
    put_policy(lib, pick)
    with SkillSpace() as space:
        with pytest.raises(ManifestError, match=r"insert_peg_round/policy\.safetensors"):
            install_library(space, lib)
        assert len(space) == 0  # All or nothing.
        put_policy(lib, insert)
        added = install_library(space, lib)
        assert [s.name for s in added] == ["pick_nut_m12", "insert_peg_round"]
        pick = space.get("pick_nut_m12")
        assert (pick.success_ci, pick.train_steps, pick.algo) == ((0.92, 0.99), 200_000, "ppo")
        # Outside the home: absolute.
        assert pick.checkpoint == str(lib / "pick_nut_m12" / "policy.safetensors")
        assert install_library(space, lib) == []  # A second install adds nothing.


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"task": "no_such_task"}, "unknown task 'no_such_task'"),
        ({"actions": ()}, "needs at least one action"),
        ({"actions": (" ",)}, "needs at least one action"),
        ({"policy_of": "reach_nut_m12"}, "trained on task 'reach_nut_m12', not 'pick_nut_m12'"),
        ({"truncate": True}, "corrupt policy weights"),
    ],
)
def test_install_refuses_what_skills_add_refuses(home, tmp_path, change, problem):
    # Each was installed and failed only at the skill's first use as a transfer source.
    lib = tmp_path / "lib"
    pick, insert = entries()
    put_policy(lib, insert)
    put_policy(lib, pick, change.pop("policy_of", None))
    if change.pop("truncate", False):
        weights = lib / pick.checkpoint
        weights.write_bytes(weights.read_bytes()[:1000])
    write_manifest(lib, [insert, replace(pick, **change)])
    with SkillSpace() as space:
        with pytest.raises(ManifestError, match="skill 'pick_nut_m12'") as err:
            install_library(space, lib)
        assert problem in str(err.value)
        assert len(space) == 0  # the good entry is not installed either


def test_own_library_is_stored_relative(home):
    with SkillSpace() as space:
        pick = entries()[0]
        write_manifest(space.library_dir, [pick])
        put_policy(space.library_dir, pick)
        (skill,) = install_library(space, space.library_dir)
        assert skill.checkpoint == "pick_nut_m12/policy.safetensors"
        assert space.checkpoint_path(skill).is_file()


def test_a_library_that_is_not_there_is_said_so(tmp_path):
    with pytest.raises(ManifestError, match="nonexist: no such directory"):
        read_manifest(tmp_path / "nonexist")
    with pytest.raises(ManifestError, match="no manifest"):
        read_manifest(tmp_path)
