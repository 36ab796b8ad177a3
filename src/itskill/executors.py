"""Run independent jobs in parallel: local worker processes by default, Ray for a cluster.

Pretraining skills, reward candidates and experiment cells are all "call this function with these
arguments, somewhere, and give me the result": :func:`run_jobs` does that and yields each result
as soon as it is finished, so callers write it to disk at once and a killed run loses only the jobs
in flight. A job that raises is reported with its exception, not raised, so one failure does not
take down the others. Ctrl-C stops the jobs in flight (each gets the ``KeyboardInterrupt``, so a
trainer saves its checkpoint) and starts none of the queued ones.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import socket
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Literal

Executor = Literal["local", "ray"]
EXECUTORS: tuple[str, ...] = ("local", "ray")


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop a command as Ctrl-C does: the training in progress saves first."""
_interrupted = False
_in_job = False
_RAY_STOP_S = 120.0
"""How long Ray tasks get to save a checkpoint after Ctrl-C before the shutdown ends them."""
_RAY_CONNECT_S = 10.0
"""How long :func:`check_executor` waits for a Ray address to accept a connection."""


class ExecutorError(RuntimeError):
    """The executor itself could not run (Ray missing or unreachable, bad name)."""


@dataclass(frozen=True)
class JobResult:
    """The outcome of one job: its index in the submitted list, its value or its error."""

    index: int
    value: Any = None
    error: BaseException | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def default_workers() -> int:
    """One job per core."""
    return max(1, os.cpu_count() or 1)


def run_jobs(
    fn: Callable[..., Any],
    jobs: Sequence[tuple[Any, ...]],
    executor: Executor = "local",
    workers: int | None = None,
    ray_address: str | None = None,
) -> Iterator[JobResult]:
    """Call ``fn(*args)`` for each ``args`` in ``jobs``; yield results in order of completion.

    ``local`` runs ``workers`` spawned processes (one job per core by default; spawned, not
    forked, so no thread pool or MuJoCo state is inherited; they show warnings as this process
    does when its ``warnings.showwarning`` can be pickled). ``ray`` submits ``ray.remote`` tasks
    to the cluster at ``ray_address``, or to a local Ray instance when it is None, keeping at most
    ``workers`` of them in flight (all of them when None: Ray then schedules them by free CPUs).
    """
    check_executor(executor, workers, ray_address)
    if executor == "local":
        yield from _run_local(fn, jobs, workers or default_workers())
    else:
        yield from _run_ray(fn, jobs, ray_address, workers)


def check_executor(
    executor: str, workers: int | None = None, ray_address: str | None = None
) -> None:
    """Raise :class:`ExecutorError` now for settings :func:`run_jobs` would fail on later: an
    unknown executor, fewer than one worker, the Ray executor without Ray installed, an empty
    Ray address, a Ray address with the local executor, or one where
    nothing listens (Ray itself retries such an address for minutes before giving up)."""
    if executor not in EXECUTORS:
        raise ExecutorError(f"unknown executor {executor!r}; expected one of {EXECUTORS}")
    if workers is not None and workers < 1:
        raise ExecutorError(f"workers must be at least 1, got {workers}")
    if executor == "ray":
        _ray()  # before a search plans and pays for its first samples
    if ray_address is None:
        return
    if not ray_address.strip():
        # A variable that expanded to nothing: Ray fails on it only once the first jobs start.
        raise ExecutorError(
            "the Ray address is empty: leave --ray-address out for a local Ray instance, or "
            "name the cluster's head node (HOST:PORT, ray://HOST:PORT or auto)"
        )
    if executor == "local":
        # Silently training on this machine when the user named a cluster would waste hours.
        raise ExecutorError(
            f"a Ray address ({ray_address}) needs the Ray executor (--executor ray)"
        )
    host, _, port = ray_address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return  # "auto" and the like: Ray resolves them itself
    try:
        socket.create_connection((host, int(port)), timeout=_RAY_CONNECT_S).close()
    except OSError as err:
        raise ExecutorError(
            f"could not reach Ray at {ray_address}: {err.strerror or err}; is the cluster's head "
            "node running (`ray start --head`) and the address right?"
        ) from err


def _run_local(fn, jobs, workers: int) -> Iterator[JobResult]:
    if workers == 1:
        # In-process: easier to debug and no start-up cost.
        for i, args in enumerate(jobs):
            try:
                yield JobResult(i, value=fn(*args))
            except Exception as err:
                yield JobResult(i, error=err)
        return
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context,
        initializer=_init_worker,
        initargs=(os.getpid(), showwarning_payload()),
    )
    try:
        pending: dict[Future, int] = {}
        for i, args in enumerate(jobs):
            try:
                payload = pickle.dumps((fn, args))
            except Exception as err:  # an argument that cannot travel fails its job alone
                yield JobResult(i, error=err)
                continue
            pending[pool.submit(_run_job, payload)] = i
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                index = pending.pop(future)
                error = future.exception()
                yield JobResult(index, value=None if error else future.result(), error=error)
    except BaseException:
        # Ctrl-C (or a caller that stopped reading): cancel the queue and interrupt the workers,
        # as a terminal's Ctrl-C would; `kill` reaches this process alone. Without this the
        # pool's shutdown below would train every queued job before returning.
        pool.shutdown(wait=False, cancel_futures=True)
        for child in multiprocessing.active_children():
            stop_child(child.pid)
        raise
    finally:
        pool.shutdown(wait=True)


def stop_child(pid: int) -> None:
    """Ask process ``pid``, one this process started, to stop as on Ctrl-C (it saves first).

    The signal is SIGINT, the one a terminal's Ctrl-C sends the child too, so that the two make
    one stop (with SIGTERM forwarded beside a terminal's SIGINT, a worker whose main thread slept
    in a system call did not stop; tests/test_executors.py). Where this process ignores SIGINT,
    so does the child it spawned (a command started in the background of a script, `cmd &`): it
    is sent SIGTERM, which it handles, or it would train on to the end of its job, unsaved, while
    this process waited for it.
    """
    ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM if ignored else signal.SIGINT)


def stop_on_first_interrupt() -> None:
    """Make SIGINT, SIGTERM and SIGHUP raise ``KeyboardInterrupt`` once in this process and be
    ignored after that.

    A worker may get Ctrl-C twice (from the terminal, and forwarded by its parent); the second
    must not cut short the checkpoint the first one made it save. SIGTERM (a scheduler stopping
    the whole process group, `kill`) and SIGHUP (the terminal closed) stop it the same way
    instead of ending it unsaved. A process started with SIGTERM or SIGHUP ignored (SIGHUP
    under `nohup`, SIGINT in a background job of a script) keeps ignoring it, as the process
    that started it does: a Ctrl-C that this whole tree ignores must not stop its workers alone.
    """
    _install(_interrupt_once)


def _install(handler: Callable[[int, Any], None]) -> None:
    """``handler`` for a worker's or child's stop signals (:func:`stop_on_first_interrupt`)."""
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, handler)


def _interrupt_once(signum: int, frame: Any) -> None:
    global _interrupted
    if not _interrupted:
        _interrupted = True
        raise KeyboardInterrupt


def _interrupt_job(signum: int, frame: Any) -> None:
    """A pool worker's handler: as :func:`_interrupt_once` inside a job; outside one (starting
    up, waiting for the next) the stop is only noted, and the job it is then handed is refused.
    Raised there, it would end the worker with a traceback on the terminal."""
    global _interrupted
    if not _interrupted:
        _interrupted = True
        if _in_job:
            raise KeyboardInterrupt


def showwarning_payload() -> bytes | None:
    """This process's ``warnings.showwarning`` pickled for the processes it spawns, so that they
    show warnings as it does (the command's one-line format of itskill's own); None when it
    cannot travel (a lambda, say). A function is pickled by its name: this module need not
    import the command's."""
    try:
        return pickle.dumps(warnings.showwarning)
    except Exception:
        return None


def install_showwarning(payload: bytes | None) -> None:
    """In a spawned process, show warnings as the parent does (:func:`showwarning_payload`).

    A spawned process starts with Python's own display; how a warning looks is not worth the
    process (a pool's worker that fails its initializer breaks the whole pool), so one that
    cannot be loaded is left as it is."""
    if payload is not None:
        with contextlib.suppress(Exception):
            warnings.showwarning = pickle.loads(payload)


def _init_worker(parent: int, showwarning: bytes | None) -> None:
    _install(_interrupt_job)
    exit_with_parent(parent)
    install_showwarning(showwarning)


def _run_job(payload: bytes) -> Any:
    global _in_job
    _in_job = True
    try:
        if _interrupted:
            # Stopped before it began: handed to this worker after Ctrl-C (a pool queues a
            # job per worker ahead) or while the worker was starting.
            raise KeyboardInterrupt
        # Unpickled here, not by the pool, so the seconds of importing the job's modules
        # (torch, MuJoCo) count as the job and a Ctrl-C there ends it as it ends a running one.
        fn, args = pickle.loads(payload)
        return fn(*args)
    finally:
        _in_job = False


def exit_with_parent(parent: int, poll_s: float = 1.0) -> None:
    """End this worker when the process that started it is gone.

    A parent killed by SIGTERM or SIGKILL runs no clean-up, and its pool workers would otherwise
    go on training (and holding the cores) with nobody to collect their results.
    """

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _call(fn: Callable[..., Any], *args: Any) -> Any:
    """Ray's remote wrapper: ``ray.remote`` takes only Python functions, not builtins."""
    return fn(*args)


def _ray() -> Any:
    """The ``ray`` module; :class:`ExecutorError` saying how to install it if it is missing."""
    try:
        import ray
    except ImportError as err:
        raise ExecutorError(
            "executor 'ray' needs Ray: pip install 'ray>=2.9' (or use --executor local)"
        ) from err
    return ray


def _run_ray(fn, jobs, address: str | None, workers: int | None) -> Iterator[JobResult]:
    ray = _ray()
    started_here = not ray.is_initialized()
    if started_here:
        # ray.init makes SIGTERM a SystemExit for the rest of the process; a SIGTERM must stay a
        # KeyboardInterrupt here, which cancels the tasks below and ends with the resume hint.
        handler = signal.getsignal(signal.SIGTERM)
        try:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as err:
            where = address or "a local instance"
            raise ExecutorError(f"could not start or reach Ray at {where}: {err}") from err
        finally:
            if handler is not None:
                signal.signal(signal.SIGTERM, handler)
    pending: dict = {}
    try:
        remote = ray.remote(_call)
        queue = list(enumerate(jobs))
        in_flight = len(queue) if workers is None else workers
        while queue or pending:
            while queue and len(pending) < in_flight:
                index, args = queue.pop(0)
                pending[remote.remote(fn, *args)] = index
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                index = pending.pop(ref)
                try:
                    result = JobResult(index, value=ray.get(ref))
                except ray.exceptions.RayTaskError as err:
                    result = JobResult(index, error=err.as_instanceof_cause())
                except ray.exceptions.RayError as err:
                    # The job's worker or node was lost (crashed, killed for memory): this job
                    # failed, the others go on.
                    result = JobResult(index, error=err)
                yield result
    except BaseException:
        # Ctrl-C (or a caller that stopped reading): a non-forced cancel raises
        # KeyboardInterrupt in each running task, so a trainer saves its checkpoint before the
        # shutdown below ends its worker.
        for ref in pending:
            ray.cancel(ref)
        if pending:
            ray.wait(list(pending), num_returns=len(pending), timeout=_RAY_STOP_S)
        raise
    finally:
        if started_here:
            ray.shutdown()
