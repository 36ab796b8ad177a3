"""Peg-in-hole physics: the rectangular peg enters its hole only when its yaw is aligned.

The rectangular peg is 16 x 10 mm in a hole with 0.75 mm clearance per side, so it fits only
within a few degrees of yaw; twisted by 20 degrees its corners land on the block around the hole.
The ``insert_*`` tasks start with the peg held in the gripper a few millimetres over its hole,
within about a millimetre of its axis, so the hand first centres the peg, as a policy would.
"""

from __future__ import annotations

import math

import numpy as np

from itskill.sim.vec_env import BatchEnv
from itskill.tasks import make_batch_env

MISALIGN = math.radians(20.0)
YAW_STEP = 0.25
"""Hand yaw per unit dyaw action, radians (``ControllerConfig.yaw_step``)."""
POS_STEP = 0.015
"""Grip point travel per unit translation action, metres (``ControllerConfig.pos_step``)."""
TURN_STEPS = 4
CENTRE_STEPS = 6
ENTER_STEPS = 4
"""Slow steps (dz = -0.25) that bring the peg's tip to the entrance before the firm push."""
PUSH_STEPS = 15
"""Control steps of dz = -1: far more travel than the hole is deep, so the push is firm."""
ENTRANCE_TOL = 0.001
"""Contact penetration allowed when a blocked peg rests on the block around the hole, metres."""


def step(env: BatchEnv, dz: float = 0.0, dyaw=0.0, centre_gain: float = 0.5) -> None:
    """One step with the fingers closed, nudging each peg towards its hole's axis."""
    ctx = env.context()
    n = env.num_envs
    actions = np.zeros((n, 5))
    actions[:, :2] = np.clip(centre_gain * ctx["obj_to_fix"][:, 0, :2] / POS_STEP, -1, 1)
    actions[:, 2] = dz
    actions[:, 3] = dyaw
    actions[:, 4] = 1.0
    env.step(actions)


def push_in(env: BatchEnv, yaw: np.ndarray) -> tuple[dict, dict, dict]:
    """Turn each hand by ``yaw``, centre the peg over its hole, push it down; three contexts."""
    start = env.context()
    for _ in range(TURN_STEPS):
        step(env, dyaw=np.asarray(yaw) / YAW_STEP / TURN_STEPS, centre_gain=0.0)
    for _ in range(CENTRE_STEPS):
        step(env)
    turned = env.context()
    for _ in range(ENTER_STEPS):
        step(env, dz=-0.25)
    for _ in range(PUSH_STEPS):
        step(env, dz=-1.0)
    return start, turned, env.context()


def test_rect_peg_is_blocked_when_twisted_and_enters_when_aligned():
    # Env 0 is twisted +20 deg, env 1 -20 deg, env 2 stays aligned; all are pushed down alike.
    env = make_batch_env("insert_peg_rect", num_envs=3, seed=0, n_threads=1)
    env.reset()
    start, turned, ctx = push_in(env, np.array([MISALIGN, -MISALIGN, 0.0]))
    env.close()
    assert np.all(start["obj_bottom_z"][:, 0] > start["fix_pos"][:, 0, 2]), "starts above"
    assert np.all(start["grasped"][:, 0] == 1.0)
    assert np.all(start["engaged"][:, 0] == 0.0)

    # The peg turned with the hand (it may slip a little in the fingers): far outside the few
    # degrees (about 7) within which it fits the hole. It hangs centred over the hole.
    err = turned["yaw_error"][:, 0]
    assert err[0] > math.radians(14) and err[1] < -math.radians(14), err
    assert abs(err[2]) < 0.05, err
    assert np.all(turned["grasped"][:, 0] == 1.0)
    assert np.all(np.linalg.norm(turned["obj_to_fix"][:, 0, :2], axis=-1) < 0.0015)

    bottom = ctx["obj_bottom_z"][:, 0]
    fix_z = ctx["fix_pos"][:, 0, 2]
    # Twisted: the peg's bottom stays at the hole entrance, not in the hole...
    assert np.all(bottom[:2] >= fix_z[:2] - ENTRANCE_TOL), (bottom, fix_z)
    assert np.all(ctx["engaged"][:2, 0] == 0.0)
    assert np.all(ctx["insertion_depth"][:2, 0] < ENTRANCE_TOL)
    # ... although the hand did push down, well below where it started.
    assert np.all(ctx["ee_pos"][:2, 2] < start["ee_pos"][:2, 2] - 0.01)

    # Aligned: the same push takes the peg deep into the hole.
    assert ctx["engaged"][2, 0] == 1.0
    assert ctx["insertion_depth"][2, 0] > 0.005
    assert bottom[2] < fix_z[2] - 0.005


def test_round_peg_enters_its_hole_when_centred():
    env = make_batch_env("insert_peg_round", num_envs=2, seed=0, n_threads=1)
    env.reset()
    start, _, ctx = push_in(env, np.zeros(2))
    success = env.task.success_fn(ctx)
    env.close()
    assert np.all(start["obj_bottom_z"][:, 0] > start["fix_pos"][:, 0, 2])
    assert np.all(start["engaged"][:, 0] == 0.0)
    assert np.all(ctx["engaged"][:, 0] == 1.0)
    assert np.all(ctx["insertion_depth"][:, 0] > 0.005)
    assert np.all(ctx["obj_bottom_z"][:, 0] < ctx["fix_pos"][:, 0, 2] - 0.005)
    assert np.all(ctx["obj_tilt"][:, 0] < 0.1)
    # Past half the hole depth, upright: the task counts it as inserted.
    assert np.all(success)
