"""Shared helpers for the reward-loop tests: a tiny search budget, the fake OpenAI server."""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

# The local OpenAI-compatible server of the llm tests (tests/llm/fake_openai.py).
sys.path.insert(0, str(Path(__file__).parents[1] / "llm"))

TINY: dict[str, Any] = {
    "iterations": 1,
    "samples": 2,
    "steps": 128,  # one PPO rollout of 64 steps x 2 environments
    "num_envs": 2,
    "evaluations": 1,
    "eval_episodes": 2,
    "correlation_envs": 2,
    "select_top": 0,
    "final_seeds": 1,
    "workers": 2,
    "max_regenerations": 1,
    "probe_envs": 2,
    "probe_steps": 4,
    "candidate_timeout_s": 300.0,
    "sandbox": {"call_timeout_s": 0.5, "cpu_limit_s": 600, "memory_limit_mb": 4096},
}
"""Search settings that train a candidate in seconds (nothing is learned at this budget)."""

TINY_TOML = """\
[search]
iterations = 1
samples = 3
steps = 128
num_envs = 2
evaluations = 1
eval_episodes = 2
correlation_envs = 2
select_top = 0
final_seeds = 1
max_regenerations = 1
probe_envs = 2
probe_steps = 4
candidate_timeout_s = 300.0

[sandbox]
call_timeout_s = 0.5
memory_limit_mb = 4096
"""
"""The same budget as a settings file, for the command line (``--config``)."""


@pytest.fixture
def quiet() -> Console:
    """A console that keeps the search's progress out of the test output."""
    return Console(file=io.StringIO(), width=120)


def tiny_config(**overrides: Any):
    from itskill.reward.config import load_search_config

    return load_search_config(overrides={**TINY, **overrides})
