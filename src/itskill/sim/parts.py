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
    def widest_grasp(self) -> float:
        """The widest side the fingers may hold the part across: its across-flats."""
        return self.across_flats

    def __post_init__(self) -> None:
        _positive(self.name, across_flats=self.across_flats, height=self.height, pitch=self.pitch)
        if self.bore_apothem >= self.across_flats / 2 - 0.001:
            raise ValueError(f"{self.name}: bore leaves less than 1 mm of wall")


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

    def __post_init__(self) -> None:
        _positive(self.name, shank_length=self.shank_length, pitch=self.pitch)


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
    def widest_grasp(self) -> float:
        """The widest side the fingers may hold the part across: a rectangular peg's longer
        side (held across it, it is as firmly held as across its thickness)."""
        return self.diameter if self.shape == "round" else max(self.width, self.depth)

    def __post_init__(self) -> None:
        if self.shape == "round":
            _positive(self.name, diameter=self.diameter, length=self.length)
        else:
            _positive(self.name, width=self.width, depth=self.depth, length=self.length)


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

    def __post_init__(self) -> None:
        _positive(self.name, hole_depth=self.hole_depth, clearance=self.clearance)


PartSpec = NutSpec | PegSpec
FixtureSpec = BoltSpec | HoleSpec


@dataclass(frozen=True)
class PlacedFixture:
    """A fixture at a fixed table position (x, y) with a yaw (radians)."""

    part: FixtureSpec
    xy: tuple[float, float]
    yaw: float = 0.0


def _positive(name: str, **values: float) -> None:
    for key, value in values.items():
        if not value > 0:
            raise ValueError(f"{name}: {key} must be > 0, got {value}")


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


def _ring(body, prefix, apothem, thickness, half_height, z, sides, rgba, half_len=None) -> None:
    """``sides`` boxes whose inner faces form a regular polygon of inradius ``apothem``."""
    half_len = half_len or (apothem + thickness) * math.tan(math.pi / sides) + 1e-4
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
