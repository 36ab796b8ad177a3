"""Procedural parts with real dimensions: hex nuts, bolts, pegs and holes.

Every part is made of convex primitives (boxes and cylinders) so contacts stay cheap: a hex nut is a
ring of six boxes around a hexagonal bore, a hole is a ring of boxes in a block fixed to the table.
Dimensions are data (see the task files); the dataclasses here validate and describe them.

Frames: a movable part's body origin is its centre; a fixture's body origin is its footprint centre
on the table top (z = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import mujoco

from itskill.datafile import is_number
from itskill.errors import PicklableError

STEEL_DENSITY = 7850.0
PART_FRICTION = (1.0, 0.01, 0.001)
PART_SOLREF = (0.008, 1.0)
PART_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)

# Contact bits: geoms collide when one's contype shares a bit with the other's conaffinity.
# Parts touch parts and the robot (PARTS); the table touches pegs, a nut's base disc and the
# robot (TABLE, ROBOT_TABLE) but not a nut's six wall boxes, which would make 24 contacts where
# the disc makes 4 and cost more time than the rest of the step.
CONTACT_PARTS = 1
CONTACT_TABLE = 2
CONTACT_ROBOT_TABLE = 4

MAX_PART_SIZE = 0.5
"""Upper bound (exclusive, metres) on every part dimension: the arm reaches a box of 0.5 m
(x) by 0.7 m (y) by 0.44 m (z) (``ControllerConfig``'s workspace), so no larger part is
anything it could handle, and far larger ones (1e300) overflow MuJoCo's geometry."""
PART_SHAPES = ("round", "rect")
MAX_HOLE_SEGMENTS = 64
"""Each wall box of a round hole is geoms and contacts with the peg; 64 already make a ring
within 0.12% of a circle (cos(pi/64)), so more only cost simulation time."""

_BOX = mujoco.mjtGeom.mjGEOM_BOX
_CYL = mujoco.mjtGeom.mjGEOM_CYLINDER


@dataclass(frozen=True)
class NutSpec:
    """ISO 4032 hex nut. Lengths in metres; ``bore_clearance`` is radial, bolt to bore flats."""

    name: str
    across_flats: float
    height: float
    thread_diameter: float
    pitch: float
    bore_clearance: float = 0.00025
    rgba: tuple[float, float, float, float] = (0.72, 0.72, 0.76, 1.0)
    kind: Literal["nut"] = "nut"

    @property
    def bore_apothem(self) -> float:
        return self.thread_diameter / 2 + self.bore_clearance

    @property
    def grasp_width(self) -> float:
        return self.across_flats

    @property
    def radius(self) -> float:
        """How far the part reaches from its axis on the table: a hex nut's corners."""
        return self.across_flats / math.sqrt(3)

    @property
    def widest_grasp(self) -> float:
        """The widest side the fingers may hold the part across: its across-flats."""
        return self.across_flats

    def __post_init__(self) -> None:
        _sizes(
            self.name,
            across_flats=self.across_flats,
            height=self.height,
            thread_diameter=self.thread_diameter,
            pitch=self.pitch,
            # Zero clearance puts the bore flats on the shank: they collide and the nut jams.
            bore_clearance=self.bore_clearance,
        )
        _check_rgba(self.name, self.rgba)
        if self.bore_apothem >= self.across_flats / 2 - 0.001:
            raise PartSpecError(self.name, "across_flats", "bore leaves less than 1 mm of wall")


@dataclass(frozen=True)
class BoltSpec:
    """A bolt standing on the table: a head (the nut's seat) and a threaded shank above it."""

    name: str
    thread_diameter: float
    pitch: float
    shank_length: float
    head_height: float = 0.008
    head_diameter: float = 0.03
    rgba: tuple[float, float, float, float] = (0.45, 0.47, 0.52, 1.0)
    kind: Literal["bolt"] = "bolt"

    @property
    def seat_z(self) -> float:
        """Height of the head's top face, where a fully screwed nut rests."""
        return self.head_height

    @property
    def tip_z(self) -> float:
        return self.head_height + self.shank_length

    @property
    def radius(self) -> float:
        """How far the bolt reaches from its axis on the table: its head."""
        return self.head_diameter / 2

    def __post_init__(self) -> None:
        _sizes(
            self.name,
            thread_diameter=self.thread_diameter,
            pitch=self.pitch,
            shank_length=self.shank_length,
            head_height=self.head_height,
            head_diameter=self.head_diameter,
        )
        _check_rgba(self.name, self.rgba)


@dataclass(frozen=True)
class PegSpec:
    """A round peg (``diameter``) or a rectangular peg (``width`` x ``depth``)."""

    name: str
    shape: Literal["round", "rect"]
    length: float
    diameter: float = 0.0
    width: float = 0.0
    depth: float = 0.0
    rgba: tuple[float, float, float, float] = (0.85, 0.55, 0.2, 1.0)
    kind: Literal["peg"] = "peg"

    @property
    def height(self) -> float:
        return self.length

    @property
    def grasp_width(self) -> float:
        return self.diameter if self.shape == "round" else self.depth

    @property
    def radius(self) -> float:
        """How far the peg reaches from its axis: its radius, a rectangle's half-diagonal."""
        return (
            self.diameter / 2 if self.shape == "round" else math.hypot(self.width, self.depth) / 2
        )

    @property
    def widest_grasp(self) -> float:
        """The widest side the fingers may hold the part across: a rectangular peg's longer
        side (held across it, it is as firmly held as across its thickness)."""
        return self.diameter if self.shape == "round" else max(self.width, self.depth)

    def __post_init__(self) -> None:
        _check_shape(
            self.name, self.shape, diameter=self.diameter, width=self.width, depth=self.depth
        )
        _sizes(self.name, length=self.length)
        _check_rgba(self.name, self.rgba)


@dataclass(frozen=True)
class HoleSpec:
    """A through hole in a block on the table; ``clearance`` is radial (per side)."""

    name: str
    shape: Literal["round", "rect"]
    hole_depth: float
    clearance: float
    diameter: float = 0.0
    width: float = 0.0
    depth: float = 0.0
    wall: float = 0.015
    segments: int = 12
    rgba: tuple[float, float, float, float] = (0.3, 0.5, 0.75, 1.0)
    kind: Literal["hole"] = "hole"

    @property
    def entrance_z(self) -> float:
        return self.hole_depth

    @property
    def radius(self) -> float:
        """How far the block reaches from the hole's axis: the outside corners of its wall (a
        polygon of ``segments`` sides around a round hole)."""
        extra = self.clearance + self.wall
        if self.shape == "round":
            return (self.diameter / 2 + extra) / math.cos(math.pi / self.segments)
        return math.hypot(self.width / 2 + extra, self.depth / 2 + extra)

    def __post_init__(self) -> None:
        _check_shape(
            self.name, self.shape, diameter=self.diameter, width=self.width, depth=self.depth
        )
        _sizes(self.name, hole_depth=self.hole_depth, clearance=self.clearance, wall=self.wall)
        segments = self.segments
        if (
            not isinstance(segments, int)
            or isinstance(segments, bool)
            or not 3 <= segments <= MAX_HOLE_SEGMENTS
        ):
            # Fewer than 3 boxes make no ring around the hole.
            raise PartSpecError(
                self.name,
                "segments",
                f"expected a whole number from 3 to {MAX_HOLE_SEGMENTS}, got {segments!r}",
            )
        _check_rgba(self.name, self.rgba)


PartSpec = NutSpec | PegSpec
FixtureSpec = BoltSpec | HoleSpec


HEX_SYMMETRY = math.pi / 3
"""A hex nut's rotational symmetry: turning it by this angle moves no geometry."""


def yaw_symmetry(part: PartSpec) -> float:
    """The smallest turn about ``part``'s axis that leaves its shape where it was: 60 degrees for
    a hex nut, 180 for a rectangular peg; 0 for a round peg, which any turn leaves so."""
    if isinstance(part, NutSpec):
        return HEX_SYMMETRY
    return math.pi if part.shape == "rect" else 0.0


def fits(part: PartSpec, fixture: FixtureSpec) -> bool:
    """Whether ``part`` goes onto or into ``fixture``: a nut onto a bolt of its thread (the
    thread coupling joins only those), a peg into a hole of its shape narrower than the bore."""
    if isinstance(part, NutSpec):
        return (
            isinstance(fixture, BoltSpec)
            and math.isclose(part.thread_diameter, fixture.thread_diameter)
            and math.isclose(part.pitch, fixture.pitch)
        )
    # The bore is the hole's size plus its clearance on each side; a peg of the bore's own
    # size jams (as a nut without bore clearance does).
    if not isinstance(fixture, HoleSpec) or part.shape != fixture.shape:
        return False
    room = 2 * fixture.clearance

    def narrower(size: float, hole: float) -> bool:
        return size < hole + room and not math.isclose(size, hole + room)

    if part.shape == "round":
        return narrower(part.diameter, fixture.diameter)
    return narrower(part.width, fixture.width) and narrower(part.depth, fixture.depth)


def fits_turned(peg: PegSpec, hole: HoleSpec, turn: float) -> bool:
    """Whether a rectangular ``peg`` turned by ``turn`` radians from its hole's axes stays inside
    the bore (any turn for a round one): the box the turned rectangle spans against the bore's
    size plus its clearance on each side."""
    if peg.shape == "round":
        return True
    c, s = abs(math.cos(turn)), abs(math.sin(turn))
    room = 2 * hole.clearance
    return (
        peg.width * c + peg.depth * s <= hole.width + room
        and peg.width * s + peg.depth * c <= hole.depth + room
    )


@dataclass(frozen=True)
class PlacedFixture:
    """A fixture at a fixed table position (x, y) with a yaw (radians)."""

    part: FixtureSpec
    xy: tuple[float, float]
    yaw: float = 0.0


class PartSpecError(PicklableError, ValueError):
    """A part field out of range: ``field`` names it, so a parts file's error can point at it."""

    def __init__(self, part: str, field: str, problem: str) -> None:
        super().__init__(f"{part}: {field}: {problem}")
        self.part, self.field, self.problem = part, field, problem


def _sizes(name: str, **values: float) -> None:
    """Each of ``values`` is a length in metres: finite, above 0, below :data:`MAX_PART_SIZE`."""
    for key, value in values.items():
        if not is_number(value) or not 0 < value < MAX_PART_SIZE:
            raise PartSpecError(
                name,
                key,
                f"expected a length in metres, 0 < {key} < {MAX_PART_SIZE}, got {value!r}",
            )


def _check_shape(name: str, shape: str, *, diameter: float, width: float, depth: float) -> None:
    """``shape`` is round (a ``diameter``) or rect (``width`` by ``depth``); the other shape's
    dimensions stay 0, since a value there would be silently ignored."""
    if shape not in PART_SHAPES:
        raise PartSpecError(name, "shape", f"expected one of {PART_SHAPES}, got {shape!r}")
    if shape == "round":
        used, unused = {"diameter": diameter}, {"width": width, "depth": depth}
    else:
        used, unused = {"width": width, "depth": depth}, {"diameter": diameter}
    for key, value in unused.items():
        if value != 0:
            raise PartSpecError(
                name, key, f"a {shape} part has {' and '.join(used)}, not {key}; got {value!r}"
            )
    _sizes(name, **used)


def _check_rgba(name: str, rgba: tuple[float, ...]) -> None:
    """Four colour components (red, green, blue, alpha), each from 0 to 1 as MuJoCo reads them."""
    if (
        not isinstance(rgba, tuple | list)
        or len(rgba) != 4
        or not all(is_number(v) and 0 <= v <= 1 for v in rgba)
    ):
        raise PartSpecError(
            name, "rgba", f"expected [red, green, blue, alpha], each 0 to 1, got {list(rgba)!r}"
        )


def _part_geom(
    body: mujoco.MjsBody, name: str, gtype, size, pos, rgba, quat=None, contact=CONTACT_PARTS
) -> mujoco.MjsGeom:
    geom = body.add_geom(name=name, type=gtype, size=list(size), pos=list(pos), rgba=list(rgba))
    if quat is not None:
        geom.quat = list(quat)
    geom.contype = geom.conaffinity = contact
    geom.density = STEEL_DENSITY
    geom.friction = list(PART_FRICTION)
    geom.condim = 4
    geom.solref = list(PART_SOLREF)
    geom.solimp = list(PART_SOLIMP)
    return geom


def _yaw_quat(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))


def _ring(body, prefix, apothem, thickness, half_height, z, sides, rgba) -> None:
    """``sides`` boxes whose inner faces form a regular polygon of inradius ``apothem``."""
    half_len = (apothem + thickness) * math.tan(math.pi / sides) + 1e-4
    for k in range(sides):
        angle = 2 * math.pi * k / sides
        r = apothem + thickness / 2
        _part_geom(
            body,
            f"{prefix}_seg{k}",
            _BOX,
            (thickness / 2, half_len, half_height),
            (r * math.cos(angle), r * math.sin(angle), z),
            rgba,
            _yaw_quat(angle),
        )


def build_nut(body: mujoco.MjsBody, nut: NutSpec) -> None:
    """Six wall boxes: outer faces are the hex flats, inner faces the bore."""
    wall = nut.across_flats / 2 - nut.bore_apothem
    _ring(body, body.name, nut.bore_apothem, wall, nut.height / 2, 0.0, 6, nut.rgba)
    size = (nut.across_flats / 2, nut.height / 2, 0)
    base = _part_geom(
        body, f"{body.name}_base", _CYL, size, (0, 0, 0), (0, 0, 0, 0), contact=CONTACT_TABLE
    )
    base.density = 0.0
    base.group = 3


def build_peg(body: mujoco.MjsBody, peg: PegSpec) -> None:
    """Add the geoms of ``peg`` (round or rectangular) to ``body``."""
    contact = CONTACT_PARTS | CONTACT_TABLE
    if peg.shape == "round":
        size = (peg.diameter / 2, peg.length / 2, 0)
        _part_geom(body, f"{body.name}_geom", _CYL, size, (0, 0, 0), peg.rgba, contact=contact)
    else:
        size = (peg.width / 2, peg.depth / 2, peg.length / 2)
        _part_geom(body, f"{body.name}_geom", _BOX, size, (0, 0, 0), peg.rgba, contact=contact)


def build_bolt(body: mujoco.MjsBody, bolt: BoltSpec) -> None:
    """Add the geoms of ``bolt`` (head and threaded shaft) to ``body``."""
    hh = bolt.head_height / 2
    _part_geom(
        body, f"{body.name}_head", _CYL, (bolt.head_diameter / 2, hh, 0), (0, 0, hh), bolt.rgba
    )
    half = bolt.shank_length / 2
    size = (bolt.thread_diameter / 2, half, 0)
    _part_geom(body, f"{body.name}_shank", _CYL, size, (0, 0, bolt.head_height + half), bolt.rgba)


def build_hole(body: mujoco.MjsBody, hole: HoleSpec) -> None:
    """Add the geoms of ``hole`` (a block with a round or rectangular hole) to ``body``."""
    hz = hole.hole_depth / 2
    if hole.shape == "round":
        apothem = hole.diameter / 2 + hole.clearance
        _ring(body, body.name, apothem, hole.wall, hz, hz, hole.segments, hole.rgba)
        return
    half_w = hole.width / 2 + hole.clearance
    half_d = hole.depth / 2 + hole.clearance
    outer_d = half_d + hole.wall
    for k, (pos, size) in enumerate(
        [
            ((half_w + hole.wall / 2, 0, hz), (hole.wall / 2, outer_d, hz)),
            ((-half_w - hole.wall / 2, 0, hz), (hole.wall / 2, outer_d, hz)),
            ((0, half_d + hole.wall / 2, hz), (half_w, hole.wall / 2, hz)),
            ((0, -half_d - hole.wall / 2, hz), (half_w, hole.wall / 2, hz)),
        ]
    ):
        _part_geom(body, f"{body.name}_wall{k}", _BOX, size, pos, hole.rgba)
