"""Part dataclasses check their own values, for a user building a scene in Python too."""

from __future__ import annotations

import pickle

import pytest

from itskill.sim.parts import BoltSpec, HoleSpec, NutSpec, PartSpecError, PegSpec, fits

NUT = {"name": "n", "across_flats": 0.018, "height": 0.0108, "thread_diameter": 0.012,
       "pitch": 0.00175}  # fmt: skip
BOLT = {"name": "b", "thread_diameter": 0.012, "pitch": 0.00175, "shank_length": 0.005}
PEG = {"name": "p", "shape": "rect", "width": 0.016, "depth": 0.01, "length": 0.05}
HOLE = {"name": "h", "shape": "round", "diameter": 0.004, "clearance": 0.0005, "hole_depth": 0.02}


@pytest.mark.parametrize(
    ("cls", "valid", "change", "field"),
    [
        # Each was accepted: a bool read as 1 m, a negative or huge size reached MuJoCo.
        (NutSpec, NUT, {"height": True}, "height"),
        (NutSpec, NUT, {"height": 1e300}, "height"),
        (NutSpec, NUT, {"bore_clearance": -0.01}, "bore_clearance"),
        (NutSpec, NUT, {"rgba": (0.5, 0.5, 0.5, 1.5)}, "rgba"),
        (BoltSpec, BOLT, {"head_diameter": -0.026}, "head_diameter"),
        (BoltSpec, BOLT, {"thread_diameter": -0.012}, "thread_diameter"),
        (BoltSpec, BOLT, {"head_height": float("nan")}, "head_height"),
        (PegSpec, PEG, {"shape": "square"}, "shape"),
        (PegSpec, PEG, {"diameter": 0.004}, "diameter"),
        (HoleSpec, HOLE, {"segments": 2}, "segments"),
        (HoleSpec, HOLE, {"wall": 0.0}, "wall"),
    ],
)
def test_a_part_value_out_of_range_names_its_field(cls, valid, change, field):
    cls(**valid)
    with pytest.raises(PartSpecError) as err:
        cls(**(valid | change))
    assert err.value.field == field and field in str(err.value)
    back = pickle.loads(pickle.dumps(err.value))  # it crosses process boundaries like the rest
    assert (back.part, back.field, back.problem) == (err.value.part, field, err.value.problem)
    assert isinstance(err.value, ValueError)  # callers that caught ValueError still do


def test_a_part_fits_the_fixtures_it_goes_onto_or_into():
    nut, bolt = NutSpec(**NUT), BoltSpec(**BOLT)
    rect_peg = PegSpec(**PEG)
    round_hole = HoleSpec(**HOLE)
    round_peg = PegSpec(name="r", shape="round", diameter=0.004, length=0.05)
    assert fits(nut, bolt) and fits(round_peg, round_hole)
    # Within a float's rounding of the thread still fits (the thread coupling's own rule).
    assert fits(nut, BoltSpec(**(BOLT | {"pitch": 0.00175 + 1e-13})))
    assert not fits(nut, BoltSpec(**(BOLT | {"thread_diameter": 0.016, "pitch": 0.002})))
    # One size apart each: a fine-pitch bolt of the nut's diameter, a thicker one of its pitch.
    assert not fits(nut, BoltSpec(**(BOLT | {"pitch": 0.00125})))
    assert not fits(nut, BoltSpec(**(BOLT | {"thread_diameter": 0.014})))
    assert not fits(nut, round_hole) and not fits(round_peg, bolt)
    assert not fits(rect_peg, round_hole)
    assert not fits(PegSpec(name="w", shape="round", diameter=0.006, length=0.05), round_hole)
    # The bore is the hole's size plus its clearance on each side: 5 mm here, which a peg of
    # 5 mm jams in.
    assert fits(PegSpec(name="w", shape="round", diameter=0.0045, length=0.05), round_hole)
    assert not fits(PegSpec(name="w", shape="round", diameter=0.005, length=0.05), round_hole)
    # Not even where the bore's float rounds a hair above the peg (0.002 + 2 * 0.0007).
    tight = HoleSpec(**(HOLE | {"diameter": 0.002, "clearance": 0.0007}))
    assert not fits(PegSpec(name="w", shape="round", diameter=0.0034, length=0.05), tight)
    # A rectangular bore, 17 x 11 mm with its clearance: each side of the peg is checked.
    rect_hole = HoleSpec(name="rh", shape="rect", width=0.016, depth=0.01, clearance=0.0005,
                         hole_depth=0.02)  # fmt: skip
    assert fits(rect_peg, rect_hole)
    assert not fits(PegSpec(**(PEG | {"width": 0.017})), rect_hole)
    assert not fits(PegSpec(**(PEG | {"depth": 0.011})), rect_hole)
