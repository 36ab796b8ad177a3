"""Reward generation (the paper's section III-A): plan a command, write rewards with a language
model, train candidates in parallel, feed their statistics back, keep the best.

- :mod:`itskill.reward.plan`: command -> validated :class:`TaskPlan`;
- :mod:`itskill.reward.generator`: K samples per iteration, code extraction, regeneration;
- :mod:`itskill.reward.probe`: each sample run on real contexts, in a limited child process;
- :mod:`itskill.reward.sandbox`: the only way generated code runs;
- :mod:`itskill.reward.candidate`: train and measure one candidate in its own process;
- :mod:`itskill.reward.feedback`: statistics of a candidate's training for the next prompt;
- :mod:`itskill.reward.search`: the optimisation loop, resumable, and its run directory;
- :mod:`itskill.reward.figure`: the Fig. 6 plot.

The names below are imported lazily, so that ``import itskill.reward.sandbox`` in a worker does not
pull in the trainer.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CandidateNetwork": "candidate",
    "PlanError": "plan",
    "TaskPlan": "plan",
    "check_command": "plan",
    "plan_command": "plan",
    "plan_for_task": "plan",
    "task_catalogue": "plan",
    "RewardSearchConfig": "search",
    "RewardSearchError": "search",
    "RewardSearchResult": "search",
    "generate_reward": "search",
    "load_search": "search",
    "load_search_config": "search",
    "search_client": "search",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"itskill.reward.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'itskill.reward' has no attribute {name!r}")
