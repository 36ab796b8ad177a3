"""One candidate's process: the wall-clock limit, the causes of a dead process, no rerun."""

from __future__ import annotations

import json
from pathlib import Path

from replies import GOOD

from itskill.reward.candidate import CandidateJob, run_candidate
from itskill.reward.generator import extract_code
from itskill.reward.sandbox import SandboxConfig


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
