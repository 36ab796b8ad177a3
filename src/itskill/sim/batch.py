"""N copies of one task scene, stepped together.

``BatchSim`` owns the physics: one ``MjModel`` shared by N ``MjData``, the end-effector controller
(vectorised over environments), the thread couplings, resets from the task's initial-state
distribution, and the reward context. Physics runs on a thread pool: ``mj_step`` releases Python's
GIL, so each worker steps its shard of environments in parallel. The environment classes
(:mod:`itskill.sim.vec_env`, :mod:`itskill.sim.env`) add episodes, observations and rewards.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from itskill.sim.context import (
    MAX_FIXTURES,
    MAX_OBJECTS,
    max_grip_offset,
    min_grasp_width,
    quat_to_mat,
    wrap_angle,
)
from itskill.sim.controller import (
    ControllerConfig,
    dls_step,
    hand_yaw,
    rotation_error,
    yaw_rotation,
)
from itskill.sim.panda import HOME_QPOS
from itskill.sim.parts import BoltSpec, HoleSpec, NutSpec, PegSpec, yaw_symmetry
from itskill.sim.scene import build_scene, fixture_anchor
from itskill.sim.task import HAND_MODES, InitSpec, ObjectInit, SimTask, default_object_fixture
from itskill.sim.thread import ThreadConfig, ThreadCoupling

GRIPPER_OPEN_WIDTH = 0.08
SETTLE_STEPS = 15
"""Physics steps after a reset, so a part placed in the gripper or on the table comes to rest."""
DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)
NUT_GRIP_YAW = math.pi / 6
"""A nut's yaw relative to the hand at which two flats face the fingers."""
REACH_TOLERANCE = 0.002
"""How far (m) the grip point may end from a start's hand position: the inverse kinematics
gets every packaged start within 1 mm."""


def symmetry_turn(part: NutSpec | PegSpec, rng: np.random.Generator) -> float:
    """A random turn about ``part``'s axis that leaves its shape where it was (a multiple of its
    :func:`~itskill.sim.parts.yaw_symmetry`, any angle for a round peg).

    A part put into the hand facing the pads one way only always shows the same yaw relative to
    the hand, while a part picked from the table shows any: a Place skill trained on the first
    acted on the yaw it saw, and let go beside the bolt of a third of the nuts a scripted pick
    handed it (docs/tasks.md).
    """
    period = yaw_symmetry(part)
    if period == 0.0:
        return float(rng.uniform(-math.pi, math.pi))
    return period * float(rng.integers(round(2 * math.pi / period)))


class UnreachableStartError(ValueError):
    """A start whose hand positions the arm cannot reach."""


class BatchSim:
    """Physics, control and state of ``num_envs`` copies of ``task``'s scene."""

    def __init__(
        self,
        task: SimTask,
        num_envs: int,
        n_threads: int | None = None,
        controller: ControllerConfig | None = None,
        thread: ThreadConfig | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError("num_envs must be >= 1")
        self.task = task
        self.num_envs = num_envs
        self.cfg = controller or ControllerConfig()
        self.scene = build_scene(task.scene)
        self.model = self.scene.model
        self.datas = [mujoco.MjData(self.model) for _ in range(num_envs)]
        # Differential IK runs on the commanded posture, not the measured one, so servo lag does
        # not feed back into the next command; each environment has a kinematics-only scratch.
        self._ik_datas = [mujoco.MjData(self.model) for _ in range(num_envs)]
        self.q_des = np.zeros((num_envs, 7))
        self.coupling = ThreadCoupling(self.scene, thread)
        threads = n_threads or min(os.cpu_count() or 1, num_envs)
        self.n_threads = max(1, min(threads, num_envs))
        self._shards = [s for s in np.array_split(np.arange(num_envs), self.n_threads) if len(s)]
        # The calling thread steps the first shard itself, so the pool needs one worker fewer.
        self._pool = ThreadPoolExecutor(self.n_threads - 1) if self.n_threads > 1 else None

        self._objects = task.scene.objects
        self._fixtures = task.scene.fixtures
        self._obj_fixture = np.array(
            task.object_fixture or default_object_fixture(len(self._objects), len(self._fixtures)),
            dtype=int,
        )
        self._static_context()
        self._home_rot = self._home_rotation()
        self._q_low = self.model.jnt_range[:7, 0] + 0.01
        self._q_high = self.model.jnt_range[:7, 1] - 0.01
        self.check_reachable(task.init, f"{task.name}'s start")
        for start in task.training_starts:
            self.check_reachable(start.init, f"{task.name}'s training start {start.name!r}")

        n, nv = num_envs, self.model.nv
        # Kinematics of each environment's commanded posture q_des: grip point, its rotation and
        # Jacobian. Evaluated right after q_des changes (in the physics workers, see simulate), and
        # read by the next apply_action; _ik_q records the posture they belong to.
        self._jacp = np.zeros((n, 3, nv))
        self._jacr = np.zeros((n, 3, nv))
        self._ik_pos = np.zeros((n, 3))
        self._ik_rot = np.zeros((n, 3, 3))
        self._ik_q = np.full((n, 7), np.nan)
        self._finger_ctrl = np.zeros(n)
        self.target_pos = np.zeros((n, 3))
        self.target_yaw = np.zeros(n)
        self.grip_closed = np.zeros(n, dtype=bool)
        self.last_action = np.zeros((n, 5))
        self.ee_pos = np.zeros((n, 3))
        self.ee_rot = np.zeros((n, 3, 3))
        self.obj_pos = np.zeros((n, MAX_OBJECTS, 3))
        self.obj_rot = np.tile(np.eye(3), (n, MAX_OBJECTS, 1, 1))
        self._obj_quat = np.zeros((n, len(self._objects), 4))
        self.finger_q = np.zeros((n, 2))
        self.engaged_thread = np.zeros((n, max(len(self.scene.threads), 1)), dtype=bool)
        self.unstable = np.zeros(n, dtype=bool)
        """Set for an environment whose physics diverged during the last step (see _step_shard)."""
        self._divergences = np.zeros(n, dtype=np.int64)
        self._prev_ee = np.zeros((n, 3))
        self._prev_obj = np.zeros((n, MAX_OBJECTS, 3))
        self.ee_vel = np.zeros((n, 3))
        self.obj_vel = np.zeros((n, MAX_OBJECTS, 3))
        self.control_dt = self.cfg.substeps * self.model.opt.timestep

    # ------------------------------------------------------------------ setup
    def _static_context(self) -> None:
        """Per-scene constants of the context: sizes, masks, fixture points."""
        k = len(self._objects)
        self.obj_mask = np.zeros(MAX_OBJECTS)
        self.obj_mask[:k] = 1
        self.obj_height = np.zeros(MAX_OBJECTS)
        self.obj_width = np.zeros(MAX_OBJECTS)
        self.obj_widest = np.zeros(MAX_OBJECTS)
        self.obj_lead = np.zeros(MAX_OBJECTS)
        for i, part in enumerate(self._objects):
            self.obj_height[i], self.obj_width[i] = part.height, part.grasp_width
            self.obj_widest[i] = part.widest_grasp
            if isinstance(part, NutSpec):
                self.obj_lead[i] = part.pitch / (2 * math.pi)
        self.fix_mask = np.zeros(MAX_FIXTURES)
        self.fix_pos = np.zeros((MAX_FIXTURES, 3))
        self.fix_yaw = np.zeros(MAX_FIXTURES)
        self.seat_z = np.zeros(MAX_FIXTURES)
        self.hole_radius = np.zeros(MAX_FIXTURES)
        for j, placed in enumerate(self._fixtures):
            self.fix_mask[j] = 1
            self.fix_pos[j] = fixture_anchor(placed)
            self.fix_yaw[j] = placed.yaw
            if isinstance(placed.part, BoltSpec):
                self.seat_z[j] = placed.part.seat_z
            else:
                hole = placed.part
                half = hole.diameter / 2 if hole.shape == "round" else hole.depth / 2
                self.hole_radius[j] = half + hole.clearance
        # Symmetry period of each part's yaw against its fixture: a peg's own (a rectangular
        # one's pi, 0 for a round one); none for a nut, whose yaw on its bolt does not matter.
        self.yaw_period = np.zeros(MAX_OBJECTS)
        for i, part in enumerate(self._objects):
            if isinstance(part, PegSpec):
                self.yaw_period[i] = yaw_symmetry(part)
        # Engagement counts on the object's own bolt only: the seat gap and depth are measured
        # there, and a nut threaded on another bolt is not where its task wants it.
        self._own_threads = [
            (t, p.obj)
            for t, p in enumerate(self.scene.threads)
            if p.fixture == self._obj_fixture[p.obj]
        ]

        # The fixture constants each object slot is measured against (zero for empty slots).
        fidx = self._obj_fixture
        k = len(fidx)
        self.obj_fix_pos = np.zeros((MAX_OBJECTS, 3))
        self.obj_fix_pos[:k] = self.fix_pos[fidx]
        self.obj_fix_yaw = np.zeros(MAX_OBJECTS)
        self.obj_fix_yaw[:k] = self.fix_yaw[fidx]
        self.obj_seat_z = np.zeros(MAX_OBJECTS)
        self.obj_seat_z[:k] = self.seat_z[fidx]
        self.obj_hole_radius = np.zeros(MAX_OBJECTS)
        self.obj_hole_radius[:k] = self.hole_radius[fidx]
        self.is_peg = np.zeros(MAX_OBJECTS, dtype=bool)
        self.is_peg[:k] = [isinstance(p, PegSpec) for p in self._objects]
        self.obj_fixture_index = np.zeros(MAX_OBJECTS)
        self.obj_fixture_index[:k] = fidx
        # In a scene without fixtures an object is measured against none: its fixture terms
        # read zero, as an empty slot's do (not distances to a fixture at the robot's base).
        self.obj_fix_mask = self.obj_mask * float(bool(self._fixtures))

    def _home_rotation(self) -> np.ndarray:
        data = mujoco.MjData(self.model)
        data.qpos[self.scene.arm_qpos] = HOME_QPOS
        mujoco.mj_kinematics(self.model, data)
        return data.site_xmat[self.scene.grip_site].reshape(3, 3).copy()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    # ------------------------------------------------------------------ reset
    def reset_env(self, env: int, rng: np.random.Generator, init: InitSpec | None = None) -> None:
        """Sample env ``env``'s initial state from ``init`` (default: the task's) and let it
        settle."""
        m, d, sc = self.model, self.datas[env], self.scene
        init = init or self.task.init
        mujoco.mj_resetData(m, d)
        self._divergences[env] = 0
        self.unstable[env] = False
        d.mocap_pos[:] = sc.crest_home
        ee = np.array([init.ee_x.sample(rng), init.ee_y.sample(rng), init.ee_z.sample(rng)])
        ee_yaw = init.ee_yaw.sample(rng)
        finger = GRIPPER_OPEN_WIDTH / 2
        closed = False
        in_hand = [o for o in init.objects if o.mode in HAND_MODES]
        if in_hand:
            obj_init = in_hand[0]
            ee = np.array([obj_init.x.sample(rng), obj_init.y.sample(rng), obj_init.z.sample(rng)])
            if obj_init.mode == "gripper":
                part = self._objects[init.objects.index(obj_init)]
                finger = max(part.grasp_width / 2 - 0.0003, 0.0)
                closed = True
        q = self._solve_ik(d, ee, ee_yaw)
        d.qpos[sc.finger_qpos] = finger
        d.ctrl[:7] = q
        d.ctrl[7] = self.cfg_closed if closed else self.cfg_open

        for i, (part, obj_init) in enumerate(zip(self._objects, init.objects, strict=True)):
            self._place_object(d, i, part, obj_init, rng, ee, ee_yaw)
        mujoco.mj_forward(m, d)
        for _ in range(SETTLE_STEPS):
            mujoco.mj_step(m, d)
        self.coupling.update(d)
        mujoco.mj_forward(m, d)
        self.target_pos[env] = d.site_xpos[sc.grip_site]
        self.q_des[env] = q
        self._ik_kinematics(env)
        self.target_yaw[env] = ee_yaw
        self.grip_closed[env] = closed
        self._finger_ctrl[env] = d.ctrl[7]
        self.last_action[env] = 0.0
        self._read_env(env)
        self._update_rotations()
        self._prev_ee[env] = self.ee_pos[env]
        self._prev_obj[env] = self.obj_pos[env]
        self.ee_vel[env] = 0.0
        self.obj_vel[env] = 0.0

    @property
    def finger_width(self) -> np.ndarray:
        """Distance between the fingers per environment (m): 0 closed on nothing, 0.08 open."""
        return self.finger_q.sum(axis=1)

    @property
    def cfg_open(self) -> float:
        return float(self.model.actuator_ctrlrange[7, 1])

    @property
    def cfg_closed(self) -> float:
        return float(self.model.actuator_ctrlrange[7, 0])

    def check_reachable(self, init: InitSpec, what: str) -> None:
        """Raise :class:`UnreachableStartError` unless the arm reaches every corner of ``init``'s
        box of hand positions, at both ends of its yaw range (the box a reset samples from).

        A start outside the arm's reach did not fail: the hand settled wherever the inverse
        kinematics stopped (behind the base, or with the physics diverging), and the episode
        went on from there.
        """
        hand = next((o for o in init.objects if o.mode in HAND_MODES), None)
        box = (hand.x, hand.y, hand.z) if hand else (init.ee_x, init.ee_y, init.ee_z)
        d = mujoco.MjData(self.model)
        corners = itertools.product(*((r.low, r.high) for r in (*box, init.ee_yaw)))
        for x, y, z, yaw in corners:
            goal = np.array([x, y, z])
            self._solve_ik(d, goal, yaw)
            mujoco.mj_kinematics(self.model, d)
            miss = float(np.linalg.norm(d.site_xpos[self.scene.grip_site] - goal))
            if miss > REACH_TOLERANCE:
                raise UnreachableStartError(
                    f"{what}: the arm cannot reach the hand position ({x:g}, {y:g}, {z:g}) m "
                    f"with yaw {yaw:g} rad (it ends {miss * 1000:.0f} mm away); narrow the "
                    "start's ranges"
                )

    def _solve_ik(
        self, d: mujoco.MjData, pos: np.ndarray, yaw: float, iters: int = 60
    ) -> np.ndarray:
        """Arm joints that put the grip point at ``pos`` with hand yaw ``yaw`` (set in ``d``)."""
        m, sc = self.model, self.scene
        d.qpos[sc.arm_qpos] = HOME_QPOS
        desired = yaw_rotation(np.array(yaw)) @ self._home_rot
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for _ in range(iters):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            cur = d.site_xmat[sc.grip_site].reshape(3, 3)
            err = np.concatenate([pos - d.site_xpos[sc.grip_site], rotation_error(desired, cur)])
            if np.linalg.norm(err) < 1e-5:
                break
            mujoco.mj_jacSite(m, d, jacp, jacr, sc.grip_site)
            jac = np.concatenate([jacp[:, sc.arm_dof], jacr[:, sc.arm_dof]])[None]
            q = d.qpos[sc.arm_qpos].copy()
            step = dls_step(jac, err[None], q[None], 0.01, 0.1, self.cfg.joint_weights)
            d.qpos[sc.arm_qpos] = q + step[0]
        return d.qpos[sc.arm_qpos].copy()

    def _place_object(self, d, i, part, init: ObjectInit, rng, ee, ee_yaw) -> None:
        adr = self.scene.obj_qpos[i]
        on_table_z = part.height / 2 + 0.0002
        if init.mode in HAND_MODES:
            # Turned so that a nut's flats face the pads.
            yaw = ee_yaw + (NUT_GRIP_YAW if isinstance(part, NutSpec) else 0.0)
            if init.mode == "gripper":
                pos = ee + np.array([0.0, 0.0, init.hold.sample(rng)])
            else:
                pos = np.array([ee[0], ee[1], on_table_z])
            if init.symmetric_yaw:
                # Drawn after the hold, so this part is held as it would be without the turn.
                yaw += symmetry_turn(part, rng)
        elif init.mode == "table":
            pos = np.array([init.x.sample(rng), init.y.sample(rng), on_table_z])
            yaw = init.yaw.sample(rng)
        elif init.mode == "bolt":
            bolt: BoltSpec = self._fixtures[init.fixture].part
            x, y = self._fixtures[init.fixture].xy
            bottom = bolt.seat_z + init.turns.sample(rng) * part.pitch
            pos = np.array([x, y, bottom + part.height / 2])
            # The yaw that satisfies the thread equation exactly at this height.
            yaw = (bottom - bolt.seat_z) / (part.pitch / (2 * math.pi))
        elif init.mode == "hole":
            placed = self._fixtures[init.fixture]
            hole: HoleSpec = placed.part
            depth = init.depth.sample(rng)
            pos = np.array([*placed.xy, hole.entrance_z - depth + part.height / 2])
            yaw = placed.yaw + init.yaw.sample(rng)
        else:  # validated on load; kept for users building SimTask by hand
            raise ValueError(f"unknown initial mode {init.mode!r}")
        if isinstance(part, NutSpec):
            d.qpos[adr[:3]] = pos
            d.qpos[adr[3]] = yaw
            d.qpos[adr[4:6]] = 0.0
            if init.mode == "bolt":
                pair = next(
                    k
                    for k, p in enumerate(self.scene.threads)
                    if p.obj == i and p.fixture == init.fixture
                )
                self.coupling.engage(d, pair)
        else:
            d.qpos[adr[:3]] = pos
            d.qpos[adr[3:7]] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]

    # ------------------------------------------------------------------ step
    def apply_action(self, actions: np.ndarray) -> None:
        """Turn actions (N, 5) into joint and finger targets for every environment.

        The targets reach the actuators in :meth:`simulate`, which must follow (``step`` does both).
        """
        cfg = self.cfg
        a = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
        self.last_action[:] = a
        self.grip_closed = a[:, 4] > cfg.grip_threshold
        target = self.target_pos + a[:, :3] * cfg.pos_step
        target = np.clip(target, cfg.workspace_low, cfg.workspace_high)
        holding = self.grip_closed & (self.finger_width > cfg.holding_width)
        lead = np.where(holding, cfg.max_lead_closed, cfg.max_lead)[:, None]
        self.target_pos = self.ee_pos + np.clip(target - self.ee_pos, -lead, lead)
        self.target_yaw = np.clip(self.target_yaw + a[:, 3] * cfg.yaw_step, *cfg.yaw_limits)

        # The commanded posture's kinematics are normally up to date (simulate evaluates them in
        # parallel); only a caller that changed q_des some other way pays for them here.
        for e in np.flatnonzero(np.any(self._ik_q != self.q_des, axis=1)):
            self._ik_kinematics(e)
        arm_dof = self.scene.arm_dof
        jac = np.concatenate([self._jacp[:, :, arm_dof], self._jacr[:, :, arm_dof]], axis=1)
        desired = yaw_rotation(self.target_yaw) @ self._home_rot
        err = np.concatenate(
            [self.target_pos - self._ik_pos, rotation_error(desired, self._ik_rot)], axis=1
        )
        self.q_des = self.q_des + dls_step(
            jac, err, self.q_des, cfg.damping, cfg.nullspace_gain, cfg.joint_weights
        )
        self.q_des = np.clip(self.q_des, self._q_low, self._q_high)
        self._finger_ctrl = np.where(self.grip_closed, self.cfg_closed, self.cfg_open)

    def _ik_kinematics(self, e: int) -> None:
        """Grip point, rotation and Jacobian of env ``e``'s commanded posture ``q_des[e]``."""
        m, d, sc = self.model, self._ik_datas[e], self.scene
        d.qpos[sc.arm_qpos] = self.q_des[e]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, self._jacp[e], self._jacr[e], sc.grip_site)
        self._ik_pos[e] = d.site_xpos[sc.grip_site]
        self._ik_rot[e] = d.site_xmat[sc.grip_site].reshape(3, 3)
        self._ik_q[e] = self.q_des[e]

    def simulate(self) -> None:
        """Advance every environment by one control period, then update thread couplings."""
        others = [self._pool.submit(self._step_shard, s) for s in self._shards[1:]]
        self._step_shard(self._shards[0])
        for future in others:
            future.result()
        self._update_rotations()
        self.ee_vel = (self.ee_pos - self._prev_ee) / self.control_dt
        self.obj_vel = (self.obj_pos - self._prev_obj) / self.control_dt
        self._prev_ee = self.ee_pos.copy()
        self._prev_obj = self.obj_pos.copy()

    def _step_shard(self, envs: np.ndarray) -> None:
        """Everything per-environment of one control step, for one worker's environments.

        mj_step and the other MuJoCo calls release the GIL, so the Python here (thread coupling,
        state reads) overlaps with the other workers' physics instead of running after it.
        """
        m, n = self.model, self.cfg.substeps
        for e in envs:
            d = self.datas[e]
            d.ctrl[:7] = self.q_des[e]
            d.ctrl[7] = self._finger_ctrl[e]
            for _ in range(n):
                mujoco.mj_step(m, d)
            # On a NaN or runaway value MuJoCo warns and silently resets the data to qpos0, which
            # would continue the episode from a nonsense state; flag it so the episode ends.
            diverged = sum(d.warning[w].number for w in DIVERGENCE_WARNINGS)
            self.unstable[e] = diverged > self._divergences[e]
            self._divergences[e] = diverged
            self.coupling.update(d)
            self._read_env(e)
            # The next apply_action linearises around the posture just commanded.
            self._ik_kinematics(e)

    def step(self, actions: np.ndarray) -> None:
        self.apply_action(actions)
        self.simulate()

    def _update_rotations(self) -> None:
        # From the quaternions, batched, rather than MuJoCo's xmat: the two differ in the last bit,
        # which tilt (arccos near 1) and a toppled part's yaw amplify to visible differences.
        self.obj_rot[:, : len(self._objects)] = quat_to_mat(self._obj_quat)

    def _read_env(self, e: int) -> None:
        """Copy env ``e``'s state into the batch arrays; ``obj_rot`` follows from ``_obj_quat``
        (see ``_update_rotations``)."""
        d, sc = self.datas[e], self.scene
        self.ee_pos[e] = d.site_xpos[sc.grip_site]
        self.ee_rot[e] = d.site_xmat[sc.grip_site].reshape(3, 3)
        self.finger_q[e] = d.qpos[sc.finger_qpos]
        k = len(sc.obj_bodies)
        self.obj_pos[e, :k] = d.xpos[sc.obj_bodies]
        self._obj_quat[e] = d.xquat[sc.obj_bodies]
        for t, pair in enumerate(sc.threads):
            self.engaged_thread[e, t] = d.eq_active[pair.eq_ids[0]]

    # ------------------------------------------------------------------ context
    def context(self, step_count: np.ndarray) -> dict[str, np.ndarray]:
        """The reward context of every environment (see ``CONTEXT_DOC``), without ``stage``."""
        n = self.num_envs
        om = self.obj_mask[None]
        obj_pos = self.obj_pos * om[..., None]
        tilt = np.arccos(np.clip(self.obj_rot[..., 2, 2], -1.0, 1.0)) * om
        obj_yaw = np.arctan2(self.obj_rot[..., 1, 0], self.obj_rot[..., 0, 0]) * om
        # |cos|: upside down, the part's bottom is the face that was its top.
        bottom = (obj_pos[..., 2] - 0.5 * self.obj_height * np.abs(np.cos(tilt))) * om
        width = self.finger_width
        to_ee = (self.ee_pos[:, None] - obj_pos) * om[..., None]

        closed = self.grip_closed[:, None]
        lateral = np.linalg.norm(to_ee[..., :2], axis=-1)
        grasped = (
            closed
            & (width[:, None] >= min_grasp_width(self.obj_width, self.obj_height))
            # A nut's corners, or a rectangular peg across its longer side, open them wider.
            & (width[:, None] <= self.obj_widest * 1.2 + 0.002)
            & (lateral <= 0.012)
            & (np.abs(to_ee[..., 2]) <= max_grip_offset(self.obj_height))
            & (om > 0)
        )

        bottom_centre = obj_pos.copy()
        bottom_centre[..., 2] = bottom
        fm = self.obj_fix_mask[None]
        obj_to_fix = (self.obj_fix_pos[None] - bottom_centre) * fm[..., None]
        period = np.where(self.yaw_period > 0, self.yaw_period, 1.0)
        yaw_error = (
            np.where(self.yaw_period > 0, wrap_angle(obj_yaw - self.obj_fix_yaw, period), 0.0) * fm
        )

        engaged = np.zeros((n, MAX_OBJECTS), dtype=bool)
        for t, obj in self._own_threads:
            engaged[:, obj] |= self.engaged_thread[:, t]
        in_hole = (
            self.is_peg[None]
            & (np.linalg.norm(obj_to_fix[..., :2], axis=-1) <= self.obj_hole_radius + 0.0005)
            & (obj_to_fix[..., 2] > 0.001)
            & (tilt < 0.3)
        )
        engaged |= in_hole
        depth = np.where(engaged, np.maximum(obj_to_fix[..., 2], 0.0), 0.0)

        return {
            "ee_pos": self.ee_pos.copy(),
            "ee_vel": self.ee_vel.copy(),
            "ee_yaw": hand_yaw(self.ee_rot, self._home_rot),
            "gripper_width": width,
            "grip_closed": self.grip_closed.astype(np.float64),
            "action": self.last_action.copy(),
            "obj_mask": np.broadcast_to(om, (n, MAX_OBJECTS)).copy(),
            "obj_pos": obj_pos,
            "obj_vel": self.obj_vel * om[..., None],
            "obj_yaw": obj_yaw,
            "obj_tilt": tilt,
            "obj_height": np.broadcast_to(self.obj_height, (n, MAX_OBJECTS)).copy(),
            "obj_width": np.broadcast_to(self.obj_width, (n, MAX_OBJECTS)).copy(),
            "obj_bottom_z": bottom,
            "obj_to_ee": to_ee,
            "grasped": grasped.astype(np.float64),
            "fix_mask": np.broadcast_to(self.fix_mask, (n, MAX_FIXTURES)).copy(),
            "fix_pos": np.broadcast_to(self.fix_pos, (n, MAX_FIXTURES, 3)).copy(),
            "fix_yaw": np.broadcast_to(self.fix_yaw, (n, MAX_FIXTURES)).copy(),
            "seat_z": np.broadcast_to(self.seat_z, (n, MAX_FIXTURES)).copy(),
            "obj_fixture": np.broadcast_to(self.obj_fixture_index, (n, MAX_OBJECTS)).copy(),
            "obj_to_fix": obj_to_fix,
            "yaw_error": yaw_error,
            "engaged": engaged.astype(np.float64),
            "insertion_depth": depth,
            "seat_gap": (bottom - self.obj_seat_z[None]) * fm,
            "thread_lead": np.broadcast_to(self.obj_lead, (n, MAX_OBJECTS)).copy(),
            "n_stages": np.full(n, float(self.task.n_stages)),
            "time_frac": np.asarray(step_count, dtype=np.float64) / self.task.max_steps,
        }
