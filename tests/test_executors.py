"""The job executors: every job's result or error comes back, locally and on a local Ray."""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import signal
import socket
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest

from itskill.executors import ExecutorError, check_executor, run_jobs
from itskill.rl.checkpoint import read_meta
from itskill.tasks.evaluate import CheckpointError

# A library function, so that Ray's workers can import it (a test module is not importable there).
JOBS = [(4.0,), (9.0,), (-1.0,), (16.0,)]


def _check(results) -> None:
    by_index = {r.index: r for r in results}
    assert sorted(by_index) == [0, 1, 2, 3]
    assert [by_index[i].value for i in (0, 1, 3)] == [2.0, 3.0, 4.0]
    assert not by_index[2].ok
    assert isinstance(by_index[2].error, ValueError)


@pytest.mark.parametrize("workers", [1, 2])
def test_local_executor_returns_every_result_and_error(workers: int) -> None:
    _check(run_jobs(math.sqrt, JOBS, "local", workers))


def test_a_worker_error_with_several_arguments_comes_back_as_itself(tmp_path) -> None:
    # CheckpointError(path, problem) used to break the pool: it could not be unpickled.
    missing = tmp_path / "no_run"
    [result] = run_jobs(read_meta, [(missing,)], "local", 2)
    assert isinstance(result.error, CheckpointError)
    assert str(result.error) == f"{missing}: no such checkpoint directory"


def test_unknown_executor_is_a_clear_error() -> None:
    with pytest.raises(ExecutorError, match="unknown executor 'slurm'"):
        list(run_jobs(math.sqrt, JOBS, "slurm"))  # type: ignore[arg-type]


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray is not installed")
@pytest.mark.parametrize("workers", [None, 2])
def test_ray_executor_on_a_local_instance(workers: int | None) -> None:
    # workers=2 goes through the refill loop (two submitted, the rest as they finish); that it
    # never has more than two in flight is not observable from these results.
    _check(run_jobs(math.sqrt, JOBS, "ray", workers))


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray is not installed")
def test_a_lost_ray_worker_fails_its_job_not_the_run() -> None:
    # A worker that dies (killed for memory, a crash) raised out of the loop, cancelling every
    # other job: a search lost its whole iteration to one candidate.
    import ray

    [result] = run_jobs(os._exit, [(1,)], "ray", 1)
    assert not result.ok and isinstance(result.error, ray.exceptions.RayError)


def test_the_ray_executor_without_ray_is_refused_before_any_work(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(ExecutorError, match=r"executor 'ray' needs Ray: pip install"):
        check_executor("ray")
    check_executor("local")


def test_a_ray_address_with_the_local_executor_is_refused() -> None:
    with pytest.raises(ExecutorError, match="needs the Ray executor"):
        list(run_jobs(math.sqrt, JOBS, "local", 2, "ray://head:10001"))


@pytest.mark.parametrize("address", ["", "  "])
def test_an_empty_ray_address_is_refused_before_any_work(tmp_path, address: str) -> None:
    # A variable that expanded to nothing: the run was recorded and its first samples paid for
    # before Ray refused the address.
    pytest.importorskip("ray")
    from typer.testing import CliRunner

    from itskill.cli import app

    with pytest.raises(ExecutorError, match="the Ray address is empty"):
        check_executor("ray", None, address)
    out = tmp_path / "run"
    smoke = Path(__file__).parents[1] / "experiments" / "smoke.toml"
    args = ["experiment", "run", str(smoke), "--executor", "ray", "--ray-address"]
    result = CliRunner().invoke(app, [*args, address, "--out", str(out)])
    assert result.exit_code != 0 and "the Ray address is empty" in " ".join(result.output.split())
    assert not out.exists()
    # A search over a transfer network asked the model for its plan and analysis first.
    args = ["reward", "generate", "pick_nut_m12", "--transfer", "itn", "--executor", "ray"]
    result = CliRunner().invoke(app, [*args, "--ray-address", address, "--out", str(out)])
    said = " ".join(result.output.replace("│", " ").split())
    assert result.exit_code == 2 and "--ray-address: empty: leave it out for a local Ray" in said
    assert not out.exists()


def test_an_address_where_no_ray_listens_is_refused_in_seconds() -> None:
    # Ray retried such an address for minutes, silently, after the run had been recorded.
    with socket.socket() as probe:  # a port nothing listens on: bound, then closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    start = time.monotonic()
    for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}"):
        with pytest.raises(ExecutorError, match=f"could not reach Ray at {address}"):
            check_executor("ray", None, address)
    assert time.monotonic() - start < 10
    check_executor("ray", None, "auto")  # resolved by Ray itself: not probed


def test_zero_workers_is_refused() -> None:
    with pytest.raises(ExecutorError, match="at least 1"):
        list(run_jobs(math.sqrt, JOBS, "local", 0))


WARNING_SCRIPT = """
import sys, warnings
from itskill.cli.common import show_warning_line
from itskill.executors import run_jobs

def work():
    from itskill.skills.library import ShippedLibraryWarning  # here: it imports torch

    warnings.warn("the shipped skill library is damaged", ShippedLibraryWarning)

if __name__ == "__main__":
    warnings.showwarning = show_warning_line  # as the itskill command does
    if sys.argv[1] == "pool":
        [result] = run_jobs(work, [()], "local", 2)
        sys.exit(0 if result.ok else 1)
    from itskill.reward.limited import run_limited
    from itskill.reward.sandbox import SandboxConfig

    run_limited(work, sandbox=SandboxConfig(), name="the test's process")
"""


@pytest.mark.parametrize("spawned_by", ["pool", "limited"])
def test_a_spawned_process_shows_warnings_as_its_parent_does(tmp_path, spawned_by) -> None:
    # A worker, or the limited process a candidate trains in, showed itskill's own warnings in
    # Python's format, file, line and source line, where the command shows one line.
    script = tmp_path / "parent.py"
    script.write_text(WARNING_SCRIPT)
    out = subprocess.run(
        [sys.executable, str(script), spawned_by], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    shown = [line for line in out.stderr.splitlines() if "damaged" in line]
    assert shown == ["warning: the shipped skill library is damaged"], out.stderr


def test_workers_start_when_the_parent_shows_warnings_with_a_lambda(monkeypatch) -> None:
    # A showwarning that cannot be pickled stays in the parent: the jobs run all the same.
    monkeypatch.setattr(warnings, "showwarning", lambda *args, **kwargs: None)
    _check(run_jobs(math.sqrt, JOBS, "local", 2))


PARENT_SCRIPT = """
import os, sys, time
from itskill.executors import run_jobs

def work(path):
    with open(path, "w") as fh:
        fh.write(str(os.getpid()))
    time.sleep(120)

if __name__ == "__main__":
    list(run_jobs(work, [(sys.argv[1],), (sys.argv[2],)], "local", 2))
"""


def _wait_for_workers(started: Callable[[], bool]) -> None:
    """Wait (up to a minute) until ``started()``: the workers have begun their jobs."""
    deadline = time.monotonic() + 60
    while not started():
        assert time.monotonic() < deadline, "workers did not start"
        time.sleep(0.1)


def _alive(pid: int) -> bool:
    """Running and not a zombie (an orphan's zombie waits for a reaper that may never come)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc to inspect processes")
def test_local_workers_end_when_the_parent_is_killed(tmp_path) -> None:
    script = tmp_path / "parent.py"
    script.write_text(PARENT_SCRIPT)
    marks = [tmp_path / "a.pid", tmp_path / "b.pid"]
    parent = subprocess.Popen([sys.executable, str(script), *map(str, marks)])
    try:
        _wait_for_workers(lambda: all(m.exists() and m.read_text() for m in marks))
        workers = [int(m.read_text()) for m in marks]
        parent.send_signal(signal.SIGTERM)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(pid) for pid in workers)
    finally:
        parent.kill()
        for m in marks:
            if m.exists() and m.read_text():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(m.read_text()), signal.SIGKILL)


INTERRUPT_SCRIPT = """
import os, sys, time
from itskill.executors import run_jobs

def work(directory, i):
    with open(os.path.join(directory, f"{i}.started"), "w") as fh:
        fh.write(str(os.getpid()))
    try:
        # Short steps, as a trainer's: a signal the kernel hands to another of the worker's
        # threads runs its handler when the main thread next runs Python, which one long
        # sleep would put off for its whole length.
        for _ in range(1200):
            time.sleep(0.1)
    except KeyboardInterrupt:
        time.sleep(1.0)  # a trainer saving its checkpoint; a second Ctrl-C must not cut it short
        open(os.path.join(directory, f"{i}.saved"), "w").close()
        raise

if __name__ == "__main__":
    import signal
    for sig in (signal.SIGTERM, signal.SIGHUP):  # as the itskill command does
        signal.signal(sig, signal.default_int_handler)
    try:
        list(run_jobs(work, [(sys.argv[1], i) for i in range(6)], "local", 2))
    except KeyboardInterrupt:
        sys.exit(130)
"""


@pytest.mark.parametrize(
    ("target", "sig", "sigint"),
    [
        ("process group", signal.SIGINT, signal.SIG_DFL),
        ("parent only", signal.SIGINT, signal.SIG_DFL),
        ("process group", signal.SIGTERM, signal.SIG_DFL),
        ("process group", signal.SIGHUP, signal.SIG_DFL),
        # Started in the background by a script (`itskill skills pretrain ... &`), then `kill`:
        # the workers, which ignore SIGINT as their parent does, were passed a SIGINT and
        # trained on to the end of their jobs while the parent waited for them.
        ("parent only", signal.SIGTERM, signal.SIG_IGN),
    ],
)
def test_ctrl_c_stops_the_jobs_in_flight_and_starts_no_more(tmp_path, target, sig, sigint) -> None:
    # A terminal's Ctrl-C reaches the parent and its workers; `kill -INT` the parent alone; a
    # batch scheduler's SIGTERM, or a closed terminal's SIGHUP, the whole group, which then
    # saves as it does on Ctrl-C.
    script = tmp_path / "parent.py"
    script.write_text(INTERRUPT_SCRIPT)
    parent = subprocess.Popen(
        [sys.executable, str(script), str(tmp_path)],
        start_new_session=True,
        # A process started in the background by a script (a CI job, say) ignores SIGINT, and
        # its children inherit that; a terminal's command does not.
        preexec_fn=lambda: signal.signal(signal.SIGINT, sigint),
    )
    try:
        _wait_for_workers(lambda: len(list(tmp_path.glob("*.started"))) >= 2)
        time.sleep(0.5)
        if target == "process group":
            os.killpg(parent.pid, sig)
        else:
            parent.send_signal(sig)
        assert parent.wait(timeout=30) == 130
        assert len(list(tmp_path.glob("*.started"))) == 2
        assert len(list(tmp_path.glob("*.saved"))) == 2
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(parent.pid, signal.SIGKILL)


IGNORED_SCRIPT = """
import os, sys, time
from itskill.executors import run_jobs

def work(directory, i):
    open(os.path.join(directory, f"{i}.started"), "w").close()
    for _ in range(30):
        time.sleep(0.1)
    open(os.path.join(directory, f"{i}.done"), "w").close()

if __name__ == "__main__":
    import signal
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    results = list(run_jobs(work, [(sys.argv[1], i) for i in range(4)], "local", 2))
    sys.exit(1 if any(not r.ok for r in results) else 0)
"""


def test_a_ctrl_c_the_background_command_ignores_stops_none_of_its_workers(tmp_path) -> None:
    # A script's background job (`cmd &`) ignores SIGINT. Its workers must too: stopped by a
    # Ctrl-C their parent ignored, they left every job failed while the parent went on.
    script = tmp_path / "parent.py"
    script.write_text(IGNORED_SCRIPT)
    parent = subprocess.Popen(
        [sys.executable, str(script), str(tmp_path)],
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    try:
        _wait_for_workers(lambda: len(list(tmp_path.glob("*.started"))) >= 2)
        os.killpg(parent.pid, signal.SIGINT)
        assert parent.wait(timeout=60) == 0
        assert len(list(tmp_path.glob("*.done"))) == 4
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(parent.pid, signal.SIGKILL)


SLOW_IMPORT_MODULE = """
import multiprocessing, os, sys, time

if os.environ.get("SLOW_IMPORT") and multiprocessing.parent_process() is not None:
    # In a worker: importing the job's modules (torch, MuJoCo) takes seconds.
    open(os.path.join(os.environ["MARKS"], f"{os.getpid()}.importing"), "w").close()
    time.sleep(60)

def work(i):
    return i
"""

SLOW_IMPORT_SCRIPT = """
import sys
from itskill.executors import run_jobs
from itskill.reward.limited import run_limited
from itskill.reward.sandbox import SandboxConfig

def limited(i):
    import os
    from slowmod import work
    os.environ["SLOW_IMPORT"] = "1"  # slow in run_limited's child, not in this pool worker
    return run_limited(work, (i,), sandbox=SandboxConfig(), name="the child")

if __name__ == "__main__":
    import os, signal
    import slowmod  # here, not above: the workers import this script too, as itskill's light one
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    if sys.argv[1] == "pool":
        fn = slowmod.work
        os.environ["SLOW_IMPORT"] = "1"
    else:
        fn = limited
    try:
        list(run_jobs(fn, [(i,) for i in range(4)], "local", 2))
    except KeyboardInterrupt:
        sys.exit(130)
"""


@pytest.mark.parametrize("where", ["pool", "limited"])
def test_ctrl_c_while_workers_import_their_job_ends_without_a_traceback(tmp_path, where) -> None:
    # Ctrl-C in the first seconds of a reward search or an experiment: the workers are still
    # importing torch. The terminal should show the command's own message, not a traceback
    # from every worker.
    (tmp_path / "slowmod.py").write_text(SLOW_IMPORT_MODULE)
    script = tmp_path / "parent.py"
    script.write_text(SLOW_IMPORT_SCRIPT)
    parent = subprocess.Popen(
        [sys.executable, str(script), where],
        cwd=tmp_path,
        env={**os.environ, "MARKS": str(tmp_path)},
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _wait_for_workers(lambda: len(list(tmp_path.glob("*.importing"))) >= 2)
        os.killpg(parent.pid, signal.SIGINT)
        _, stderr = parent.communicate(timeout=30)
        assert parent.returncode == 130
        assert "Traceback" not in stderr
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(parent.pid, signal.SIGKILL)
