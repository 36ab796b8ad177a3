"""`itskill reward generate` killed with SIGKILL mid-iteration, then resumed with --resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from fake_openai import FakeOpenAIServer
from replies import CONSTANT, GOOD
from search_helpers import TINY_TOML
from typer.testing import CliRunner

from itskill.cli import app

ITSKILL = str(Path(sys.executable).with_name("itskill"))


def _results(run: Path) -> dict[Path, tuple[int, int]]:
    return {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in run.glob("iter_*/*/result.json")}


def test_kill_9_then_resume_repeats_no_finished_work(tmp_path: Path) -> None:
    config = tmp_path / "search.toml"
    config.write_text(TINY_TOML)
    run = tmp_path / "run"
    with FakeOpenAIServer([GOOD, CONSTANT, GOOD]) as server:
        llm = ["--llm", "openai:fake-model", "--base-url", server.base_url]
        cmd = [ITSKILL, "reward", "generate", "pick_nut_m12", *llm, "--config", str(config)]
        proc = subprocess.Popen(
            [*cmd, "--workers", "2", "--out", str(run)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 300
            while not _results(run) and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.2)
            assert proc.poll() is None, "the run ended before any candidate finished"
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
        finally:
            if proc.poll() is None:
                proc.kill()
        finished = _results(run)
        assert 1 <= len(finished) < 3 and not (run / "summary.json").exists()
        asked = len(server.requests)
        time.sleep(3)  # orphaned workers and candidates notice within a second each, and stop

        resumed = subprocess.run(
            [ITSKILL, "reward", "generate", "--resume", str(run), "--base-url", server.base_url],
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert resumed.returncode == 0, resumed.stderr + resumed.stdout
        # The model was not asked again: the replies came from the run's cache.
        assert len(server.requests) == asked == 1

    # Finished candidates were not trained again: the same files, never rewritten.
    after = _results(run)
    assert {p: after[p] for p in finished} == finished
    assert len(after) == 3
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "complete"
    assert summary["final"]["expert"]["seeds"] == [1]
    assert len(summary["iterations"][0]["samples"]) == 3
    sessions = json.loads((run / "usage.json").read_text())["sessions"]
    assert len(sessions) == 2
    assert sessions[1]["requests"] == 0 and sessions[1]["cache_hits"] == 1

    shown = CliRunner().invoke(app, ["reward", "show", str(run)], env={"COLUMNS": "120"})
    assert shown.exit_code == 0, shown.output
    assert "replies by openai:fake-model" in shown.output and "best reward:" in shown.output
    assert "expert: success" in shown.output and "2 session(s)" in shown.output
    as_json = CliRunner().invoke(app, ["reward", "show", str(run), "--json"])
    assert json.loads(as_json.output)["summary"]["task"] == "pick_nut_m12"
