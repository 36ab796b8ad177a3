"""Training runs: resume continues the step count, checkpoints load or fail clearly, CLI works."""

from __future__ import annotations

import csv
import importlib
import io
import json
import os
import signal
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from rich.console import Console
from stable_baselines3.common.save_util import load_from_zip_file
from typer.testing import CliRunner

from itskill.cli import app
from itskill.curves import EVAL_SEED
from itskill.rl import eval_callback
from itskill.rl.checkpoint import as_policy, best_policy_dir, load_policy
from itskill.rl.config import HyperparamError
from itskill.rl.logger import LoggerConfig, read_metrics
from itskill.rl.train import (
    ResumeMismatchError,
    RewardLoadError,
    RewardSource,
    ScheduleWarning,
    train,
)
from itskill.sim.layout import OBSERVATION_VERSION
from itskill.tasks import get_task
from itskill.tasks.evaluate import CheckpointError, EvalResult, RandomPolicy, evaluate

# The package re-exports the function ``train`` under the module's name.
train_module = importlib.import_module("itskill.rl.train")
FAST_PPO = {"n_steps": 16, "batch_size": 64, "n_epochs": 2}
QUIET = LoggerConfig(progress=False, tensorboard=False, min_steps_per_row=1)
TASK = "reach_nut_m12"


def _train(
    out: Path, reward: Path, steps: int, algo: str = "ppo", overrides: dict | None = None, **kw
):
    fast = FAST_PPO if algo == "ppo" else {"n_steps": 4}
    return train(
        TASK, algo, steps, seed=1, reward=reward, out=out, num_envs=4,
        overrides={**fast, **(overrides or {})}, logger=QUIET, **kw,
    )  # fmt: skip


def test_resume_continues_step_count(tmp_path: Path, reach_reward: Path) -> None:
    out = tmp_path / "run"
    first = _train(out, reach_reward, 128)
    assert first.num_timesteps == 128 and first.resumed_from == 0
    weights = load_policy(out).state_dict()
    # Its learning rate decayed linearly to 0 at 128: at 256 it jumps back, said.
    with pytest.warns(ScheduleWarning, match="to 0 at its budget, 128 env-steps until now: "
                      "with --steps 256 it goes on at"):  # fmt: skip
        second = _train(out, reach_reward, 256)
    assert second.resumed_from == 128 and second.num_timesteps == 256
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["num_timesteps"] == 256 and meta["task"] == TASK and meta["algo"] == "ppo"
    steps = [row["step"] for row in read_metrics(out)]
    assert steps == sorted(set(steps)) and steps[-1] == 256
    assert any(s <= 128 for s in steps) and any(s > 128 for s in steps)
    rows = (out / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("step,") and "close" in rows[0] and len(rows) == len(steps) + 1
    resumed = load_policy(out).state_dict()
    assert not torch.equal(weights["action_net.weight"], resumed["action_net.weight"])
    # The reward scale is saved with the checkpoint, and a resumed run starts from it.
    stats = json.loads((out / "reward_norm.json").read_text())
    assert stats["count"] > 256 and stats["var"] > 0
    # The training wall time adds up over sessions, and the checkpoint records it.
    assert first.wall_s == pytest.approx(first.session_wall_s, abs=0.01) and first.wall_s > 0
    assert second.wall_s == meta["train_wall_s"]
    assert second.wall_s == pytest.approx(first.wall_s + second.session_wall_s, abs=0.02)
    # The target reached: nothing left to do, and the run's time is reported as it was.
    done = _train(out, reach_reward, 256)
    assert done.num_timesteps == 256 and done.session_wall_s == 0.0
    assert done.wall_s == second.wall_s
    # A smaller budget would have stopped at 128: its figures cannot be read off this run.
    with pytest.raises(ResumeMismatchError, match="trained to 256 env-steps, past the 128"):
        _train(out, reach_reward, 128)
    # One the last rollout passed (it stops at the first rollout at or over its budget) is done.
    assert _train(out, reach_reward, 200).num_timesteps == 256
    # Without the reward scale a resume started from fresh statistics, rescaling every reward;
    # a finished run, which trains on no reward, is read as it is.
    (out / "reward_norm.json").unlink()
    assert _train(out, reach_reward, 256).num_timesteps == 256
    with pytest.raises(CheckpointError, match=r"reward_norm\.json: missing: the run normalises"):
        _train(out, reach_reward, 384)


def test_progress_bar_counts_to_where_training_stops(tmp_path: Path, reach_reward: Path) -> None:
    # Whole rollouts of 4 environments x 16 steps: a budget of 1 trains 64 steps, and the bar
    # says 64/64, not 64/1.
    out = io.StringIO()
    console = Console(file=out, width=200)
    shown = LoggerConfig(progress=True, tensorboard=False, min_steps_per_row=1)
    result = train(
        TASK, "ppo", 1, seed=1, reward=reach_reward, out=tmp_path / "run", num_envs=4,
        overrides=FAST_PPO, logger=shown, console=console,
    )  # fmt: skip
    assert result.num_timesteps == 64
    assert "64/64" in out.getvalue() and "/1 " not in out.getvalue(), out.getvalue()


def test_training_leaves_nothing_in_the_temporary_directory(
    tmp_path: Path, reach_reward: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Stable-Baselines3 made an empty SB3-<time> folder there on every run: hundreds in /tmp.
    import tempfile

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    _train(tmp_path / "run", reach_reward, 64)
    assert not [p.name for p in scratch.iterdir() if p.name.startswith("SB3-")]


def test_a_run_resumed_from_an_older_evaluation_file_keeps_its_columns(
    tmp_path: Path, reach_reward: Path
) -> None:
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    path = out / "eval.csv"
    lines = path.read_text().splitlines()
    assert lines[0].endswith(",mean_length,stages_done") and len(lines) == 3
    # Written before subtask progress was recorded: one column fewer.
    path.write_text("".join(line.rsplit(",", 1)[0] + "\n" for line in lines))
    _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    rows = [line.split(",") for line in path.read_text().splitlines()]
    assert rows[0][-1] == "mean_length" and len(rows) == 5
    assert {len(r) for r in rows} == {6}


def test_the_best_evaluated_policy_is_kept_across_a_resume(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    """best/ holds the weights of the highest evaluation (then most subtasks, later on a tie),
    and a resumed run only replaces it with one that matches or beats it."""
    scores = iter(
        [
            *[(0.25, 0.5), (0.75, 0.8), (0.75, 0.8), (0.5, 0.9)],  # the first session
            *[(0.5, 1.0), (0.5, 0.9)],  # the second: below the earlier best, which stays
            (0.75, 0.9),  # the third: as successful, more subtasks: it replaces it
        ]
    )
    evaluated: list[torch.Tensor] = []  # the weights each evaluation saw, every 64 env-steps

    def fake_evaluate(spec, actor, episodes, seed, num_envs):
        success, stages = next(scores)
        evaluated.append(actor.policy.action_net.weight.detach().clone())
        return EvalResult(
            spec.id, episodes, 0, success, 0.0, 1.0, 10.0, 0.0, "live",
            stages * len(spec.stages), len(spec.stages), [10.0] + [0.0] * (len(spec.stages) - 1),
        )  # fmt: skip

    monkeypatch.setattr(eval_callback, "evaluate", fake_evaluate)
    out = tmp_path / "run"
    first = _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert best_policy_dir(out) == out / "best" and not (out / "best" / "model.zip").exists()
    assert first.best is not None and first.best["env_steps"] == 192
    assert first.best["success"] == 0.75 and first.best["episodes"] == 2
    assert torch.equal(load_policy(out / "best").action_net.weight, evaluated[2])
    # Evaluations fall between updates: the last one saw the weights the run ended with.
    assert torch.equal(load_policy(out).action_net.weight, evaluated[3])
    assert not torch.equal(evaluated[1], evaluated[2])

    second = _train(out, reach_reward, 384, eval_every=64, eval_episodes=2)
    assert second.best is not None and second.best["env_steps"] == 192
    assert torch.equal(load_policy(out / "best").action_net.weight, evaluated[2])
    third = _train(out, reach_reward, 448, eval_every=64, eval_episodes=2)
    assert third.best is not None and third.best["env_steps"] == 448
    assert torch.equal(load_policy(out / "best").action_net.weight, evaluated[6])


@pytest.mark.parametrize("selection", [{"env_steps": 64}, {"env_steps": 64, "success": "0.5"}])
def test_a_run_whose_best_record_lost_its_score_resumes_and_evaluates_anew(
    tmp_path: Path, reach_reward: Path, selection: dict
) -> None:
    # It stopped with a KeyError before its first update; the next evaluation writes a new one.
    out = tmp_path / "run"
    _train(out, reach_reward, 64, eval_every=64, eval_episodes=2)
    path = out / "best" / "checkpoint.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "selection": selection}))
    result = _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    assert result.num_timesteps == 128
    assert result.best is not None and result.best["env_steps"] == 128


def _record_evaluation_seeds(monkeypatch) -> list[int]:
    """Seeds the evaluation callback draws its episodes from, in order (the evaluation itself
    runs as usual)."""
    seeds: list[int] = []
    real = eval_callback.evaluate

    def recording(spec, actor, episodes, seed, num_envs):
        seeds.append(seed)
        return real(spec, actor, episodes, seed, num_envs=num_envs)

    monkeypatch.setattr(eval_callback, "evaluate", recording)
    return seeds


def test_each_training_seed_is_evaluated_on_its_own_episodes(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    """Seeds average over as many episode samples as there are seeds; one seed's runs share
    theirs (whatever the method or reward), and keep them across a resume."""
    seeds = _record_evaluation_seeds(monkeypatch)
    for seed in (0, 3):
        train(
            TASK, "ppo", 128, seed=seed, reward=reach_reward, out=tmp_path / f"seed{seed}",
            num_envs=4, overrides=FAST_PPO, logger=QUIET, eval_every=64, eval_episodes=2,
        )  # fmt: skip
    assert seeds == [EVAL_SEED] * 2 + [EVAL_SEED + 3] * 2
    meta = json.loads((tmp_path / "seed3" / "checkpoint.json").read_text())
    assert meta["evaluation"] == {"every": 64, "episodes": 2, "seed": EVAL_SEED + 3}
    best = json.loads((tmp_path / "seed3" / "best" / "checkpoint.json").read_text())
    assert best["selection"]["seed"] == EVAL_SEED + 3


def test_a_run_from_before_evaluation_seeds_resumes_on_its_old_episodes(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    """Runs recorded no evaluation seed while every training seed used EVAL_SEED: a resumed
    one stays on those episodes, so its curve compares its policies on one set."""
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    path = out / "checkpoint.json"
    meta = json.loads(path.read_text())
    assert meta["evaluation"].pop("seed") == EVAL_SEED + 1
    path.write_text(json.dumps(meta))
    seeds = _record_evaluation_seeds(monkeypatch)
    _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert seeds == [EVAL_SEED] * 2
    assert json.loads(path.read_text())["evaluation"]["seed"] == EVAL_SEED


def test_the_learning_curves_clock_goes_on_across_a_resume_without_the_evaluations(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Reports read env-steps and wall time to 80% off eval.csv: a resumed run must not restart
    # its clock (it undercounted the time trained before the interruption).
    def slow_evaluate(spec, actor, episodes, seed, num_envs):
        time.sleep(0.5)
        return EvalResult(
            spec.id, episodes, 0, 0.5, 0.0, 1.0, 10.0, 0.0, "live",
            0.0, len(spec.stages), [10.0] + [0.0] * (len(spec.stages) - 1),
        )  # fmt: skip

    monkeypatch.setattr(eval_callback, "evaluate", slow_evaluate)
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    with open(out / "eval.csv", newline="") as fh:
        rows = [(int(r["env_steps"]), float(r["wall_s"])) for r in csv.DictReader(fh)]
    assert [step for step, _ in rows] == [64, 128, 192, 256]
    walls = [wall for _, wall in rows]
    assert walls == sorted(walls) and walls[2] > walls[1]
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["eval_wall_s"] >= 4 * 0.5
    assert walls[-1] <= meta["train_wall_s"] - meta["eval_wall_s"] + 0.01
    # metrics.csv keeps the same clock: its rows after the resume go on from the first session's.
    metric_walls = [row["wall_s"] for row in read_metrics(out)]
    assert metric_walls == sorted(metric_walls)
    assert metric_walls[-1] <= meta["train_wall_s"] - meta["eval_wall_s"] + 0.01


def test_a_run_with_the_largest_seed_resumes(tmp_path: Path, reach_reward: Path) -> None:
    # The resumed session's random state is drawn from the seed and the steps done: their sum
    # passed the 2**32 numpy accepts, so such a run trained once and never resumed.
    out = tmp_path / "run"
    kw = {"num_envs": 2, "overrides": FAST_PPO, "logger": QUIET, "reward": reach_reward}
    train(TASK, "ppo", 32, seed=2**32 - 1, out=out, **kw)
    assert train(TASK, "ppo", 64, seed=2**32 - 1, out=out, **kw).resumed_from == 32


@pytest.mark.parametrize("bad", [{"eval_every": 0}, {"eval_every": -5}, {"eval_episodes": 0}])
def test_evaluation_settings_below_one_are_refused_before_training(
    tmp_path: Path, reach_reward: Path, bad: dict
) -> None:
    # The checkpoint would record settings its reader refuses: a run nothing could resume.
    with pytest.raises(ValueError, match="must be at least 1"):
        _train(tmp_path / "run", reach_reward, 64, **{"eval_every": 32, **bad})
    assert not (tmp_path / "run").exists()


def test_a_run_whose_evaluation_file_was_emptied_resumes(
    tmp_path: Path, reach_reward: Path
) -> None:
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    (out / "eval.csv").write_text("")
    _train(out, reach_reward, 192, eval_every=64, eval_episodes=2)
    # The header is written again, and the policy at the checkpoint evaluated again.
    lines = (out / "eval.csv").read_text().splitlines()
    assert lines[0].startswith("env_steps,")
    assert [line.split(",")[0] for line in lines[1:]] == ["128", "192"]


def test_resume_refuses_other_evaluation_settings(tmp_path: Path, reach_reward: Path) -> None:
    out = tmp_path / "run"
    _train(out, reach_reward, 64, eval_every=64, eval_episodes=2)
    before = (out / "eval.csv").read_text()
    with pytest.raises(ResumeMismatchError, match=r"over 2 episodes.*every 64 over 3"):
        _train(out, reach_reward, 128, eval_every=64, eval_episodes=3)
    with pytest.raises(ResumeMismatchError, match="every 32 over 2"):
        _train(out, reach_reward, 128, eval_every=32, eval_episodes=2)
    assert (out / "eval.csv").read_text() == before
    # A session without evaluations adds no rows and keeps the record for the next one, and
    # says that best/ no longer follows the training.
    told = io.StringIO()
    train(
        TASK, "ppo", 128, seed=1, reward=reach_reward, out=out, num_envs=4, overrides=FAST_PPO,
        logger=replace(QUIET, progress=True), console=Console(file=told, width=400),
    )  # fmt: skip
    assert (out / "eval.csv").read_text() == before
    assert (
        "this session adds no evaluations, so best/ stays the policy its evaluations to 64 "
        "env-steps chose; resume with --eval-every 64 --eval-episodes 2" in told.getvalue()
    )
    with pytest.raises(ResumeMismatchError, match="every 64 over 3"):
        _train(out, reach_reward, 192, eval_every=64, eval_episodes=3)
    result = _train(out, reach_reward, 192, eval_every=64, eval_episodes=2)
    assert result.num_timesteps == 192
    steps = [line.split(",")[0] for line in (out / "eval.csv").read_text().splitlines()[1:]]
    # The policy trained without evaluations is evaluated where the session resumed from.
    assert steps == ["64", "128", "192"]


def test_a_run_without_evaluations_keeps_no_best_policy(tmp_path: Path, reach_reward: Path) -> None:
    out = tmp_path / "run"
    result = _train(out, reach_reward, 64)
    assert result.best is None and best_policy_dir(out) == out


def test_resume_refuses_other_settings(tmp_path: Path, reach_reward: Path) -> None:
    out = tmp_path / "run"
    _train(out, reach_reward, 64, algo="a2c")
    with pytest.raises(ResumeMismatchError, match="algo"):
        _train(out, reach_reward, 128, algo="ppo")
    # Loading the model kept the old rate and rollout length while the checkpoint recorded the
    # new ones; now the run says so.
    with pytest.raises(ResumeMismatchError, match=r"a2c\.n_steps: 4 -> 8"):
        train(
            TASK, "a2c", 128, seed=1, reward=reach_reward, out=out, num_envs=4,
            overrides={"n_steps": 8}, logger=QUIET,
        )  # fmt: skip
    with pytest.raises(ResumeMismatchError, match="num_envs: 4 -> 2"):
        train(
            TASK, "a2c", 128, seed=1, reward=reach_reward, out=out, num_envs=2,
            overrides={"n_steps": 4}, logger=QUIET,
        )  # fmt: skip


def test_a_resumed_run_draws_fresh_initial_states(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Stable-Baselines3 seeds the environments with the run's seed when it builds or loads the
    # model: each session must then reseed them with its own.
    from itskill.sim.vec_env import BatchEnv

    seeds: list[int | None] = []
    original = BatchEnv.seed

    def record(self, seed=None):
        seeds.append(seed)
        return original(self, seed)

    monkeypatch.setattr(BatchEnv, "seed", record)
    out = tmp_path / "run"
    _train(out, reach_reward, 64)
    fresh = seeds[-1]
    _train(out, reach_reward, 128)
    resumed = seeds[-1]
    assert len({fresh, resumed, 1}) == 3  # neither the run's seed nor each other's


def test_callable_reward_is_recorded_and_guards_resume(tmp_path: Path, reach_reward: Path) -> None:
    calls = []

    def compute_reward(ctx):
        calls.append(len(ctx["ee_pos"]))
        close = np.exp(-np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1) / 0.05)
        return close, {"close": close}

    out = tmp_path / "run"
    source = RewardSource(compute_reward, {"kind": "generated", "sha256": "a" * 64})
    _train(out, source, 64)  # type: ignore[arg-type]
    assert calls and set(calls) == {4}
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["reward"] == {"kind": "generated", "sha256": "a" * 64}
    assert meta["policy_class"].endswith("StagedActorCriticPolicy")
    assert "close" in (out / "metrics.csv").read_text().splitlines()[0]
    other = RewardSource(compute_reward, {"kind": "generated", "sha256": "b" * 64})
    with pytest.raises(ResumeMismatchError, match="reward"):
        _train(out, other, 128)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="sha256"):
        RewardSource(compute_reward, {"kind": "generated"})


def test_interrupt_saves_checkpoint(tmp_path: Path, reach_reward: Path, monkeypatch) -> None:
    from itskill.rl import logger

    calls = {"n": 0}
    original = logger.MetricsCallback._on_step

    def interrupting(self):
        calls["n"] += 1
        if calls["n"] == 40:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(logger.MetricsCallback, "_on_step", interrupting)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        _train(out, reach_reward, 10_000)
    # Ctrl-C at env-step 160, in the third rollout of 64 (16 steps x 4 environments): the
    # checkpoint counts the two rollouts the weights learned from.
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["num_timesteps"] == 128
    monkeypatch.undo()
    done = _train(out, reach_reward, 256)
    assert done.resumed_from == 128 and done.num_timesteps == 256
    assert [row["step"] for row in read_metrics(out)][-1] == 256


def test_ctrl_c_as_the_last_metrics_row_is_written_keeps_the_finished_run_finished(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # The checkpoint was saved at the last rollout's start, and the resumed run learned that
    # rollout a second time.
    from itskill.rl import logger

    def interrupting(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(logger.MetricsCallback, "_on_training_end", interrupting)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        _train(out, reach_reward, 128)
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 128
    monkeypatch.undo()
    done = _train(out, reach_reward, 128)
    assert done.num_timesteps == 128 and done.session_wall_s == 0.0


def test_an_update_cut_short_leaves_its_rollout_uncounted(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    from stable_baselines3 import PPO

    calls = {"n": 0}
    original = PPO.train

    def interrupting(self):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(PPO, "train", interrupting)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        _train(out, reach_reward, 10_000)
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 64
    monkeypatch.undo()
    assert _train(out, reach_reward, 192).num_timesteps == 192


def test_an_expert_run_resumes_only_under_the_expert_reward_it_trained_with(
    tmp_path: Path,
) -> None:
    # Both sides recorded {"kind": "expert"} alone: a run resumed after the reward's terms or
    # the task's stages changed went on under the new reward without a word.
    out = tmp_path / "run"
    _train(out, "expert", 64)
    record = json.loads((out / "checkpoint.json").read_text())
    assert len(record["reward"]["sha256"]) == 64
    record["reward"]["sha256"] = "0" * 64  # as a run of another version of the reward records
    (out / "checkpoint.json").write_text(json.dumps(record))
    with pytest.raises(ResumeMismatchError, match="expert reward as it was then"):
        _train(out, "expert", 128)
    del record["reward"]["sha256"]  # a run from before the fingerprint: taken as it was
    (out / "checkpoint.json").write_text(json.dumps(record))
    assert _train(out, "expert", 128).num_timesteps == 128


def test_a_run_resumes_only_on_the_task_as_it_trained_on_it(
    tmp_path: Path, reach_reward: Path
) -> None:
    # A reward file's fingerprint does not cover the task: a run resumed after its stages
    # changed (the peg's place stage, 2026-12-07) saw another stage one-hot without a word.
    out = tmp_path / "run"
    _train(out, reach_reward, 64)
    record = json.loads((out / "checkpoint.json").read_text())
    assert record["task_sha256"] == get_task(record["task"]).fingerprint
    record["task_sha256"] = "0" * 64  # as a run of the task's earlier file records
    (out / "checkpoint.json").write_text(json.dumps(record))
    with pytest.raises(ResumeMismatchError, match="as the task was then"):
        _train(out, reach_reward, 128)
    del record["task_sha256"]  # a run from before the fingerprint: taken as it was
    (out / "checkpoint.json").write_text(json.dumps(record))
    assert _train(out, reach_reward, 128).num_timesteps == 128
    # and left without one: its first steps were taken on a task of unknown version.
    assert "task_sha256" not in json.loads((out / "checkpoint.json").read_text())


def test_a_resume_ignores_settings_of_tables_the_run_never_used(
    tmp_path: Path, reach_reward: Path
) -> None:
    # A release retuning the starting policy's or the warm start's settings stopped every run
    # that used neither.
    out = tmp_path / "run"
    _train(out, reach_reward, 64, overrides={"demos": {"episodes": 0}})
    unused = {"demos": {"episodes": 0, "epochs": 7}, "init": {"learning_rate": 5e-5}}
    assert _train(out, reach_reward, 128, overrides=unused).num_timesteps == 128
    with pytest.raises(ResumeMismatchError, match=r"policy\.log_std_init"):
        _train(out, reach_reward, 192, overrides={"policy": {"log_std_init": -2.5}})


def test_ctrl_c_during_an_update_saves_the_update_whole_with_its_rollout_counted(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # The checkpoint counted the steps before the rollout while its weights had learned from it
    # (in part or whole): the resumed run learned that rollout again.
    from stable_baselines3 import PPO

    calls, learned = {"n": 0}, {}
    original = PPO.train

    def interrupted(self):
        calls["n"] += 1
        if calls["n"] == 2:
            os.kill(os.getpid(), signal.SIGINT)  # arrives while the update runs
        original(self)
        learned.update({k: v.clone() for k, v in self.policy.state_dict().items()})

    monkeypatch.setattr(PPO, "train", interrupted)
    out = tmp_path / "run"
    # Python's own handler, as a terminal's process has: pytest-xdist's workers ignore SIGINT.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            # A periodic checkpoint at 64 too: saved while the update's wrapper is in place.
            _train(out, reach_reward, 10_000, overrides={"checkpoint_every": 64})
    finally:
        signal.signal(signal.SIGINT, previous)
    assert calls["n"] == 2
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 128
    saved = load_from_zip_file(out / "model.zip")[1]["policy"]
    assert all(torch.equal(saved[k], v) for k, v in learned.items())


def test_an_evaluation_is_labelled_with_the_steps_its_policy_learned_from(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Rollouts of 64 env-steps, evaluations due every 100: each is taken between updates, at
    # the last one before its step (the row at 100 held the policy of 64 env-steps), so that a
    # curve has a row by each due step (Table II reads the success at 20% of the budget).
    fake, _ = _scripted_evaluate(iter([0.5] * 10))
    monkeypatch.setattr(eval_callback, "evaluate", fake)
    out = tmp_path / "run"
    _train(out, reach_reward, 256, eval_every=100, eval_episodes=2)
    assert _eval_steps(out) == [64, 192, 256]


def test_a_run_evaluated_in_the_middle_of_rollouts_resumes_without_a_gap(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Releases before 2026-12-06 labelled a row with the step it fell due at, mid-rollout: such
    # a row covers that step only, not the rest of the rollout after it.
    fake, _ = _scripted_evaluate(iter([0.5] * 20))
    monkeypatch.setattr(eval_callback, "evaluate", fake)
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=50, eval_episodes=2)
    rows = (out / "eval.csv").read_text().splitlines()
    old = [
        rows[0],
        *(f"{step},{r.split(',', 1)[1]}" for step, r in zip((50, 100), rows[1:3], strict=True)),
    ]
    (out / "eval.csv").write_text("\n".join(old) + "\n")
    _train(out, reach_reward, 256, eval_every=50, eval_episodes=2)
    assert _eval_steps(out) == [50, 100, 128, 192, 256]


def test_ctrl_c_before_a_resumed_sessions_first_rollout_keeps_its_steps(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Cut short while the session's logging starts, the checkpoint was saved at 0 env-steps and
    # the resumed run then dropped the first session's curve.
    from itskill.rl import logger

    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    original = logger.MetricsCallback._on_training_start

    def interrupting(self):
        original(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(logger.MetricsCallback, "_on_training_start", interrupting)
    with pytest.raises(KeyboardInterrupt):
        _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 128
    monkeypatch.undo()
    done = _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert done.resumed_from == 128 and _eval_steps(out) == [64, 128, 192, 256]


def test_missing_and_corrupt_checkpoints(tmp_path: Path, reach_reward: Path) -> None:
    with pytest.raises(CheckpointError, match="no such checkpoint directory") as info:
        load_policy(tmp_path / "nowhere")
    assert str(tmp_path / "nowhere") in str(info.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(CheckpointError, match=r"checkpoint\.json: missing"):
        load_policy(tmp_path / "empty")

    out = tmp_path / "run"
    _train(out, reach_reward, 64)
    policy_file = out / "policy.safetensors"
    good = policy_file.read_bytes()
    policy_file.write_bytes(good[:100])
    with pytest.raises(CheckpointError, match="corrupt policy weights") as info:
        load_policy(out)
    assert str(policy_file) in str(info.value)
    policy_file.unlink()
    with pytest.raises(CheckpointError, match="missing policy weights"):
        load_policy(out)
    policy_file.write_bytes(good)
    meta_file = out / "checkpoint.json"
    meta = meta_file.read_text()
    meta_file.write_text(meta[:20])
    with pytest.raises(CheckpointError, match="not valid JSON"):
        load_policy(out)
    # Resuming from it says what to do instead.
    with pytest.raises(CheckpointError, match=r"not valid JSON.*train into another run directory"):
        _train(out, reach_reward, 128)
    meta_file.write_text(meta)
    model = (out / "model.zip").read_bytes()
    (out / "model.zip").unlink()
    with pytest.raises(CheckpointError, match=r"model\.zip: missing; the run cannot be resumed"):
        _train(out, reach_reward, 128)
    (out / "model.zip").write_bytes(model)
    data = json.loads(meta)
    data["policy"]["stages"] = [64, 64, 64]
    meta_file.write_text(json.dumps(data))
    with pytest.raises(CheckpointError, match="do not fit"):
        load_policy(out)
    meta_file.write_text(meta)
    assert load_policy(out).obs_norm.count.item() > 0
    # Trained on what a slice held before: refused, where its size alone matched.
    assert data["obs_version"] == OBSERVATION_VERSION
    meta_file.write_text(json.dumps({**json.loads(meta), "obs_version": OBSERVATION_VERSION - 1}))
    with pytest.raises(CheckpointError, match="observation layout version 1, this release"):
        load_policy(out)
    with pytest.raises(CheckpointError, match="observation layout version 1"):
        _train(out, reach_reward, 128)
    # Written before the version was recorded: loads as before.
    meta_file.write_text(
        json.dumps({k: v for k, v in json.loads(meta).items() if k != "obs_version"})
    )
    assert load_policy(out).obs_norm.count.item() > 0


def test_bad_reward_file(tmp_path: Path) -> None:
    bad = tmp_path / "r.py"
    bad.write_text("x = 1\n")
    with pytest.raises(RewardLoadError, match="compute_reward"):
        _train(tmp_path / "run", bad, 64)
    with pytest.raises(RewardLoadError, match="no such reward file"):
        _train(tmp_path / "run", tmp_path / "absent.py", 64)
    with pytest.raises(RewardLoadError, match="a directory"):
        _train(tmp_path / "run", tmp_path, 64)


BROKEN_REWARDS = {
    "raises": ("raise RuntimeError('boom')", "compute_reward raised RuntimeError: boom"),
    "returns a string": (
        "return 'high'",
        "compute_reward must return (total, components); got str",
    ),
    "returns one number": (
        "return 1.0, {}",
        "total has shape (); expected (2,), one per environment",
    ),
    "returns no components": (
        "return ctx['time_frac'] * 0.0, None",
        "components must be a dict; got NoneType",
    ),
    # SystemExit is no Exception: it ended `itskill train` silently, with the file's exit code.
    "exits": ("raise SystemExit(0)", "compute_reward raised SystemExit: 0"),
}


def _reward_file(directory: Path, body: str) -> Path:
    path = directory / "my_reward.py"
    path.write_text(f"def compute_reward(ctx):\n    {body}\n")
    return path


@pytest.mark.parametrize("case", list(BROKEN_REWARDS))
def test_a_broken_reward_file_is_refused_before_training(tmp_path: Path, case: str) -> None:
    body, problem = BROKEN_REWARDS[case]
    reward = _reward_file(tmp_path, body)
    with pytest.raises(RewardLoadError) as err:
        _train(tmp_path / "run", reward, 64)
    assert str(err.value) == f"{reward}: {problem}"
    assert not (tmp_path / "run").exists()  # refused before anything was built or written


def test_a_reward_file_exiting_as_it_loads_is_refused(tmp_path: Path) -> None:
    reward = tmp_path / "my_reward.py"
    reward.write_text("import sys\nsys.exit(3)\n")
    with pytest.raises(RewardLoadError) as err:
        _train(tmp_path / "run", reward, 64)
    assert str(err.value) == f"{reward}: failed to run: SystemExit: 3"


def test_a_new_run_refuses_a_directory_that_is_not_a_run(tmp_path: Path, reach_reward: Path):
    # A user's folder with a best/ in it: a new run deletes best/ and overwrites the metrics.
    out = tmp_path / "photos"
    (out / "best").mkdir(parents=True)
    (out / "best" / "wedding.jpg").write_text("irreplaceable")
    (out / "metrics.csv").write_text("mine")
    with pytest.raises(ResumeMismatchError, match=r"holds best/wedding\.jpg, which no training"):
        _train(out, reach_reward, 64)
    assert (out / "best" / "wedding.jpg").read_text() == "irreplaceable"
    assert (out / "metrics.csv").read_text() == "mine"
    (out / "notes.txt").write_text("x")
    with pytest.raises(ResumeMismatchError, match=r"holds notes\.txt, best/wedding\.jpg"):
        _train(out, reach_reward, 64)
    file = tmp_path / "a_file"
    file.write_text("x")
    with pytest.raises(ResumeMismatchError, match="a file, not a directory"):
        _train(file, reach_reward, 64)


def test_a_new_run_starts_again_where_a_killed_one_left_files(
    tmp_path: Path, reach_reward: Path
) -> None:
    # Killed before its first checkpoint: rows, TensorBoard logs, an evaluation, a best policy
    # and a half-written temporary file, but no checkpoint.json to resume from. Every file a run
    # writes must count as the run's, or such a run could never be started again.
    out = tmp_path / "run"
    logger = LoggerConfig(progress=False, tensorboard=True, min_steps_per_row=1)
    train(
        TASK, "ppo", 64, seed=1, reward=reach_reward, out=out, num_envs=4, overrides=FAST_PPO,
        logger=logger, eval_every=64, eval_episodes=2,
    )  # fmt: skip
    assert (out / "tb").is_dir() and (out / "best").is_dir()
    for name in ("checkpoint.json", "model.zip"):
        (out / name).unlink()
    (out / ".checkpoint.json.123.tmp").write_text("{")
    (out / ".DS_Store").write_bytes(b"")  # a file browser showed the folder
    result = _train(out, reach_reward, 64, eval_every=64, eval_episodes=2)
    assert result.resumed_from == 0 and result.num_timesteps == 64
    assert [row["step"] for row in read_metrics(out)][-1] == 64
    assert not (out / "tb").exists()  # the killed run's curves would show beside the new ones
    # A user's own temporary file is not one of the run's.
    (out / "checkpoint.json").unlink()
    (out / ".notes.tmp").write_text("mine")
    with pytest.raises(ResumeMismatchError, match=r"holds \.notes\.tmp"):
        _train(out, reach_reward, 64)


def test_a_reward_file_failing_during_training_names_the_file(tmp_path: Path) -> None:
    # Fine on the initial states it is probed on; it breaks once the episodes have begun.
    late = "if ctx['time_frac'].max() > 0:\n        raise ValueError('late')"
    body = f"{late}\n    return ctx['time_frac'] * 0.0, {{}}"
    reward = _reward_file(tmp_path, body)
    with pytest.raises(RewardLoadError) as err:
        _train(tmp_path / "run", reward, 64)
    assert str(err.value) == f"{reward}: compute_reward raised ValueError: late"


def test_cli_reports_a_broken_reward_file_in_one_line(tmp_path: Path) -> None:
    reward = _reward_file(tmp_path, BROKEN_REWARDS["raises"][0])
    args = ["train", TASK, "--steps", "64", "--reward", str(reward), "--out", str(tmp_path / "run")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    output = "".join(result.output.split())  # rich wraps long lines
    assert "compute_rewardraisedRuntimeError:boom" in output and str(reward) in output
    assert "Traceback" not in result.output


def test_cli_says_a_budget_ends_on_a_whole_rollout(tmp_path: Path, reach_reward: Path) -> None:
    args = ["train", TASK, "--algo", "a2c", "--steps", "40", "--num-envs", "4"]
    args += ["--reward", str(reach_reward), "--out", str(tmp_path / "run")]
    result = CliRunner().invoke(app, args)  # A2C: rollouts of 4 environments x 8 steps
    assert result.exit_code == 0, result.output
    assert "64 env-steps in total (whole rollouts: 40 asked)" in " ".join(result.output.split())


def test_cli_train_and_eval_run_directory(tmp_path: Path, reach_reward: Path) -> None:
    out = tmp_path / "run"
    runner = CliRunner()
    args = ["train", TASK, "--algo", "a2c", "--steps", "64", "--seed", "2"]
    args += ["--reward", str(reach_reward), "--out", str(out), "--num-envs", "4"]
    result = runner.invoke(app, [*args, "--eval-every", "32", "--eval-episodes", "2"])
    assert result.exit_code == 0, result.output
    assert "64 env-steps" in result.output and f"{out}/best" in result.output.replace("\n", "")
    assert len((out / "eval.csv").read_text().splitlines()) == 3
    result = runner.invoke(app, ["eval", TASK, "--policy", str(out), "--episodes", "4", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["episodes"] == 4
    result = runner.invoke(app, ["eval", TASK, "--policy", str(tmp_path), "--episodes", "2"])
    assert result.exit_code == 2 and "checkpoint.json" in result.output


def test_ppo_learns_reach_better_than_random(tmp_path: Path, reach_reward: Path) -> None:
    """A short PPO run beats the random policy's success rate (deterministic evaluation)."""
    out = tmp_path / "run"
    train(
        TASK, "ppo", 20_000, seed=0, reward=reach_reward, out=out, num_envs=16,
        overrides={"n_steps": 64, "batch_size": 256, "n_epochs": 5, "learning_rate": 1e-3,
                   "policy": {"log_std_init": -0.5}},
        logger=QUIET,
    )  # fmt: skip
    spec = get_task(TASK)
    trained = evaluate(spec, as_policy(out), episodes=64, seed=123)
    random = evaluate(spec, RandomPolicy(), episodes=64, seed=123)
    assert trained.success_rate >= random.success_rate + 0.1  # measured: 0.22 vs 0.0


def test_resume_restores_reward_scale(tmp_path: Path, reach_reward: Path, monkeypatch) -> None:
    out = tmp_path / "run"
    _train(out, reach_reward, 64)
    saved = json.loads((out / "reward_norm.json").read_text())
    seen = {}
    real = train_module.restore_reward_norm

    def spy(env, run_dir):
        real(env, run_dir)
        seen.update(mean=float(env.ret_rms.mean), count=float(env.ret_rms.count))

    monkeypatch.setattr(train_module, "restore_reward_norm", spy)
    _train(out, reach_reward, 128)
    assert seen == {"mean": saved["mean"], "count": saved["count"]}


def test_evaluating_a_finished_run_keeps_its_reward_scale(
    tmp_path: Path, reach_reward: Path
) -> None:
    # Stopped during its last evaluation, the run is called again to evaluate: its closing
    # checkpoint wrote fresh statistics, which a later --steps raise then trained on.
    out = tmp_path / "run"
    _train(out, reach_reward, 64, eval_every=32, eval_episodes=2)
    saved = (out / "reward_norm.json").read_text()
    rows = (out / "eval.csv").read_text().splitlines()
    (out / "eval.csv").write_text("\n".join(rows[:-1]) + "\n")
    result = _train(out, reach_reward, 64, eval_every=32, eval_episodes=2)
    assert result.num_timesteps == 64
    again = (out / "eval.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in again] == [r.split(",")[0] for r in rows]  # evaluated at 64
    assert (out / "reward_norm.json").read_text() == saved


def test_a_task_table_of_the_hyperparameter_file_reaches_its_training(
    tmp_path: Path, reach_reward: Path
) -> None:
    hp = tmp_path / "hp.toml"
    hp.write_text(f"[nutbolt.tasks.{TASK}.policy]\nlog_std_init = -1.5\n")
    out = tmp_path / "run"
    _train(out, reach_reward, 64, hyperparams=hp)
    meta = json.loads((out / "checkpoint.json").read_text())
    assert meta["hyperparams"]["policy"]["log_std_init"] == -1.5
    np.testing.assert_allclose(load_policy(out).log_std.detach().numpy(), -1.5, atol=0.05)


def _square_averages(run_dir: Path) -> torch.Tensor:
    """Every running average of squared gradients the run's RMSprop holds, in one tensor."""
    _, params, _ = load_from_zip_file(run_dir / "model.zip", device="cpu")
    state = params["policy.optimizer"]["state"].values()
    return torch.cat([s["square_avg"].flatten() for s in state])


def test_a2c_with_tensorflows_rmsprop_keeps_it_across_a_resume(
    tmp_path: Path, reach_reward: Path
) -> None:
    out, tf_like = tmp_path / "tf", {"rms_prop_tf_like": True}
    _train(out, reach_reward, 16, algo="a2c", overrides=tf_like)
    # TensorFlow's averages start at 1, so after an update of clipped gradients they are near
    # it; torch's start at 0 and stay orders of magnitude below.
    assert _square_averages(out).min() > 0.98
    _train(out, reach_reward, 32, algo="a2c", overrides=tf_like)
    assert _square_averages(out).min() > 0.97
    torch_out = tmp_path / "torch"
    _train(torch_out, reach_reward, 16, algo="a2c")
    assert _square_averages(torch_out).max() < 0.1


def test_a_run_from_before_tensorflows_rmsprop_resumes_only_with_torchs(
    tmp_path: Path, reach_reward: Path
) -> None:
    out = tmp_path / "run"
    _train(out, reach_reward, 16, algo="a2c")
    meta_file = out / "checkpoint.json"
    meta = json.loads(meta_file.read_text())
    del meta["hyperparams"]["a2c"]["rms_prop_tf_like"]  # as releases before it wrote
    meta_file.write_text(json.dumps(meta))
    # Its model.zip restores torch's RMSprop whatever the settings say.
    with pytest.raises(ResumeMismatchError, match=r"a2c\.rms_prop_tf_like: False -> True"):
        _train(out, reach_reward, 32, algo="a2c", overrides={"rms_prop_tf_like": True})
    assert _train(out, reach_reward, 32, algo="a2c").num_timesteps == 32


def test_tensorflows_rmsprop_needs_rmsprop(tmp_path: Path, reach_reward: Path) -> None:
    with pytest.raises(HyperparamError, match="rms_prop_tf_like needs use_rms_prop"):
        tf_without_rms_prop = {"use_rms_prop": False, "rms_prop_tf_like": True}
        _train(tmp_path / "run", reach_reward, 16, algo="a2c", overrides=tf_without_rms_prop)


def test_tensorboard_labels_each_update_with_the_steps_it_learned_from(
    tmp_path: Path, reach_reward: Path
) -> None:
    # Each update's statistics were written with the next rollout's row, a rollout late, and
    # the last update's never.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "run"
    logger = LoggerConfig(progress=False, tensorboard=True, min_steps_per_row=1)
    train(TASK, "ppo", 256, seed=1, reward=reach_reward, out=out, num_envs=4,
          overrides={**FAST_PPO, "lr_schedule": "linear"}, logger=logger)  # fmt: skip
    events = EventAccumulator(str(out / "tb"))
    events.Reload()
    rates = [(e.step, e.value) for e in events.Scalars("train/learning_rate")]
    start = json.loads((out / "checkpoint.json").read_text())["hyperparams"]["ppo"]
    # Rollouts of 64: the update after the rollout that ends at N runs at 1 - N / 256 of the
    # starting rate (SB3 computes its progress once the rollout is collected).
    expected = [(n, start["learning_rate"] * (1 - n / 256)) for n in (64, 128, 192, 256)]
    assert [s for s, _ in rates] == [s for s, _ in expected]
    assert all(
        v == pytest.approx(w, rel=1e-5) for (_, v), (_, w) in zip(rates, expected, strict=True)
    )


def test_the_training_rate_leaves_the_evaluations_out(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # A row after an evaluation counted its seconds: 22 steps/s beside 155-294 for the others.
    fake, _ = _scripted_evaluate(iter([0.5] * 10))

    def slow(*args, **kwargs):
        time.sleep(1.5)
        return fake(*args, **kwargs)

    monkeypatch.setattr(eval_callback, "evaluate", slow)
    out = tmp_path / "run"
    _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    rates = [row["steps_per_s"] for row in read_metrics(out)]
    # Rows of 64 env-steps: with each evaluation's 1.5 s in them, every rate is under 43.
    assert len(rates) == 4 and min(rates) > 64 / 1.5, rates


def _scripted_evaluate(scores, interrupt_at=()):
    """An ``evaluate`` stand-in: each call takes the next success from ``scores``, and the calls
    numbered in ``interrupt_at`` (from 1) raise KeyboardInterrupt as a Ctrl-C during it would."""
    calls = {"n": 0}

    def fake(spec, actor, episodes, seed, num_envs):
        calls["n"] += 1
        if calls["n"] in interrupt_at:
            raise KeyboardInterrupt
        n = len(spec.stages)
        return EvalResult(
            spec.id, episodes, 0, next(scores), 0.0, 1.0, 10.0, 0.0, "live",
            0.0, n, [10.0] + [0.0] * (n - 1),
        )  # fmt: skip

    return fake, calls


def _eval_steps(out: Path) -> list[int]:
    with open(out / "eval.csv", newline="") as fh:
        return [int(r["env_steps"]) for r in csv.DictReader(fh)]


def test_an_evaluation_cut_short_by_ctrl_c_is_made_up_on_resume(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # The checkpoint saved on Ctrl-C is past the evaluation's step, so it never came round again;
    # cut short at the end, the finished run never evaluated its final policy at all.
    fake, calls = _scripted_evaluate(iter([0.5] * 10), interrupt_at=(2, 4, 6))
    monkeypatch.setattr(eval_callback, "evaluate", fake)
    out = tmp_path / "run"
    for _ in range(3):  # interrupted at 128, then at 192, then at 256 (the last one)
        with pytest.raises(KeyboardInterrupt):
            _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert _eval_steps(out) == [64, 128, 192]
    # The last update was done: the run is finished but for its final evaluation.
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 256
    done = _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert done.num_timesteps == 256 and _eval_steps(out) == [64, 128, 192, 256]
    assert done.best is not None and done.best["env_steps"] == 256
    assert calls["n"] == 7
    _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)  # finished: nothing to do
    assert calls["n"] == 7


def test_evaluations_after_the_checkpoint_a_crash_went_back_to_are_forgotten(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Killed after evaluating at 192 and 256 but before checkpointing past 128: the resumed run
    # trains 128..256 again, differently; the old rows doubled the curve (and a reward
    # candidate's peak success was taken over both). best/, a policy this run trained and
    # measured, stays until an evaluation matches or beats it.
    scores = iter([0.25, 0.25, 0.5, 1.0, 0.0, 0.0])
    fake, _ = _scripted_evaluate(scores)
    monkeypatch.setattr(eval_callback, "evaluate", fake)
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    saved = {
        f: (out / f).read_bytes() for f in ("model.zip", "checkpoint.json", "reward_norm.json")
    }
    lost = _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert lost.best is not None and lost.best["success"] == 1.0
    for name, data in saved.items():  # the state kill -9 leaves: the 128 checkpoint
        (out / name).write_bytes(data)
    resumed = _train(out, reach_reward, 256, eval_every=64, eval_episodes=2)
    assert resumed.resumed_from == 128 and _eval_steps(out) == [64, 128, 192, 256]
    assert resumed.best == lost.best


def test_a_fresh_run_forgets_what_a_session_killed_before_its_first_checkpoint_left(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # No checkpoint: nothing says those rows and that best policy came from these settings.
    fake, _ = _scripted_evaluate(iter([1.0, 1.0, 0.25, 0.25]))
    monkeypatch.setattr(eval_callback, "evaluate", fake)
    out = tmp_path / "run"
    _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    (out / "checkpoint.json").unlink()  # the state a kill before the first checkpoint leaves
    again = _train(out, reach_reward, 128, eval_every=64, eval_episodes=2)
    assert again.resumed_from == 0 and _eval_steps(out) == [64, 128]
    assert again.best is not None and again.best["success"] == 0.25
    assert [row["step"] for row in read_metrics(out)] == sorted(
        {r["step"] for r in read_metrics(out)}
    )


def test_a_checkpoint_torn_between_its_files_resumes_from_the_model(
    tmp_path: Path, reach_reward: Path
) -> None:
    # Killed after model.zip was replaced and before checkpoint.json was: the model holds 128
    # env-steps, the record 64. The model is the truth, and the record is repaired.
    out = tmp_path / "run"
    _train(out, reach_reward, 128)
    meta = json.loads((out / "checkpoint.json").read_text())
    (out / "checkpoint.json").write_text(json.dumps({**meta, "num_timesteps": 64}))
    done = _train(out, reach_reward, 256)
    assert done.resumed_from == 128 and done.num_timesteps == 256
    steps = [row["step"] for row in read_metrics(out)]
    assert 128 in steps and steps == sorted(set(steps))
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 256


def test_a_run_killed_while_writing_its_first_trained_checkpoint_resumes_from_it(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Before a new run saved a checkpoint at step 0, a kill between its first model.zip and
    # checkpoint.json left no record: the next session started again from step 0.
    from itskill.rl import checkpoint as checkpoint_module

    real = checkpoint_module.write_text

    def killed_at_the_record(path, text):
        if Path(path).name == "checkpoint.json" and json.loads(text)["num_timesteps"] > 0:
            raise SystemExit("killed")
        real(path, text)

    out = tmp_path / "run"
    monkeypatch.setattr(checkpoint_module, "write_text", killed_at_the_record)
    with pytest.raises(SystemExit):
        _train(out, reach_reward, 128)
    monkeypatch.undo()
    assert json.loads((out / "checkpoint.json").read_text())["num_timesteps"] == 0
    done = _train(out, reach_reward, 256)
    assert done.resumed_from == 128 and done.num_timesteps == 256


def test_a_run_killed_before_its_first_update_starts_over_as_a_new_budget_would(
    tmp_path: Path, reach_reward: Path, monkeypatch
) -> None:
    # Resumed from its step-0 checkpoint toward another budget, it warned of a moved learning
    # rate schedule (nothing had trained), kept the killed session's TensorBoard events, and
    # said best/ stayed a policy no evaluation had chosen.
    run = tmp_path / "run"

    def killed(*args, **kwargs):
        raise SystemExit("killed")

    monkeypatch.setattr(train_module, "_learn", killed)
    with pytest.raises(SystemExit):
        train(
            TASK, "ppo", 64, seed=1, reward=reach_reward, out=run, num_envs=4,
            overrides=FAST_PPO, logger=QUIET, eval_every=64, eval_episodes=2,
        )  # fmt: skip
    monkeypatch.undo()
    (run / "tb").mkdir()
    (run / "tb" / "events.out.tfevents.killed").write_text("")  # what its session logged
    told = io.StringIO()
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScheduleWarning)
        result = train(
            TASK, "ppo", 128, seed=1, reward=reach_reward, out=run, num_envs=4,
            overrides=FAST_PPO, logger=replace(QUIET, progress=True),
            console=Console(file=told, width=400),
        )  # fmt: skip
    assert result.resumed_from == 0 and result.num_timesteps == 128
    assert not (run / "tb" / "events.out.tfevents.killed").exists()
    assert "best/ stays" not in told.getvalue()


def test_a_run_directory_in_training_elsewhere_is_refused_and_left_as_it_is(
    tmp_path: Path, reach_reward: Path
) -> None:
    # Two sessions on one --out wrote every metrics row twice and kept whichever model saved
    # last.
    from itskill.files import directory_lock
    from itskill.transfer import train_transfer

    out = tmp_path / "run"
    _train(out, reach_reward, 64)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with directory_lock(out, "train"):
        with pytest.raises(ResumeMismatchError, match="in use by another itskill training"):
            _train(out, reach_reward, 128)
        with pytest.raises(ResumeMismatchError, match="in use by another itskill training"):
            train_transfer("pick_nut_m12", "no_transfer", out=out, steps=128)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert _train(out, reach_reward, 128).resumed_from == 64
