"""Pretraining: a skill is trained, its best policy measured, exported without optimiser state and
registered."""

from __future__ import annotations

import json

import pytest

from itskill.rl.checkpoint import MODEL_FILE, load_policy
from itskill.skills import SkillSpace
from itskill.skills.manifest import read_manifest
from itskill.skills.pretrain import ABANDONED_KEY, PretrainConfig, pretrain


def test_pretrain_registers_a_measured_skill_and_resumes(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    config = PretrainConfig(
        steps=1024, num_envs=8, eval_episodes=6, min_success=0.0, eval_every=512, seeds=1
    )
    runs, library = tmp_path / "runs", tmp_path / "library"
    seen = []
    with SkillSpace() as space:
        entries = pretrain(
            ["reach_nut_m12"], config, runs, library, space, workers=1,
            on_result=lambda task, entry, error: seen.append((task, error)),
        )  # fmt: skip
        assert seen == [("reach_nut_m12", None)]
        skill = space.get("reach_nut_m12")
    (entry,) = entries
    assert entry.steps >= 1024
    assert 0.0 <= entry.success <= 1.0
    assert skill.success_rate == entry.success
    assert skill.description == "Move the gripper to the M12 nut"
    # The library holds weights and metadata only, and they load as a policy.
    files = sorted(p.name for p in (library / "reach_nut_m12").iterdir())
    assert files == ["checkpoint.json", "policy.safetensors"]
    assert MODEL_FILE not in files
    load_policy(library / "reach_nut_m12")
    # What was exported is the policy the run kept as its best evaluated one.
    exported = (library / "reach_nut_m12" / "checkpoint.json").read_text()
    assert exported == (runs / "reach_nut_m12" / "seed0" / "best" / "checkpoint.json").read_text()
    assert json.loads(exported)["selection"]["env_steps"] in (512, 1024)
    assert [e.name for e in read_manifest(library)] == ["reach_nut_m12"]

    # A rerun with the same budget finds the finished checkpoint and trains no further.
    steps_before = json.loads((runs / "reach_nut_m12" / "seed0" / "checkpoint.json").read_text())
    with SkillSpace() as space:
        (again,) = pretrain(["reach_nut_m12"], config, runs, library, space, workers=1)
        assert len(space.list()) == 1
    assert again.steps == steps_before["num_timesteps"]


def test_a_skill_below_min_success_is_reported_but_not_added(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    config = PretrainConfig(steps=1024, num_envs=8, eval_episodes=4, min_success=1.01)
    reported = []
    with SkillSpace() as space:
        added = pretrain(
            ["reach_nut_m12"], config, tmp_path / "runs", tmp_path / "library", space, workers=1,
            on_result=lambda task, entry, error: reported.append(entry),
        )  # fmt: skip
        assert added == [] and space.list() == []
    assert reported[0].name == "reach_nut_m12" and reported[0].steps >= 1024
    assert not (tmp_path / "library" / "reach_nut_m12").exists()


def _steps(run_dir) -> int:
    return json.loads((run_dir / "checkpoint.json").read_text())["num_timesteps"]


def test_a_stalled_run_gives_way_to_the_next_seed_and_a_rerun_replays_it(tmp_path) -> None:
    # Every run counts as stalled (no success exceeds 1.0), so seeds 0 and 1 stop at half the
    # budget and the last seed trains to the full budget whatever it scores.
    config = PretrainConfig(
        steps=1024, num_envs=8, eval_episodes=4, min_success=0.0, eval_every=256,
        seeds=3, restart_success=1.0,
    )  # fmt: skip
    runs, library = tmp_path / "runs", tmp_path / "library"
    (entry,) = pretrain(["reach_nut_m12"], config, runs, library, workers=1)
    assert entry.seed == 2
    assert entry.steps >= 1024
    abandoned = entry.extra[ABANDONED_KEY]
    assert [r["seed"] for r in abandoned] == [0, 1]
    for run in abandoned:
        assert 512 <= run["steps"] < 1024
        assert run["steps"] == _steps(runs / "reach_nut_m12" / f"seed{run['seed']}")
        assert 0.0 <= run["best_success"] <= 1.0
    # The manifest keeps the abandoned runs, so their cost is part of the skill's record.
    (listed,) = read_manifest(library)
    assert listed.seed == 2 and listed.extra[ABANDONED_KEY] == abandoned
    exported = json.loads((library / "reach_nut_m12" / "checkpoint.json").read_text())
    assert exported["seed"] == 2

    # A rerun makes the same decisions from the checkpoints, training nothing further.
    before = {d.name: _steps(d) for d in (runs / "reach_nut_m12").iterdir()}
    (again,) = pretrain(["reach_nut_m12"], config, runs, library, workers=1)
    assert again.seed == 2 and again.extra[ABANDONED_KEY] == abandoned
    assert {d.name: _steps(d) for d in (runs / "reach_nut_m12").iterdir()} == before


def test_a_run_that_scores_keeps_its_seed_and_trains_through_the_check(tmp_path) -> None:
    # No run counts as stalled (every success exceeds -1), so the first seed is the skill's.
    config = PretrainConfig(
        steps=1024, num_envs=8, eval_episodes=4, min_success=0.0, eval_every=256,
        seeds=3, restart_success=-1.0,
    )  # fmt: skip
    runs = tmp_path / "runs"
    (entry,) = pretrain(["reach_nut_m12"], config, runs, tmp_path / "library", workers=1)
    assert entry.seed == 0 and ABANDONED_KEY not in entry.extra
    assert [d.name for d in (runs / "reach_nut_m12").iterdir()] == ["seed0"]
    assert _steps(runs / "reach_nut_m12" / "seed0") == entry.steps >= 1024
    # Its evaluations run on across the check as in one uninterrupted run.
    rows = (runs / "reach_nut_m12" / "seed0" / "eval.csv").read_text().splitlines()[1:]
    steps = [int(r.split(",")[0]) for r in rows]
    assert steps == sorted(set(steps)) and steps[-1] == entry.steps and len(steps) >= 4


def test_pretrain_config_refuses_an_impossible_restart() -> None:
    with pytest.raises(ValueError, match="seeds"):
        PretrainConfig(seeds=0)
    with pytest.raises(ValueError, match="restart_at"):
        PretrainConfig(restart_at=1.0)
