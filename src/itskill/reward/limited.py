"""A function run in a child process under the sandbox's process limits.

Whatever trains with generated reward code runs through :func:`run_limited`: a reward candidate
(:mod:`itskill.reward.candidate`) and the trainings after the search
(:mod:`itskill.experiments.sandboxed`: ``itskill learn``'s final one, an experiment's cells).
The child is a fresh spawned interpreter whose address space and CPU time are capped
(:func:`~itskill.reward.sandbox.apply_process_limits`), so code that computes its way to a memory
bomb on some state the static checks could not foresee fails there with ``MemoryError`` and takes
down nothing else. The caller's process keeps its own limits, and gets back the function's value,
its exception, or why the child died.

Interruptions: a Ctrl-C in a terminal reaches the child as well (same process group); one that
reaches only the caller (`kill`, or a stop its own parent forwarded) is passed on
(:func:`~itskill.executors.stop_child`). Either way
the child stops the way a training does on Ctrl-C (it saves) and the caller raises
``KeyboardInterrupt`` once the child has ended.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from itskill.executors import (
    exit_with_parent,
    install_showwarning,
    showwarning_payload,
    stop_child,
    stop_on_first_interrupt,
)
from itskill.reward.sandbox import SandboxConfig, apply_process_limits, death_cause

INTERRUPTED = 130
"""Exit code of a child stopped by Ctrl-C (as a shell reports SIGINT)."""
_SAVE_S = 60.0
"""How long an interrupted child is given to save before it is killed."""


class ChildFailed(RuntimeError):
    """The child ended without an answer: killed (a limit, a signal) or past its time limit."""


class RemoteTraceback(Exception):
    """The child's traceback, chained to the exception re-raised in the caller."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return self.text


def run_limited(
    fn: Callable[..., Any],
    args: Sequence[Any] = (),
    *,
    sandbox: SandboxConfig,
    name: str,
    timeout_s: float | None = None,
) -> Any:
    """``fn(*args)`` in a spawned child under ``sandbox``'s process limits; its return value.

    ``fn`` and ``args`` must be picklable (``fn`` a module-level function). An exception ``fn``
    raises is raised here, of its own type, chained to a :class:`RemoteTraceback` (as a
    ``RuntimeError`` naming its type if its attributes cannot be pickled). :class:`ChildFailed`
    says why a child that died or ran past ``timeout_s`` (wall clock) gave no answer; ``name``
    is the child in its message ("the candidate's process").
    """
    spawn = multiprocessing.get_context("spawn")
    receiver, sender = spawn.Pipe(duplex=False)
    child = spawn.Process(
        target=_child_main,
        args=(sender, pickle.dumps((fn, tuple(args))), sandbox, os.getpid(), showwarning_payload()),
        name=name,
    )
    child.start()
    sender.close()  # the child holds the only sending end: EOF here once it is gone
    try:
        answer = _wait(child, receiver, name, timeout_s)
    except KeyboardInterrupt:
        stop_child(child.pid)
        child.join(_SAVE_S)
        if child.is_alive():
            child.kill()
        raise
    finally:
        receiver.close()
    child.join()
    if answer is None:
        if child.exitcode == INTERRUPTED:
            raise KeyboardInterrupt
        raise ChildFailed(death_cause(child.exitcode, sandbox, name))
    if answer[0] == "error":
        raise _unpack(answer[1]) from RemoteTraceback(answer[2])
    return answer[1]


def _wait(child: Any, receiver: Any, name: str, timeout_s: float | None) -> tuple | None:
    """The child's answer, or None if it ended without one."""
    start, parent = time.monotonic(), os.getppid()
    while True:
        # Read while waiting: a large answer fills the pipe and the child blocks until it is read.
        if receiver.poll(1.0):
            try:
                return receiver.recv()
            except (EOFError, OSError):  # gone, perhaps in the middle of its answer
                return None
        if not child.is_alive():
            return receiver.recv() if receiver.poll() else None
        if os.getppid() != parent and multiprocessing.parent_process() is not None:
            # This is a worker whose own parent is gone (kill -9): leave no orphan training.
            child.kill()
            os._exit(1)
        if timeout_s is not None and time.monotonic() - start > timeout_s:
            child.kill()
            child.join()
            raise ChildFailed(f"timed out: {name} took longer than {timeout_s:g} s (wall clock)")


def _pack(err: BaseException) -> Any:
    """``err`` in a form that crosses the pipe as it was: its type, ``args`` and attributes.

    Pickling an exception rebuilds it as ``type(err)(*err.args)``, which fails, or builds another
    message, for an exception whose constructor takes other arguments than its ``args``
    (``CheckpointError(path, problem)``). An OSError goes as pickle sends it: its errno,
    message and file name are set by its constructor alone, from the arguments pickle keeps. A
    RuntimeError naming it where even that cannot travel.
    """
    if isinstance(err, OSError):
        try:
            copy = pickle.loads(pickle.dumps(err))
        except Exception:
            return RuntimeError(f"{type(err).__name__}: {err}")
        if str(copy) == str(err):
            return copy
    packed = (type(err), err.args, dict(vars(err)))
    try:
        pickle.loads(pickle.dumps(packed))
    except Exception:
        return RuntimeError(f"{type(err).__name__}: {err}")
    return packed


def _unpack(packed: Any) -> BaseException:
    if isinstance(packed, BaseException):
        return packed
    kind, args, state = packed
    err = kind.__new__(kind)
    err.args = args
    vars(err).update(state)
    return err


def _child_main(
    sender: Any,
    payload: bytes,
    sandbox: SandboxConfig,
    parent_pid: int,
    showwarning: bytes | None,
) -> None:
    stop_on_first_interrupt()
    exit_with_parent(parent_pid)
    try:
        # Unpickled once the handlers are in place: the warning display and the function import
        # their modules (the command's; torch, MuJoCo: seconds), and a Ctrl-C then must end the
        # child quietly, not with a traceback.
        install_showwarning(showwarning)
        fn, args = pickle.loads(payload)
        apply_process_limits(sandbox)
        answer: tuple = ("ok", fn(*args))
    except KeyboardInterrupt:
        os._exit(INTERRUPTED)  # no answer: the caller raises KeyboardInterrupt
    except Exception as err:
        answer = ("error", _pack(err), traceback.format_exc())
    sender.send(answer)
