"""What a reward callable must return: ``compute_reward(ctx) -> (total[N], {component: [N]})``.

One check for every reward that does not come from itskill itself: a user's reward file
(:func:`itskill.rl.train.load_reward`) and generated code (:mod:`itskill.reward.sandbox`). It
imports NumPy only, so the sandbox's worker processes stay quick to start.
"""

from __future__ import annotations

from typing import Any

import numpy as np

EXPERT = "expert"
"""The reward name that picks the task's own human-designed reward
(:func:`itskill.tasks.rewards.expert_reward`) wherever a reward file may be given."""

LOG_COLUMNS = (
    "step",
    "wall_s",
    "updates",
    "episodes",
    "success_rate",
    "ep_return",
    "ep_length",
    "steps_per_s",
)
"""The training log's own columns (``metrics.csv``), which a reward component beside them may
not be named: ``step`` is what a resumed run truncates the log by."""

EPISODE_RETURN = "episode_return"
"""The name the reward search's feedback gives the episode return beside the components, so no
component may take it either."""


class RewardOutputError(ValueError):
    """A reward callable's result that breaks the contract; the message says how."""


REWARD_MAGNITUDE_MAX = 1e9
"""The largest reward or component value a reward may return, either sign: far above any
sensible reward, far below float32's 3.4e38, past which the training environment's float32
rewards turn to inf and the reward normalisation's statistics to nan."""


def _finite_vector(value: Any, n: int, what: str) -> np.ndarray:
    if isinstance(value, list | tuple) and any(
        isinstance(v, list | tuple | dict | set) for v in value
    ):
        # Nested containers are no vector, and NumPy's conversion of a list that holds itself
        # ran for hours in C, where no time limit reaches.
        raise RewardOutputError(
            f"{what} is a {type(value).__name__} of containers; expected {n} numbers, one per "
            "environment"
        )
    try:
        array = np.array(value, dtype=np.float64)  # a copy: never a view of the context
    except (TypeError, ValueError, OverflowError) as err:
        # NumPy's message quotes the value, which may be megabytes of it.
        why = str(err)[:200]
        raise RewardOutputError(f"{what} is not numeric: {type(value).__name__} ({why})") from err
    if array.shape != (n,):
        raise RewardOutputError(
            f"{what} has shape {array.shape}; expected ({n},), one per environment"
        )
    if not np.all(np.isfinite(array)):
        bad = int(np.sum(~np.isfinite(array)))
        raise RewardOutputError(f"{what} has {bad} non-finite value(s) (nan or inf)")
    if np.any(np.abs(array) > REWARD_MAGNITUDE_MAX):
        largest = np.abs(array).max()
        raise RewardOutputError(
            f"{what} has values beyond ±{REWARD_MAGNITUDE_MAX:g} (largest {largest:g}); scale the "
            "reward down"
        )
    return array


COMPONENTS_MAX = 64
"""The most components a reward may return: each is a column of every training log row and a
line of the feedback sent back to the language model."""
COMPONENT_NAME_MAX = 100
"""The longest component name: a name of 100,000 characters made a feedback prompt of 20 million,
and one past 131,072 a ``metrics.csv`` that Python's CSV reader refuses."""


def check_reward_output(result: Any, n: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``result`` of a reward call on ``n`` environments, checked and converted to float64:
    ``(total, components)`` with a finite value per environment in each array, or
    :class:`RewardOutputError`."""
    if not isinstance(result, tuple) or len(result) != 2:
        raise RewardOutputError(
            f"compute_reward must return (total, components); got {type(result).__name__}"
        )
    total, components = result
    total = _finite_vector(total, n, "total")
    if not isinstance(components, dict):
        raise RewardOutputError(f"components must be a dict; got {type(components).__name__}")
    if len(components) > COMPONENTS_MAX:
        raise RewardOutputError(
            f"{len(components)} components; at most {COMPONENTS_MAX} (one per reward term)"
        )
    checked = {}
    for key, value in components.items():
        if not isinstance(key, str):
            raise RewardOutputError(f"component names must be strings; got {type(key).__name__}")
        if len(key) > COMPONENT_NAME_MAX or not key.isprintable() or not key:
            raise RewardOutputError(
                f"component name {key[:40]!r}{'...' if len(key) > 40 else ''} must be 1 to "
                f"{COMPONENT_NAME_MAX} printable characters"
            )
        if key in LOG_COLUMNS or key == EPISODE_RETURN:
            raise RewardOutputError(
                f"component name {key!r} is taken by the training log; use another name"
            )
        checked[key] = _finite_vector(value, n, f"components[{key!r}]")
    return total, checked
