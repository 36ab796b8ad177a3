"""Search settings for the reward-loop tests: a budget that trains a candidate in seconds.

A module of its own (not conftest.py) so that tests import it by a name no other test folder
uses: ``conftest`` is one module name for every folder, and the first one imported wins.
"""

from __future__ import annotations

from typing import Any

from itskill.reward.config import RewardSearchConfig, load_search_config

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


def tiny_config(**overrides: Any) -> RewardSearchConfig:
    """The tiny budget, with ``overrides`` on top."""
    return load_search_config(overrides={**TINY, **overrides})
