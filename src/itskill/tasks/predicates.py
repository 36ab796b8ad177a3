"""Stage and success predicates, written in task files as small expressions over the reward context.

An expression is one or more terms joined by ``and``; a term is ``name(args)`` optionally preceded
by ``not``. Arguments are numbers; the first is an object slot. Examples::

    lifted(0, 3)                      # object 0's bottom is 3 of its heights above the table
    engaged(0) and not grasped(0)
    seated(0, 0.00175)                # within one M12 pitch of the bolt's seat

Each predicate returns a boolean array over the batch.
"""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from itskill.sim.task import Context


def near(ctx: Context, i: int, dist: float = 0.02) -> np.ndarray:
    """The grip point is within ``dist`` metres of object ``i``'s centre."""
    return np.linalg.norm(ctx["obj_to_ee"][:, i], axis=-1) < dist


def fixture_offset(ctx: Context, i: int, height: float) -> np.ndarray:
    """The point ``height`` metres above object ``i``'s fixture, minus the grip point (N, 3)."""
    fix = ctx["obj_fixture"][:, i].astype(int)
    point = ctx["fix_pos"][np.arange(len(fix)), fix].copy()
    point[:, 2] += height
    return point - ctx["ee_pos"]


def over_fixture(ctx: Context, i: int, dist: float = 0.015, height: float = 0.05) -> np.ndarray:
    """The grip point is within ``dist`` of the point ``height`` above object ``i``'s fixture."""
    return np.linalg.norm(fixture_offset(ctx, i, height), axis=-1) < dist


def grasped(ctx: Context, i: int) -> np.ndarray:
    """The closed fingers hold object ``i``."""
    return ctx["grasped"][:, i] > 0.5


def upright(ctx: Context, i: int, degrees: float = 20.0) -> np.ndarray:
    """Object ``i``'s axis is within ``degrees`` of vertical.

    Closed fingers also hold a nut tipped on its side (across its height), and a part held that
    way can never go onto its bolt or into its hole.
    """
    return ctx["obj_tilt"][:, i] < np.radians(degrees)


def lifted(ctx: Context, i: int, heights: float = 3.0) -> np.ndarray:
    """Object ``i``'s bottom is at least ``heights`` part heights above the table (Factory)."""
    return ctx["obj_bottom_z"][:, i] >= heights * ctx["obj_height"][:, i]


def above_fixture(
    ctx: Context, i: int, radius: float = 0.004, height: float = 0.03, depth: float = 0.002
) -> np.ndarray:
    """Object ``i`` hangs over its fixture: centred within ``radius``, its bottom at most
    ``height`` above the fixture point and at most ``depth`` below it.

    A stage that ends over a hole, followed by one that ends with the peg deep in it, needs a
    ``depth`` as deep as the next stage's goal: otherwise, between the two, neither holds and the
    stage falls back to the approach while the peg goes in.
    """
    off = ctx["obj_to_fix"][:, i]
    lateral = np.linalg.norm(off[:, :2], axis=-1)
    return (lateral < radius) & (off[:, 2] < depth) & (-off[:, 2] < height)


def engaged(ctx: Context, i: int) -> np.ndarray:
    """Object ``i`` is on its fixture: a nut's thread engaged, a peg inside its hole."""
    return ctx["engaged"][:, i] > 0.5


def seated(ctx: Context, i: int, tolerance: float) -> np.ndarray:
    """Object ``i`` is engaged and within ``tolerance`` of its seat (a nut: one pitch)."""
    return engaged(ctx, i) & (ctx["seat_gap"][:, i] <= tolerance)


def hole_depth(ctx: Context, i: int) -> np.ndarray:
    """The depth of object ``i``'s hole: from its entrance to its seat."""
    fix = ctx["obj_fixture"][:, i].astype(int)
    rows = np.arange(len(fix))
    return ctx["fix_pos"][rows, fix, 2] - ctx["seat_z"][rows, fix]


def inserted(ctx: Context, i: int, fraction: float = 0.5, yaw_tol: float = 0.1) -> np.ndarray:
    """Object ``i`` is in its hole past ``fraction`` of the hole depth, axis and yaw aligned."""
    return (
        engaged(ctx, i)
        & (ctx["insertion_depth"][:, i] >= fraction * hole_depth(ctx, i))
        & (np.abs(ctx["yaw_error"][:, i]) <= yaw_tol)
        & (ctx["obj_tilt"][:, i] <= 0.1)
    )


def aligned(ctx: Context, i: int, tolerance: float = 0.05) -> np.ndarray:
    """Object ``i``'s yaw matches its fixture's within ``tolerance`` (always true if round)."""
    return np.abs(ctx["yaw_error"][:, i]) <= tolerance


def released(ctx: Context, i: int) -> np.ndarray:
    """Object ``i`` is not held and the fingers are commanded open."""
    return ~grasped(ctx, i) & (ctx["grip_closed"] < 0.5)


def removed(ctx: Context, i: int, height: float = 0.02) -> np.ndarray:
    """Object ``i`` is off its fixture, its bottom at least ``height`` above the fixture point."""
    return ~engaged(ctx, i) & (ctx["obj_to_fix"][:, i, 2] <= -height)


def displaced(ctx: Context, i: int, dx: float, dy: float, tolerance: float = 0.02) -> np.ndarray:
    """Object ``i``'s centre is within ``tolerance`` of (dx, dy) from its fixture's point."""
    off = -ctx["obj_to_fix"][:, i, :2] - np.array([dx, dy])
    return np.linalg.norm(off, axis=-1) < tolerance


PREDICATES: dict[str, Callable[..., np.ndarray]] = {
    f.__name__: f
    for f in (
        near, over_fixture, grasped, upright, lifted, above_fixture, engaged, seated, inserted,
        aligned, released, removed, displaced,
    )
}  # fmt: skip

FIXTURE_PREDICATES = frozenset(
    {"over_fixture", "above_fixture", "engaged", "seated", "inserted", "aligned", "removed",
     "displaced"}
)  # fmt: skip
"""The predicates that measure an object against its fixture: meaningless in a task without
one, whose fixture slots read as zeros (a fixture at the robot's base)."""

_TERM = re.compile(r"^(not\s+)?([a-z_]+)\(([^()]*)\)$")


class PredicateError(ValueError):
    """A predicate expression that does not parse or names an unknown predicate."""


@dataclass(frozen=True)
class Expression:
    """A parsed predicate expression, callable on a context."""

    source: str
    terms: tuple[tuple[bool, str, tuple[float, ...]], ...]

    def __call__(self, ctx: Context) -> np.ndarray:
        result = np.ones(ctx["ee_pos"].shape[0], dtype=bool)
        for negate, name, args in self.terms:
            value = PREDICATES[name](ctx, int(args[0]), *args[1:])
            result &= ~value if negate else value
        return result

    @property
    def objects(self) -> set[int]:
        return {int(args[0]) for _, _, args in self.terms}

    @property
    def names(self) -> set[str]:
        return {name for _, name, _ in self.terms}


_SIGNED = {"dx", "dy"}
"""Arguments that are offsets and may be negative; every other one after the object slot is a
distance, angle, count of heights or fraction, for which a negative value makes the predicate
always false (or, negated, always true) and so the stage or task unreachable or free."""


def _check_args(term: str, name: str, args: tuple[float, ...]) -> None:
    """Refuse on load what would fail at the first step (too few or too many arguments) or
    quietly measure something else (a fractional slot read as a whole one, nan, inf)."""
    params = list(inspect.signature(PREDICATES[name]).parameters.values())[1:]  # after ctx
    least = sum(p.default is inspect.Parameter.empty for p in params)
    if not least <= len(args) <= len(params):
        names = ", ".join(
            p.name if p.default is inspect.Parameter.empty else f"{p.name}={p.default}"
            for p in params
        )
        raise PredicateError(f"{term!r}: {name} takes ({names}), got {len(args)} argument(s)")
    for param, value in zip(params, args, strict=False):
        if not math.isfinite(value):
            # nan compares false with everything and inf true with everything.
            raise PredicateError(f"{term!r}: {param.name} must be a finite number, got {value}")
        if param.name == "i" and not (value.is_integer() and value >= 0):
            raise PredicateError(
                f"{term!r}: the object slot must be a whole number 0 or more, got {value:g}"
            )
        if param.name not in _SIGNED and value < 0:
            raise PredicateError(f"{term!r}: {param.name} must be 0 or more, got {value:g}")
        if param.name == "fraction" and value > 1:
            # A part goes no deeper than its hole: never true (or, negated, always).
            raise PredicateError(f"{term!r}: fraction must be at most 1, got {value:g}")


def predicate_params(name: str, args: tuple[float, ...]) -> dict[str, Any]:
    """A predicate's arguments by parameter name, defaults filled in (slot included as ``i``)."""
    signature = inspect.signature(PREDICATES[name])
    bound = signature.bind(None, *[int(args[0]), *args[1:]])
    bound.apply_defaults()
    params = dict(bound.arguments)
    params.pop(next(iter(signature.parameters)))
    return params


def parse(source: str) -> Expression:
    """Parse ``source``; raise :class:`PredicateError` saying what is wrong."""
    terms = []
    # Any whitespace around "and": a multi-line TOML string breaks lines there.
    for raw in re.split(r"\s+and\s+", source.strip()):
        match = _TERM.match(raw.strip())
        if not match:
            raise PredicateError(
                f"cannot parse {raw.strip()!r}: expected name(args) or not name(args)"
            )
        negate, name, arg_text = bool(match.group(1)), match.group(2), match.group(3)
        if name not in PREDICATES:
            known = ", ".join(sorted(PREDICATES))
            raise PredicateError(f"unknown predicate {name!r}; known: {known}")
        pieces = arg_text.split(",") if arg_text.strip() else []
        if not all(a.strip() for a in pieces):
            # "lifted(0,,0.03)" would read the height as the first optional argument.
            raise PredicateError(f"{raw.strip()!r}: an argument is empty")
        try:
            args = tuple(float(a) for a in pieces)
        except ValueError as err:
            raise PredicateError(f"{raw.strip()!r}: arguments must be numbers") from err
        if not args:
            raise PredicateError(f"{raw.strip()!r}: the first argument is the object slot")
        _check_args(raw.strip(), name, args)
        terms.append((negate, name, args))
    return Expression(source, tuple(terms))
