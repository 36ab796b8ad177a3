"""Checkpoint writes: Ctrl-C waits for a checkpoint being written, then acts as it would have."""

from __future__ import annotations

import os
import signal
import time

import pytest

from itskill.rl.checkpoint import interrupts_deferred


def _ctrl_c_during_block(done: list[str]) -> list[str]:
    with interrupts_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # a signal is handled between bytecodes: it would have struck here
        done.append("the whole block ran")
    done.append("after the block")
    return done


def test_ctrl_c_during_a_checkpoint_is_raised_once_it_is_written() -> None:
    # Set here: a test run started in the background inherits SIGINT ignored.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        done: list[str] = []
        with pytest.raises(KeyboardInterrupt):
            _ctrl_c_during_block(done)
        assert done == ["the whole block ran"]  # raised as the block ended, not inside it
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # put back
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_process_ignoring_ctrl_c_still_ignores_it_after_a_checkpoint() -> None:
    # A worker that already saved on its first Ctrl-C ignores the second one.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        assert _ctrl_c_during_block([]) == ["the whole block ran", "after the block"]
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)
