"""A function run in a limited child: its value, its exception, its death, its interruption."""

from __future__ import annotations

import errno
import os
import resource
import signal
import threading
import time
from pathlib import Path

import pytest

from itskill.reward.limited import ChildFailed, RemoteTraceback, run_limited
from itskill.reward.sandbox import SandboxConfig

LIMITS = SandboxConfig(memory_limit_mb=1024, cpu_limit_s=60)


def _address_space_limit() -> int:
    return resource.getrlimit(resource.RLIMIT_AS)[0]


def _allocate(gigabytes: float) -> int:
    import numpy as np

    return int(np.ones(int(gigabytes * 2**30 / 8)).size)


class _Unpicklable(Exception):
    def __init__(self, a: int, b: int) -> None:
        super().__init__(f"{a}/{b}")
        self.lock = threading.Lock()  # an attribute no pickle takes


def _raise(kind: str) -> None:
    if kind == "value":
        raise ValueError("bad reward at step 7")
    raise _Unpicklable(1, 2)


def _kill_self() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _sleep(seconds: float) -> None:
    time.sleep(seconds)


def _large() -> bytes:
    return b"x" * (8 * 2**20)  # far more than a pipe holds: read while the child writes


def _loop_until_interrupted(marker: str) -> None:
    Path(marker + ".started").touch()
    try:
        while True:
            time.sleep(0.05)
    except KeyboardInterrupt:
        Path(marker).write_text("saved")  # as a training saves its checkpoint
        raise


def test_the_child_is_limited_and_the_caller_is_not() -> None:
    before = _address_space_limit()
    assert run_limited(_address_space_limit, sandbox=LIMITS, name="child") == 1024 * 2**20
    assert _address_space_limit() == before
    # 2 GB fits this machine: only the child's address-space limit stops it.
    with pytest.raises(MemoryError):
        run_limited(_allocate, (2.0,), sandbox=LIMITS, name="child")
    assert run_limited(_allocate, (0.01,), sandbox=LIMITS, name="child") > 0


def test_the_childs_exception_is_raised_with_its_traceback() -> None:
    with pytest.raises(ValueError, match="bad reward at step 7") as info:
        run_limited(_raise, ("value",), sandbox=LIMITS, name="child")
    assert isinstance(info.value.__cause__, RemoteTraceback)
    assert "in _raise" in str(info.value.__cause__)
    with pytest.raises(RuntimeError, match="_Unpicklable: 1/2"):
        run_limited(_raise, ("other",), sandbox=LIMITS, name="child")


def test_a_dead_or_overdue_child_is_named() -> None:
    with pytest.raises(ChildFailed, match="killed by SIGKILL"):
        run_limited(_kill_self, sandbox=LIMITS, name="the trainer")
    start = time.monotonic()
    with pytest.raises(ChildFailed, match="the trainer took longer than 3 s"):
        run_limited(_sleep, (120.0,), sandbox=LIMITS, name="the trainer", timeout_s=3.0)
    assert time.monotonic() - start < 60.0


def test_a_large_answer_arrives_whole() -> None:
    assert run_limited(_large, sandbox=LIMITS, name="child") == _large()


def test_an_interrupt_of_the_caller_reaches_the_child_which_saves(tmp_path: Path) -> None:
    marker = tmp_path / "saved"

    def interrupt_once_started() -> None:
        while not Path(str(marker) + ".started").exists():
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGINT)  # reaches this process alone, as `kill -INT` does

    # Set here as the itskill command sets it: a test run started in the background by a
    # script inherits SIGINT ignored, and the interrupt would never come.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Thread(target=interrupt_once_started, daemon=True).start()
        with pytest.raises(KeyboardInterrupt):
            run_limited(
                _loop_until_interrupted, (str(marker),), sandbox=LIMITS, name="child", timeout_s=60
            )
    finally:
        signal.signal(signal.SIGINT, previous)
    assert marker.read_text() == "saved"


def _missing_checkpoint(path: str) -> None:
    from itskill.tasks.evaluate import CheckpointError

    raise CheckpointError(path, "missing: the directory holds no finished checkpoint")


def test_an_exception_whose_constructor_differs_from_its_args_keeps_its_type() -> None:
    # Pickle would rebuild it as CheckpointError(message) and fail: the caller could no longer
    # tell a user's missing checkpoint (one line) from a bug (a traceback).
    from itskill.tasks.evaluate import CheckpointError

    with pytest.raises(CheckpointError) as info:
        run_limited(_missing_checkpoint, ("/runs/x",), sandbox=LIMITS, name="child")
    assert info.value.path == "/runs/x" and str(info.value).startswith("/runs/x: missing")


def _disk_full(path: str) -> None:
    raise OSError(errno.ENOSPC, "No space left on device", path)


def test_an_os_error_in_the_child_keeps_its_errno_and_file_name() -> None:
    # It came back as "(28, 'No space left on device')" with no errno or path: the user was
    # not told which path, and a read-only disk was no longer recognised as a path problem.
    with pytest.raises(OSError) as info:
        run_limited(_disk_full, ("/runs/x/model.zip",), sandbox=LIMITS, name="child")
    assert (info.value.errno, info.value.filename) == (errno.ENOSPC, "/runs/x/model.zip")
    assert str(info.value) == "[Errno 28] No space left on device: '/runs/x/model.zip'"
