"""One observation layout for every task, described slice by slice.

A skill learned on one task can be a transfer source for another only if both see the same vector,
so every task fills the same named slices from the reward context (unused slots are zero with mask
0). ``ObservationLayout.describe()`` prints the table that docs/simulation.md shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from itskill.sim.context import MAX_FIXTURES, MAX_OBJECTS

MAX_STAGES = 8
OBSERVATION_VERSION = 2
"""Raised whenever what a slice holds changes without the vector's size changing, which a
policy trained on the old values cannot notice: checkpoints record it, and one of another
version is refused. 2 (2026-12-06): in a scene without fixtures, each part's ``to_fix`` and
``yaw_error`` read zero (before, they measured to a fixture at the robot's base). Checkpoints
from before versions were recorded hold none, and load: every packaged task has a fixture, so
their observations did not change."""


@dataclass(frozen=True)
class Slice:
    """One named block of the observation vector."""

    name: str
    size: int
    frame: str
    unit: str
    start: int = 0

    @property
    def stop(self) -> int:
        return self.start + self.size


def _blocks() -> list[tuple[str, int, str, str]]:
    blocks = [
        ("ee_pos", 3, "world", "m"),
        ("ee_yaw_sincos", 2, "world", "-"),
        ("ee_vel", 3, "world", "m/s"),
        ("gripper_width", 1, "-", "m"),
        ("grip_closed", 1, "-", "0/1"),
    ]
    for i in range(MAX_OBJECTS):
        blocks += [
            (f"obj{i}_pos", 3, "world", "m"),
            (f"obj{i}_yaw_sincos", 2, "world", "-"),
            (f"obj{i}_tilt", 1, "-", "rad"),
            (f"obj{i}_to_ee", 3, "world", "m"),
            (f"obj{i}_size", 2, "-", "m (width, height)"),
            (f"obj{i}_grasped", 1, "-", "0/1"),
            (f"obj{i}_mask", 1, "-", "0/1"),
        ]
    for j in range(MAX_FIXTURES):
        blocks += [
            (f"fix{j}_pos", 3, "world", "m"),
            (f"fix{j}_yaw_sincos", 2, "world", "-"),
            (f"fix{j}_mask", 1, "-", "0/1"),
        ]
    for i in range(MAX_OBJECTS):
        blocks += [
            (f"obj{i}_to_fix", 3, "world", "m"),
            (f"obj{i}_yaw_error", 1, "-", "rad"),
            (f"obj{i}_engaged", 1, "-", "0/1"),
            (f"obj{i}_insertion_depth", 1, "-", "m"),
        ]
    blocks += [("stage_onehot", MAX_STAGES, "-", "0/1"), ("time_frac", 1, "-", "0..1")]
    return blocks


class ObservationLayout:
    """The observation vector as named slices; ``build`` fills it from a reward context."""

    def __init__(self) -> None:
        slices, start = [], 0
        for name, size, frame, unit in _blocks():
            slices.append(Slice(name, size, frame, unit, start))
            start += size
        self.slices: tuple[Slice, ...] = tuple(slices)
        self.size = start
        self._by_name = {s.name: s for s in self.slices}

    def __getitem__(self, name: str) -> slice:
        s = self._by_name[name]
        return slice(s.start, s.stop)

    def describe(self) -> str:
        rows = [f"| {s.name} | {s.start}:{s.stop} | {s.frame} | {s.unit} |" for s in self.slices]
        return "\n".join(["| slice | indices | frame | unit |", "|---|---|---|---|", *rows])

    def build(self, ctx: dict[str, np.ndarray]) -> np.ndarray:
        """Observation (N, size) float32 from the context of N environments."""
        n = ctx["ee_pos"].shape[0]
        obs = np.zeros((n, self.size), dtype=np.float32)

        def put(name: str, value: np.ndarray) -> None:
            obs[:, self[name]] = np.reshape(value, (n, -1))

        def sincos(angle: np.ndarray) -> np.ndarray:
            return np.stack([np.sin(angle), np.cos(angle)], -1)

        put("ee_pos", ctx["ee_pos"])
        put("ee_yaw_sincos", sincos(ctx["ee_yaw"]))
        put("ee_vel", ctx["ee_vel"])
        put("gripper_width", ctx["gripper_width"])
        put("grip_closed", ctx["grip_closed"])
        for i in range(MAX_OBJECTS):
            mask = ctx["obj_mask"][:, i : i + 1]
            put(f"obj{i}_pos", ctx["obj_pos"][:, i])
            put(f"obj{i}_yaw_sincos", sincos(ctx["obj_yaw"][:, i]) * mask)
            put(f"obj{i}_tilt", ctx["obj_tilt"][:, i])
            put(f"obj{i}_to_ee", ctx["obj_to_ee"][:, i])
            put(f"obj{i}_size", np.stack([ctx["obj_width"][:, i], ctx["obj_height"][:, i]], -1))
            put(f"obj{i}_grasped", ctx["grasped"][:, i])
            put(f"obj{i}_mask", mask)
            put(f"obj{i}_to_fix", ctx["obj_to_fix"][:, i])
            put(f"obj{i}_yaw_error", ctx["yaw_error"][:, i])
            put(f"obj{i}_engaged", ctx["engaged"][:, i])
            put(f"obj{i}_insertion_depth", ctx["insertion_depth"][:, i])
        for j in range(MAX_FIXTURES):
            mask = ctx["fix_mask"][:, j : j + 1]
            put(f"fix{j}_pos", ctx["fix_pos"][:, j])
            put(f"fix{j}_yaw_sincos", sincos(ctx["fix_yaw"][:, j]) * mask)
            put(f"fix{j}_mask", mask)
        onehot = np.zeros((n, MAX_STAGES), dtype=np.float32)
        onehot[np.arange(n), np.clip(ctx["stage"], 0, MAX_STAGES - 1).astype(int)] = 1.0
        put("stage_onehot", onehot)
        put("time_frac", ctx["time_frac"])
        return obs


OBSERVATION_LAYOUT = ObservationLayout()
