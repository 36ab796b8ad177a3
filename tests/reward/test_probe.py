"""The probe: generated code is checked on real contexts in a limited child process."""

from __future__ import annotations

import pytest
from replies import GOOD

from itskill.reward.generator import extract_code, probe_contexts
from itskill.reward.probe import Probe
from itskill.reward.sandbox import SandboxConfig, compile_reward

# 2 probe envs x 1.5e8 float64: 2.4 GB, computed from the context, so no static check sizes it.
COMPUTED_BOMB = """
import numpy as np

def compute_reward(ctx):
    n = ctx["time_frac"].shape[0] * 150_000_000
    big = np.ones(n)
    return ctx["time_frac"] + big[:1], {}
"""


@pytest.fixture(scope="module")
def contexts():
    return probe_contexts("pick_nut_m12", num_envs=2, steps=2)


def test_good_and_broken_code(contexts) -> None:
    with Probe(contexts, SandboxConfig(call_timeout_s=2.0)) as probe:
        assert probe.check(extract_code(GOOD)) is None
        assert "KeyError: 'nope'" in probe.check(
            "def compute_reward(ctx):\n    return ctx['nope'], {}"
        )
        assert "import 'os' is not allowed" in probe.check("import os\n")
        assert "contains no code" in probe.check("   ")


def test_a_computed_memory_bomb_fails_in_the_limited_child(contexts) -> None:
    compile_reward(COMPUTED_BOMB, SandboxConfig())  # the static checks let it through
    limits = SandboxConfig(call_timeout_s=5.0, memory_limit_mb=1024)
    with Probe(contexts, limits) as probe:
        # 2.4 GB would fit this machine: only the child's address-space limit stops it.
        assert "ran out of memory" in probe.check(COMPUTED_BOMB)
        assert probe.check(extract_code(GOOD)) is None


def test_a_dead_child_is_reported_and_replaced(contexts) -> None:
    with Probe(contexts, SandboxConfig(call_timeout_s=2.0)) as probe:
        assert probe.check(extract_code(GOOD)) is None
        probe._child.kill()  # as the kernel's OOM killer would
        probe._child.join()
        assert "killed by SIGKILL (out of memory?)" in probe.check(extract_code(GOOD))
        assert probe.check(extract_code(GOOD)) is None


def test_a_child_that_dies_before_reading_the_code_is_reported(contexts) -> None:
    # Its socket closed with the code unread: the search stopped on ConnectionResetError.
    with Probe(contexts, SandboxConfig(call_timeout_s=2.0)) as probe:
        probe._start()
        conn, send = probe._conn, probe._conn.send

        def send_then_die(code: str) -> None:
            send(code)
            probe._child.kill()
            probe._child.join()

        conn.send = send_then_die
        assert "failed on the probe batch" in probe.check(extract_code(GOOD))
        assert probe.check(extract_code(GOOD)) is None


def test_a_child_that_does_not_answer_is_stopped(contexts) -> None:
    with Probe(contexts, SandboxConfig(call_timeout_s=2.0)) as probe:
        probe.answer_s = 0.001  # less than a spawned interpreter needs to start
        message = probe.check(extract_code(GOOD))
        assert message is not None and "no answer within" in message
        assert probe._child is None
