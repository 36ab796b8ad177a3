"""What the simulator needs to know about a task, independent of where the task came from.

``itskill.tasks`` builds these from the TOML task files; users can build their own directly.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from itskill.sim.scene import SceneSpec

Context = Mapping[str, np.ndarray]
"""Named batched arrays describing N environments (see :mod:`itskill.sim.context`)."""
RewardFn = Callable[[Context], tuple[np.ndarray, dict[str, np.ndarray]]]
"""``compute_reward(ctx) -> (total[N], {component: [N]})``."""
Predicate = Callable[[Context], np.ndarray]


@dataclass(frozen=True)
class Range:
    """A uniform interval; ``low == high`` is a constant."""

    low: float
    high: float

    def __post_init__(self) -> None:
        if self.high < self.low:
            raise ValueError(f"range [{self.low}, {self.high}] has high < low")

    def sample(self, rng: np.random.Generator) -> float:
        return float(self.low if self.low == self.high else rng.uniform(self.low, self.high))


@dataclass(frozen=True)
class ObjectInit:
    """Where a part starts.

    - ``table``: lying on the table at (x, y) with yaw.
    - ``gripper``: held between the fingers, the grip point at (x, y, z) and the part's centre
      ``hold`` metres above it (a part picked from the table is rarely held at its middle).
    - ``fingers``: standing on the table between the open fingers, the grip point at (x, y, z).
      In either hand mode the part faces the pads; with ``symmetric_yaw`` it is also turned by a
      random one of its symmetries (:func:`itskill.sim.batch.symmetry_turn`), so the fingers
      meet the same faces but its yaw is as varied as that of a part picked from the table.
    - ``bolt``: threaded on fixture ``fixture``, its bottom ``turns`` pitches above the seat.
    - ``hole``: standing in fixture ``fixture``'s hole, inserted ``depth`` metres.
    """

    mode: Literal["table", "gripper", "fingers", "bolt", "hole"]
    x: Range = Range(0.0, 0.0)
    y: Range = Range(0.0, 0.0)
    z: Range = Range(0.0, 0.0)
    yaw: Range = Range(0.0, 0.0)
    turns: Range = Range(0.0, 0.0)
    depth: Range = Range(0.0, 0.0)
    hold: Range = Range(0.0, 0.0)
    fixture: int = 0
    symmetric_yaw: bool = False


HAND_MODES = ("gripper", "fingers")
"""Start modes that put the grip point at the part (at most one object per start)."""


@dataclass(frozen=True)
class InitSpec:
    """Initial-state distribution: the grip point's start and each part's start."""

    ee_x: Range = Range(0.45, 0.45)
    ee_y: Range = Range(0.0, 0.0)
    ee_z: Range = Range(0.2, 0.2)
    ee_yaw: Range = Range(0.0, 0.0)
    objects: tuple[ObjectInit, ...] = ()


@dataclass(frozen=True)
class TrainingStart:
    """A start used only while training: a share of training episodes begin from ``init``.

    Used to start some episodes where a later subtask begins (the part already in the fingers), so
    the learner meets that subtask's reward before it can reach it on its own; evaluation always
    uses the task's own start.
    """

    init: InitSpec
    share: float
    name: str = ""

    def __post_init__(self) -> None:
        if not 0.0 < self.share < 1.0:
            raise ValueError(f"expected 0 < share < 1, got {self.share}")


def check_start_shares(starts: tuple[TrainingStart, ...]) -> None:
    """Training starts must leave some episodes to the task's own start."""
    total = sum(s.share for s in starts)
    if total >= 1.0:
        raise ValueError(f"training start shares must sum to less than 1, got {total:g}")


def default_object_fixture(n_objects: int, n_fixtures: int) -> tuple[int, ...]:
    """The fixture each object is meant for when a task does not say: the one of the same index,
    the last fixture for objects beyond them, fixture 0 where there are none."""
    return tuple(min(i, max(n_fixtures - 1, 0)) for i in range(n_objects))


@dataclass(frozen=True)
class SimTask:
    """A task as the simulator sees it.

    ``stage_fn`` returns each environment's current subtask index (0-based, < ``n_stages``),
    ``success_fn`` whether it has succeeded, and ``reward_fn`` (optional) the reward; all take the
    reward context of the current state. ``object_fixture[i]`` names the fixture that object ``i``
    is meant for (its offset to that fixture appears in observations; empty:
    :func:`default_object_fixture`). ``training_starts`` are
    drawn instead of ``init`` by environments built for training (see ``BatchEnv``).
    """

    name: str
    scene: SceneSpec
    init: InitSpec
    max_steps: int
    n_stages: int
    stage_fn: Predicate
    success_fn: Predicate
    reward_fn: RewardFn | None = None
    object_fixture: tuple[int, ...] = field(default=())
    terminate_on_success: bool = False
    training_starts: tuple[TrainingStart, ...] = ()

    def __post_init__(self) -> None:
        try:
            check_start_shares(self.training_starts)
        except ValueError as err:
            raise ValueError(f"{self.name}: {err}") from None
