"""Expert (human-designed) rewards: the baseline that LLM-generated rewards are compared against.

One reward recipe serves every task. It is built from the task's data, not written per task:

* The task's stages say which subtask an environment is in (``ctx["stage"]``). Each stage's
  ``done`` predicate names what the subtask must achieve (``near``, ``grasped``, ``lifted``,
  ``above_fixture``, ``engaged``, ``seated``, ``inserted``, ``removed``, ``displaced``, ...), and
  its arguments (object slot, heights, tolerances, push offsets) parameterise the shaping.
* Every predicate name maps to a *term function* that returns dense shaping terms in [0, 1] which
  reach 1 when the predicate holds (closeness of the grip point to the part, part height up to the
  target, closeness of the part's bottom to its fixture point, yaw alignment, thread travel, ...).
* Only the current stage's terms are paid, as a weighted mean ``progress`` in [0, 1].

The total per step is::

    STAGE_BONUS * stage + PROGRESS_WEIGHT * progress + SUCCESS_BONUS * success - action penalty

With ``PROGRESS_WEIGHT <= STAGE_BONUS`` completing a stage never lowers the reward: the bonus of
the next stage is at least what the finished stage's shaping could pay. Each transformed term has
its own temperature in :data:`TEMPERATURES` (metres or radians); the reward-optimisation loop may
pass its own values to :func:`expert_reward`.

Components are named ``"<k>.<stage name>/<term>"`` (the stage index keeps repeated stage names such
as the two ``approach`` stages of pick-and-place apart) plus ``"stage_bonus"``, ``"success"`` and
``"action_penalty"``; they sum to the total.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from itskill.sim.context import min_grasp_width
from itskill.sim.controller import ControllerConfig
from itskill.sim.task import Context, RewardFn
from itskill.tasks.predicates import fixture_offset, hole_depth
from itskill.tasks.spec import TaskSpec

STAGE_BONUS = 1.0
"""Reward per completed stage, paid every step while the stage stays completed."""
PROGRESS_WEIGHT = 1.0
"""Weight of the current stage's shaping (a mean in [0, 1]); at most ``STAGE_BONUS``."""
SUCCESS_BONUS = 2.0
"""Paid every step on which the task's success predicate holds (a task's episodes do not end on
success unless it sets ``terminate_on_success``, so a policy that keeps the part lifted or
seated keeps earning it)."""
ACTION_PENALTY = 0.01
"""Weight of the mean squared motion action [dx, dy, dz, dyaw]: discourages jitter, small enough
not to stop exploration."""

_YAW_LOW, _YAW_HIGH = ControllerConfig().yaw_limits

APPROACH_SLOPE = 1.0
"""Height over a part that its approach aims at, per metre of lateral offset (see ``near``)."""
APPROACH_HOVER = 0.05
"""The most the approach aims over a part (m): the scripted grasps hover 4 cm above it."""

TEMPERATURES: dict[str, float] = {
    "reach": 0.15,  # grip point to part, coarse: still has a slope 30 cm away (m)
    "reach_fine": 0.015,  # grip point to part, fine: the last centimetres before a grasp (m)
    "grasp_align": 0.01,  # grip point to the part's grip zone while closing (m)
    "fixture": 0.15,  # part bottom to a point over its fixture, coarse: slope 30 cm away (m)
    "fixture_fine": 0.006,  # part bottom over its fixture, fine (a bolt tip is ~12 mm wide) (m)
    "axis_fine": 0.001,  # part bottom to its fixture's axis, for millimetre tolerances (m)
    "yaw": 0.15,  # part yaw to fixture yaw (rad)
    "tilt": 0.5,  # part axis to vertical, beyond a slack (rad)
    "engage": 0.008,  # part bottom to the fixture point while placing (m)
    "screw": 0.004,  # nut seat gap left to travel (m; M12 pitch is 1.75 mm)
    "push": 0.1,  # part centre to the push target: slope from the start 15 cm away (m)
    "push_reach": 0.06,  # grip point to the pushed part (m)
}
"""Distance scale of each tanh-shaped term: ``1 - tanh(distance / temperature)``."""

Term = Callable[[Context, int, tuple[float, ...], Mapping[str, float]], dict[str, np.ndarray]]
"""``(ctx, object slot, extra predicate args, temperatures) -> {term name: value in [0, 1]}``."""


def _closeness(distance: np.ndarray, temperature: float) -> np.ndarray:
    """1 at zero distance, falling off smoothly over ``temperature``."""
    return 1.0 - np.tanh(np.maximum(distance, 0.0) / temperature)


def _fraction(value: np.ndarray, target: np.ndarray | float) -> np.ndarray:
    """``value / target`` clipped to [0, 1]: linear progress, with the same slope everywhere."""
    return np.clip(value / np.maximum(target, 1e-6), 0.0, 1.0)


def _fixture_of(ctx: Context, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and fixture index of object ``i``'s fixture, for fancy indexing."""
    fix = ctx["obj_fixture"][:, i].astype(int)
    return np.arange(len(fix)), fix


def _ee_dist(ctx: Context, i: int) -> np.ndarray:
    return np.linalg.norm(ctx["obj_to_ee"][:, i], axis=-1)


# ------------------------------------------------------------------------------ term functions
def near_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Approach a part from above: the grip point's closeness to a point over the part that
    sinks onto it as the grip point centres (a cone of :data:`APPROACH_SLOPE`, at most
    :data:`APPROACH_HOVER` high), on a coarse and a fine scale.

    The cone because fingers lowered beside a part push it away along the table; two scales
    because one tanh either has no slope far away or none in the last centimetres.
    """
    off = ctx["obj_to_ee"][:, i]
    lateral = np.linalg.norm(off[:, :2], axis=-1)
    hover = np.minimum(APPROACH_SLOPE * lateral, APPROACH_HOVER)
    d = np.hypot(lateral, off[:, 2] - hover)
    return {"reach": _closeness(d, t["reach"]), "reach_fine": _closeness(d, t["reach_fine"])}


def over_fixture_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Move the empty gripper over a fixture: the grip point's closeness to the point ``height``
    above it, on the same two scales as approaching a part."""
    height = args[1] if len(args) > 1 else 0.05
    d = np.linalg.norm(fixture_offset(ctx, i, height), axis=-1)
    return {"reach": _closeness(d, t["reach"]), "reach_fine": _closeness(d, t["reach_fine"])}


def grasped_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Grasp (or keep holding) a part.

    1 while held. Otherwise pay for centring the grip point on the part's grip zone, halved while
    the fingers are closed on nothing: fingers shut above the part block the descent, a local
    optimum the policy otherwise settles in. The cap below 1 keeps a held part strictly better
    than any near miss.
    """
    held = ctx["grasped"][:, i]
    # The fingers hold anywhere along the part's height, so only the part of the vertical offset
    # beyond half its height counts (the grip point cannot reach a short nut's centre anyway: the
    # fingertips touch the table first).
    off = ctx["obj_to_ee"][:, i]
    vertical = np.maximum(np.abs(off[:, 2]) - 0.5 * ctx["obj_height"][:, i], 0.0)
    align = _closeness(np.hypot(np.linalg.norm(off[:, :2], axis=-1), vertical), t["grasp_align"])
    narrowest = min_grasp_width(ctx["obj_width"][:, i], ctx["obj_height"][:, i])
    empty = ctx["grip_closed"] * (ctx["gripper_width"] < narrowest)
    attempt = 0.7 * align * (1.0 - 0.5 * empty)
    return {"grasp": np.maximum(held, attempt)}


def upright_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Keep a part upright: its tilt beyond half the predicate's allowance, smoothly.

    Slack inside the allowance, so a part hanging slightly askew in the fingers still pays 1."""
    degrees = args[0] if args else 20.0
    excess = ctx["obj_tilt"][:, i] - 0.5 * np.radians(degrees)
    return {"upright": _closeness(excess, t["tilt"])}


def lifted_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Lift a part: its bottom's height as a fraction of the target (``heights`` part heights),
    counted only while it is held so that knocking it into the air earns nothing."""
    heights = args[0] if args else 3.0
    target = heights * ctx["obj_height"][:, i]
    return {"lift": ctx["grasped"][:, i] * _fraction(ctx["obj_bottom_z"][:, i], target)}


def above_fixture_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Carry a part over its fixture: its bottom's closeness to a point over the fixture point,
    in the middle of the predicate's height window, coarse and fine. A radius under half the
    fine temperature (a peg placed within 1.5 mm of its hole's axis) also pays the lateral
    offset at the millimetre scale: the fine term barely tells 1 mm from 3 mm."""
    radius = args[0] if args else 0.004
    height = args[1] if len(args) > 1 else 0.03
    off = np.array(ctx["obj_to_fix"][:, i], dtype=np.float64)
    off[:, 2] += 0.5 * height  # aim half-way up the allowed hover window
    d = np.linalg.norm(off, axis=-1)
    terms = {
        "to_fixture": _closeness(d, t["fixture"]),
        "over_fixture": _closeness(d, t["fixture_fine"]),
    }
    if radius < 0.5 * t["fixture_fine"]:
        lateral = np.linalg.norm(off[:, :2], axis=-1)
        terms["over_axis"] = _closeness(lateral, t["axis_fine"])
    return terms


def aligned_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Turn a part to its fixture's yaw (the error is 0 for a round part)."""
    return {"yaw": _closeness(np.abs(ctx["yaw_error"][:, i]), t["yaw"])}


def engaged_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Place a part on its fixture: its bottom's closeness to the fixture point (the nut's
    thread catches there), then 1 once engaged."""
    d = np.linalg.norm(ctx["obj_to_fix"][:, i], axis=-1)
    engaged = ctx["engaged"][:, i]
    return {"engage": np.maximum(engaged, 0.9 * _closeness(d, t["engage"]))}


def _turn_left(ctx: Context, clockwise: bool) -> np.ndarray:
    """Radians the hand can still turn clockwise (seen from above) or anticlockwise before the
    wrist's limit."""
    yaw = ctx["ee_yaw"]
    return np.maximum(yaw - _YAW_LOW if clockwise else _YAW_HIGH - yaw, 0.0)


def seated_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Screw a nut down: the seat gap still to travel, while engaged; the gap a gripped turn to
    the wrist's limit would leave (``wind``); and the grip point on the nut, on the coarse and
    the fine scale (the hand starts several centimetres away), since only a gripped nut turns.

    The wrist turns the hand less than a turn, so screwing is cycles of turning the held nut and
    turning the open hand back. ``wind`` pays the second half: a gripped turn leaves it as it is
    (the ``screw`` term pays that), turning back raises it. With it the policies turn the open
    hand back before their first sweep (94% against 86% without it, docs/skills.md); it has not
    yet taught a second sweep.
    """
    tolerance = args[0] if args else 0.0
    gap = ctx["seat_gap"][:, i] - tolerance
    engaged = ctx["engaged"][:, i]
    reachable = gap - ctx["thread_lead"][:, i] * _turn_left(ctx, clockwise=True)
    return {
        "screw": engaged * _closeness(gap, t["screw"]),
        "wind": engaged * _closeness(reachable, t["screw"]),
        **_reach_terms(ctx, i, t),
    }


def inserted_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Insert a peg: centred over the hole (coarse, and fine: a held peg that meets the hole
    half a millimetre off tilts and jams), yaw aligned, and depth as a fraction of the target,
    counted only while the peg is held. A peg let go over the hole falls in only if it is
    already centred and still, so paying for its depth taught an insert skill to drop the peg:
    it worked from its own start and from none that a moving hand-over gives."""
    fraction = args[0] if args else 0.5
    lateral = np.linalg.norm(ctx["obj_to_fix"][:, i, :2], axis=-1)
    depth = _fraction(ctx["insertion_depth"][:, i], fraction * hole_depth(ctx, i))
    return {
        "centre": _closeness(lateral, t["fixture_fine"]),
        "centre_fine": _closeness(lateral, t["axis_fine"]),
        "yaw": _closeness(np.abs(ctx["yaw_error"][:, i]), t["yaw"]),
        "depth": ctx["grasped"][:, i] * depth,
    }


def removed_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Unscrew or pull a part off its fixture: its bottom's height from the seat up to ``height``
    above the fixture point (the whole travel, linear), while the grip point stays on the part.
    A nut also gets ``wind``, as in :func:`seated_terms` the other way round: the height an
    anticlockwise gripped turn to the wrist's limit would reach, while its thread is engaged;
    and, as there, the coarse scale of the grip point's distance (a pull starts with the hand on
    the part, an unscrew several centimetres away)."""
    height = args[0] if args else 0.02
    rows, fix = _fixture_of(ctx, i)
    seat = ctx["seat_z"][rows, fix]
    travel = ctx["fix_pos"][rows, fix, 2] + height - seat
    bottom = ctx["obj_bottom_z"][:, i]
    lead = ctx["thread_lead"][:, i]
    terms = {"raise": _fraction(bottom - seat, travel)}
    if not np.any(lead > 0):  # a peg (the slot holds the same part in every environment)
        return terms | {"reach_fine": _closeness(_ee_dist(ctx, i), t["reach_fine"])}
    reachable = bottom + lead * _turn_left(ctx, clockwise=False)
    terms["wind"] = ctx["engaged"][:, i] * _fraction(reachable - seat, travel)
    return terms | _reach_terms(ctx, i, t)


def _reach_terms(ctx: Context, i: int, t: Mapping[str, float]) -> dict[str, np.ndarray]:
    """The grip point's closeness to a part's centre on the coarse and the fine scale."""
    d = _ee_dist(ctx, i)
    return {"reach": _closeness(d, t["reach"]), "reach_fine": _closeness(d, t["reach_fine"])}


def displaced_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Push a part to (dx, dy) from its fixture point: the part's closeness to that target, and
    the grip point staying near the part (a coarse scale: the pusher sits beside it)."""
    dx, dy = (args[0], args[1]) if len(args) >= 2 else (0.0, 0.0)
    err = -ctx["obj_to_fix"][:, i, :2] - np.array([dx, dy])
    return {
        "push": _closeness(np.linalg.norm(err, axis=-1), t["push"]),
        "push_reach": _closeness(_ee_dist(ctx, i), t["push_reach"]),
    }


def released_terms(ctx: Context, i: int, args: tuple[float, ...], t: Mapping[str, float]):
    """Let go of a part: fingers commanded open and the part not held."""
    return {"release": (1.0 - ctx["grasped"][:, i]) * (1.0 - ctx["grip_closed"])}


TERMS: dict[str, Term] = {
    "near": near_terms,
    "over_fixture": over_fixture_terms,
    "grasped": grasped_terms,
    "upright": upright_terms,
    "lifted": lifted_terms,
    "above_fixture": above_fixture_terms,
    "aligned": aligned_terms,
    "engaged": engaged_terms,
    "seated": seated_terms,
    "inserted": inserted_terms,
    "removed": removed_terms,
    "displaced": displaced_terms,
    "released": released_terms,
}
"""Shaping for each stage predicate (see :mod:`itskill.tasks.predicates`)."""

TERM_WEIGHTS: dict[str, float] = {"reach_fine": 0.5, "push_reach": 0.5}
"""Relative weight of a term inside its stage's mean (1 if not listed): auxiliary terms count
less than the term that measures the subtask itself."""


# ------------------------------------------------------------------------------ the reward
@dataclass(frozen=True)
class _StagePlan:
    """What one stage pays for: ``(predicate, object slot, extra args)`` per shaped term."""

    label: str
    terms: tuple[tuple[str, int, tuple[float, ...]], ...]


def _plan(spec: TaskSpec) -> list[_StagePlan]:
    """Shaped predicates per stage: the positive terms of each stage's ``done`` expression.

    A term already required by the previous stage (``engaged(0)`` in ``engaged(0) and near(1)``)
    is dropped: it holds anyway, and paying for it again would only flatten the new terms.
    Negated terms are not shaped (they say what must stay false, not where to go).
    """
    plans: list[_StagePlan] = []
    previous: set[tuple[str, tuple[float, ...]]] = set()
    for k, stage in enumerate(spec.stages):
        current = {(name, args) for neg, name, args in stage.done.terms if not neg}
        new = [
            (name, int(args[0]), tuple(args[1:]))
            for neg, name, args in stage.done.terms
            if not neg and name in TERMS and (name, args) not in previous
        ]
        if not new:  # a stage that repeats its predecessor's predicate: shape all of it
            new = [
                (name, int(args[0]), tuple(args[1:]))
                for neg, name, args in stage.done.terms
                if not neg and name in TERMS
            ]
        plans.append(_StagePlan(f"{k}.{stage.name}", tuple(new)))
        previous = current
    return plans


def expert_reward(spec: TaskSpec, temperatures: Mapping[str, float] | None = None) -> RewardFn:
    """The expert reward of task ``spec``: staged dense shaping, stage bonus and success bonus.

    ``temperatures`` overrides entries of :data:`TEMPERATURES` (unknown names are an error, so a
    typo does not silently leave the default in place).
    """
    temps = dict(TEMPERATURES)
    for name, value in (temperatures or {}).items():
        if name not in temps:
            raise KeyError(f"unknown temperature {name!r}; known: {', '.join(temps)}")
        temps[name] = float(value)
    plans = _plan(spec)
    success_fn = spec.success

    def compute_reward(ctx: Context) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        n = ctx["ee_pos"].shape[0]
        stage = np.asarray(ctx["stage"]).astype(int).reshape(n)
        components: dict[str, np.ndarray] = {}
        for k, plan in enumerate(plans):
            active = stage == k
            values: dict[str, np.ndarray] = {}
            for name, slot, args in plan.terms:
                for term, value in TERMS[name](ctx, slot, args, temps).items():
                    key = term if term not in values else f"{term}_{slot}"
                    values[key] = value
            total_weight = sum(_weight(term) for term in values) or 1.0
            for term, value in values.items():
                share = PROGRESS_WEIGHT * _weight(term) / total_weight
                components[f"{plan.label}/{term}"] = np.where(active, share * value, 0.0)
        components["stage_bonus"] = STAGE_BONUS * stage.astype(np.float64)
        components["success"] = SUCCESS_BONUS * np.asarray(success_fn(ctx), dtype=np.float64)
        motion = np.asarray(ctx["action"], dtype=np.float64)[:, :4]
        components["action_penalty"] = -ACTION_PENALTY * np.mean(motion**2, axis=-1)
        total = np.sum(list(components.values()), axis=0)
        return total, components

    return compute_reward


def _weight(term: str) -> float:
    """A term's weight in its stage's mean, ignoring a ``_<slot>`` suffix."""
    if term in TERM_WEIGHTS:
        return TERM_WEIGHTS[term]
    base = term.rsplit("_", 1)[0]
    return TERM_WEIGHTS.get(base, 1.0) if term[-1:].isdigit() else 1.0


def expert_fingerprint(spec: TaskSpec) -> str:
    """A sha256 of what decides ``spec``'s expert reward: this module's code and the task's
    stages and success predicate. A run records it, so one resumed after either changed (a
    term added, a stage's radius narrowed) is refused rather than continued under another
    reward. The predicates' own code is not covered."""
    digest = hashlib.sha256(Path(__file__).read_bytes())
    digest.update(repr((spec.stages, spec.success)).encode())
    return digest.hexdigest()
