"""End-effector control: ``[dx, dy, dz, dyaw, grip]`` in [-1, 1] -> arm joint targets.

The controller keeps a commanded end-effector pose per environment, moves it by the scaled action,
clips it to the workspace (and a few millimetres above the table, so the fingertips never jam on
it), and maps it to joint targets with one damped-least-squares step of differential IK, with a
null-space pull towards the home posture. The hand always points down; only its yaw turns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from itskill.sim.panda import HOME_QPOS


@dataclass(frozen=True)
class ControllerConfig:
    """Control rate and step sizes, chosen for learnability (20 Hz, 1.5 cm, binary grip)."""

    substeps: int = 12
    """Physics steps per action: 12 x 4 ms = 48 ms, about 20 Hz."""
    pos_step: float = 0.015
    """End-effector translation per unit action, metres."""
    yaw_step: float = 0.25
    """End-effector yaw per unit action, radians."""
    max_lead: float = 0.03
    """The commanded position never runs further than this ahead of the measured one."""
    max_lead_closed: float = 0.015
    """``max_lead`` while the closed fingers hold something: a payload speed limit (about 0.11 m/s
    instead of 0.23). At full speed the arm's servo lag shakes a held part along the pads: moving
    straight up, 31 of 32 held M12 nuts (and every peg) slid out within 20 steps, whatever the pad
    friction, contact stiffness or solver iterations; at this limit none did."""
    holding_width: float = 0.002
    """Closed fingers further apart than this are taken to hold a part (the thinnest, the round
    peg, keeps them 4 mm apart); closed on nothing they touch, and the hand keeps full speed."""
    workspace_low: tuple[float, float, float] = (0.25, -0.35, 0.011)
    workspace_high: tuple[float, float, float] = (0.75, 0.35, 0.45)
    yaw_limits: tuple[float, float] = (-2.0, 3.0)
    """Hand yaw range relative to home. At home joint 7 sits at 0.785 rad of its +-2.897 range,
    so the wrist alone turns the hand from -2.11 to +3.68 rad; beyond that the IK twists the
    whole arm and stalls. The top stays below pi, where the reported yaw wraps around."""
    damping: float = 0.05
    joint_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 4.0)
    """Relative ease of moving each joint in the IK. Turning the hand with the wrist (joint 7)
    rather than spreading it over joints 1, 3, 5 and 7, whose servos lag differently, keeps the
    fingertips from swinging sideways by several millimetres while the hand turns."""
    nullspace_gain: float = 0.05
    """Fraction of the way back to the home posture per step, in the null space. At 0.3 the
    commanded posture swung along the redundant joint1/joint3 mode faster than those joints'
    87 N m servos could follow: both saturated against each other and the hand stalled for
    seconds mid-move (a third of the rectangular-peg carries that turned the wrist failed)."""
    grip_threshold: float = 0.0
    """``grip > threshold`` closes the fingers, otherwise they open."""


def yaw_rotation(yaw: np.ndarray) -> np.ndarray:
    """Rotation matrices about +z, batched: (N,) -> (N, 3, 3)."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros((*np.shape(yaw), 3, 3))
    rot[..., 0, 0], rot[..., 0, 1], rot[..., 1, 0], rot[..., 1, 1] = c, -s, s, c
    rot[..., 2, 2] = 1.0
    return rot


def rotation_error(desired: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Axis-angle vector that rotates ``current`` into ``desired`` (small-angle form), batched."""
    rel = desired @ np.swapaxes(current, -1, -2)
    return 0.5 * np.stack(
        [
            rel[..., 2, 1] - rel[..., 1, 2],
            rel[..., 0, 2] - rel[..., 2, 0],
            rel[..., 1, 0] - rel[..., 0, 1],
        ],
        axis=-1,
    )


def hand_yaw(site_rot: np.ndarray, home_rot: np.ndarray) -> np.ndarray:
    """Yaw of the hand relative to its home orientation, batched (N, 3, 3) -> (N,)."""
    rel = site_rot @ home_rot.T
    return np.arctan2(rel[..., 1, 0], rel[..., 0, 0])


def dls_step(
    jac: np.ndarray,
    err: np.ndarray,
    q: np.ndarray,
    damping: float,
    nullspace_gain: float,
    weights: np.ndarray | None = None,
    q_home: np.ndarray = HOME_QPOS,
) -> np.ndarray:
    """One weighted damped-least-squares IK step, batched: jac (N, 6, 7), err (N, 6), q (N, 7).

    Minimises ``sum(dq_i**2 / weights_i)``: a joint with a larger weight takes more of the motion.
    """
    sqrt_w = np.sqrt(np.ones(q.shape[-1]) if weights is None else np.asarray(weights))
    jw = jac * sqrt_w  # J W^(1/2): solve in scaled joint coordinates, then scale back
    jwt = np.swapaxes(jw, 1, 2)
    jjt = jw @ jwt + (damping**2) * np.eye(6)
    dq = sqrt_w * (jwt @ np.linalg.solve(jjt, err[..., None]))[..., 0]
    # The exact pseudo-inverse for the null-space projector: a damped one leaks the posture pull
    # into the task and leaves a millimetre-scale offset, too much for 0.5 mm peg clearances.
    null = np.eye(q.shape[-1]) - (sqrt_w[:, None] * np.linalg.pinv(jw)) @ jac
    return dq + (null @ (nullspace_gain * (q_home - q))[..., None])[..., 0]
