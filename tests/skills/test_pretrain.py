"""Pretraining: a skill is trained, its best policy measured, exported without optimiser state and
registered."""

from __future__ import annotations

import json

from itskill.rl.checkpoint import MODEL_FILE, load_policy
from itskill.skills import SkillSpace
from itskill.skills.manifest import read_manifest
from itskill.skills.pretrain import PretrainConfig, pretrain


def test_pretrain_registers_a_measured_skill_and_resumes(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    config = PretrainConfig(
        steps=1024, num_envs=8, eval_episodes=6, min_success=0.0, eval_every=512
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
    assert exported == (runs / "reach_nut_m12" / "best" / "checkpoint.json").read_text()
    assert json.loads(exported)["selection"]["env_steps"] in (512, 1024)
    assert [e.name for e in read_manifest(library)] == ["reach_nut_m12"]

    # A rerun with the same budget finds the finished checkpoint and trains no further.
    steps_before = json.loads((runs / "reach_nut_m12" / "checkpoint.json").read_text())
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
