"""One candidate's process: the wall-clock limit, the causes of a dead process, no rerun."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from replies import GOOD

from itskill.curves import eval_seed
from itskill.reward.candidate import CandidateJob, _train_and_measure, run_candidate
from itskill.reward.generator import extract_code
from itskill.reward.sandbox import SandboxConfig
from itskill.rl.checkpoint import as_policy
from itskill.tasks import get_task
from itskill.tasks.evaluate import evaluate


def _job(out: Path, timeout_s: float) -> CandidateJob:
    return CandidateJob(
        task="pick_nut_m12",
        out=out,
        code=extract_code(GOOD),
        seeds=(0,),
        steps=128,
        num_envs=2,
        algo="ppo",
        eval_every=128,
        eval_episodes=2,
        correlation_envs=2,
        sandbox=SandboxConfig(call_timeout_s=0.5),
        timeout_s=timeout_s,
    )


def test_a_candidate_past_its_wall_clock_limit_is_stopped_and_recorded(tmp_path: Path) -> None:
    job = _job(tmp_path / "cand", timeout_s=0.5)  # less than the process needs to start
    result = run_candidate(job)
    assert result["status"] == "failed"
    assert "took longer than 0.5 s" in result["error"]
    path = tmp_path / "cand" / "result.json"
    assert json.loads(path.read_text()) == result
    # A finished candidate, failed or not, is never run again.
    stamp = path.stat().st_mtime_ns
    assert run_candidate(_job(tmp_path / "cand", timeout_s=300)) == result
    assert path.stat().st_mtime_ns == stamp


def test_a_failure_of_the_machine_in_the_child_is_not_recorded_as_the_candidates(
    tmp_path: Path,
) -> None:
    # Any exception the child raised was the candidate's failure, never to be trained again, and
    # fed back to the model as its code's fault.
    job = _job(tmp_path / "cand", timeout_s=300)
    (tmp_path / "cand").mkdir()
    (tmp_path / "cand" / "train").write_text("a file where the training runs go")
    with pytest.raises(OSError):
        run_candidate(job)
    assert not (tmp_path / "cand" / "result.json").exists()


def _rerun_with_evaluations(tmp_path: Path, rows: str) -> dict:
    """The candidate's result once more, its finished run's ``eval.csv`` holding ``rows``."""
    job = _job(tmp_path / "cand", timeout_s=300)
    assert run_candidate(job)["status"] == "ok"
    (tmp_path / "cand" / "result.json").unlink()
    eval_file = job.train_dir(0) / "eval.csv"
    header = eval_file.read_text().splitlines()[0]
    eval_file.write_bytes(f"{header}\n{rows}".encode("utf-8", "surrogateescape"))
    return run_candidate(job)


def test_a_candidates_success_leaves_out_evaluations_a_resumed_session_replaced(
    tmp_path: Path,
) -> None:
    # The first session evaluated at 128 (90%) and died with its checkpoint at 64; the resumed
    # one evaluated 64 and 128 again. The 90% belonged to a policy thrown away.
    rows = "128,2,0.9,0,1,60,0\n64,1,0.2,0,1,60,0\n128,2,0.5,0,1,60,0\n"
    result = _rerun_with_evaluations(tmp_path, rows)
    assert result["status"] == "ok"
    assert result["success"] == 0.5 and result["runs"][0]["curve"] == [(64, 0.2), (128, 0.5)]


@pytest.mark.parametrize(
    ("rows", "problem"),
    [("64,1,0.2,0,1,60,0\n128,2\n", "not a number"), ("64,1,0.2,0,1,60,\udcff\n", "not UTF-8")],
)
def test_a_candidate_whose_evaluations_are_damaged_fails_naming_the_file(
    tmp_path: Path, rows: str, problem: str
) -> None:
    result = _rerun_with_evaluations(tmp_path, rows)
    assert result["status"] == "failed"
    assert f"eval.csv: {problem}" in result["error"]


def test_a_candidate_whose_last_evaluation_was_cut_short_evaluates_its_final_policy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On the episodes its run evaluates on: those of its training seed."""
    job = replace(_job(tmp_path / "cand", timeout_s=300), seeds=(3,))
    assert run_candidate(job)["status"] == "ok"
    # Killed between its last checkpoint (128) and that checkpoint's evaluation.
    eval_file = job.train_dir(3) / "eval.csv"
    header = eval_file.read_text().splitlines()[0]
    eval_file.write_text(f"{header}\n64,1,0.2,0,1,60,0\n")
    seeds = []

    def recording(spec, policy, episodes, seed, num_envs):
        seeds.append(seed)
        return evaluate(spec, policy, episodes, seed, num_envs)

    # In this process, not the candidate's child, so that the evaluation can be watched: the
    # trainer makes it up on resuming the finished run, or the candidate does after it.
    monkeypatch.setattr("itskill.tasks.evaluate.evaluate", recording)
    monkeypatch.setattr("itskill.rl.eval_callback.evaluate", recording)
    result = _train_and_measure(job)
    assert seeds == [eval_seed(3)]
    final = evaluate(get_task("pick_nut_m12"), as_policy(job.train_dir(3)), 2, eval_seed(3), 25)
    assert result["runs"][0]["curve"] == [(64, 0.2), (128, final.success_rate)]
