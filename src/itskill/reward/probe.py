"""The probe: generated reward code run on a batch of real contexts before it is trained.

A sample is accepted once it compiles in the sandbox and returns finite ``(total, components)``
on every probe context within the sandbox's time limit (:func:`check_code`). :class:`Probe` runs
that check in a child process under the sandbox's process limits (``RLIMIT_AS``,
``RLIMIT_CPU``), as candidates train under them, so code that computes its way to a memory bomb
fails there with ``MemoryError`` instead of taking the search's own process (or the machine) with
it, and a sample that crashes or hangs its interpreter costs only the child, which is restarted
for the next sample. The child imports the sandbox and NumPy only: it starts in about a second.
"""

from __future__ import annotations

import multiprocessing
import signal
from typing import TYPE_CHECKING, Any

from itskill.reward.sandbox import (
    SandboxConfig,
    SandboxError,
    SandboxTimeout,
    SandboxViolation,
    apply_process_limits,
    compile_reward,
    death_cause,
)

if TYPE_CHECKING:  # the child imports nothing it does not use
    from itskill.sim.task import Context

NO_CODE = "the reply contains no code: write compute_reward(ctx) in a ```python fence"
_START_S = 60.0
"""Wall-clock allowance for the child's start and first answer, on top of the calls' own limits
(a spawned interpreter importing NumPy on a loaded 2-core machine)."""


def check_code(code: str, contexts: list[Context], sandbox: SandboxConfig) -> str | None:
    """Why ``code`` cannot be used (a message for the model), or None if it passes the probe.

    Runs the code in this process: :class:`Probe` calls it in its limited child.
    """
    if not code.strip():
        return NO_CODE
    try:
        reward = compile_reward(code, sandbox)
        for ctx in contexts:
            reward(ctx)  # the sandbox hands the code read-only views: ctx stays intact
    except SandboxViolation as err:
        return f"rejected by the sandbox: {err}"
    except SandboxTimeout as err:
        return f"timed out on the probe batch: {err}"
    except SandboxError as err:
        return f"failed on the probe batch: {err}"
    return None


class Probe:
    """:func:`check_code` on ``contexts`` in a child process under ``sandbox``'s limits.

    Use it as a context manager (or call :meth:`close`): the child lives from the first check to
    the close, so the contexts are sent once. A child that dies or stops answering is reported as
    the sample's failure and replaced at the next check.
    """

    def __init__(self, contexts: list[Context], sandbox: SandboxConfig) -> None:
        self.contexts, self.sandbox = contexts, sandbox
        # Every call may use its whole time limit, plus the module body's run.
        self.answer_s = sandbox.call_timeout_s * (len(contexts) + 1) + _START_S
        self._child: Any = None
        self._conn: Any = None

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def check(self, code: str) -> str | None:
        """Why ``code`` cannot be used, or None if it passes the probe."""
        if self._child is None:
            self._start()
        try:
            self._conn.send(code)
            if not self._conn.poll(self.answer_s):
                self.close()
                return f"timed out on the probe batch: no answer within {self.answer_s:g} s"
            return self._conn.recv()
        # The child died (this code, or killed from outside); a socket it closed with the code
        # unread resets the connection rather than ending it.
        except (EOFError, OSError):
            self._child.join(5.0)
            cause = death_cause(self._child.exitcode, self.sandbox, "the probe's process")
            self.close()
            return f"failed on the probe batch: {cause}"

    def close(self) -> None:
        """Stop the child (a later :meth:`check` starts a new one)."""
        if self._child is None:
            return
        self._conn.close()
        self._child.join(5.0)
        if self._child.is_alive():
            self._child.kill()
            self._child.join()
        self._child = self._conn = None

    def _start(self) -> None:
        context = multiprocessing.get_context("spawn")
        self._conn, child_end = context.Pipe()
        self._child = context.Process(
            target=_serve,
            args=(child_end, self.contexts, self.sandbox),
            name="reward-probe",
            daemon=True,
        )
        self._child.start()
        child_end.close()


def _serve(conn: Any, contexts: list[Context], sandbox: SandboxConfig) -> None:
    # Ctrl-C is the search's to handle: it closes this process with the probe.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    apply_process_limits(sandbox)
    while True:
        try:
            code = conn.recv()
        except EOFError:  # the search closed the probe, or died
            return
        conn.send(check_code(code, contexts, sandbox))
