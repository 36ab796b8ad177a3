"""Screw threads: one pitch per turn, self-locking, release past the tip, engagement on the tip."""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np
import pytest

from itskill.sim.vec_env import BatchEnv
from itskill.tasks import all_tasks, make_env
from itskill.tasks.spec import load_parts, load_task_file

TURN_TORQUE = 0.01
"""N m on the nut's yaw joint: well above its friction (2e-3 N m), tiny for the thread locks."""


class Nut:
    """Hand access to object 0 of a nut task: its joint chain and the bolt it belongs to."""

    def __init__(self, task: str, seed: int = 0) -> None:
        self.env = make_env(task)
        self.env.reset(seed=seed)
        self.sim = self.env.batch.sim
        self.data = self.env.data
        self.qpos = self.sim.scene.obj_qpos[0]
        self.dof = self.sim.scene.obj_dof[0]
        self.spec = all_tasks()[task]
        self.pitch = self.spec.objects[0].pitch
        self.height = self.spec.objects[0].height
        self.bolt = self.spec.fixtures[0]

    @property
    def z(self) -> float:
        return float(self.data.qpos[self.qpos[2]])

    @property
    def yaw(self) -> float:
        return float(self.data.qpos[self.qpos[3]])

    @property
    def bottom(self) -> float:
        return self.z - self.height / 2

    @property
    def engaged(self) -> bool:
        return bool(self.sim.coupling.engaged(self.data)[0])

    def torque(self, value: float) -> None:
        self.data.qfrc_applied[self.dof[3]] = value

    def step(self, n: int = 1) -> None:
        """Control periods with the arm holding still; couplings update after each."""
        for _ in range(n):
            self.sim.simulate()

    def turn(self, radians: float, speed: float = 5.0, limit: int = 5000) -> None:
        """Turn the nut by ``radians`` (positive: counter-clockwise seen from above, i.e. up).

        A torque well above the turn's friction drives it; its speed is capped at ``speed`` rad/s
        (a hand turning a nut), so it stops within a small fraction of a turn of the target.
        """
        sign = math.copysign(1.0, radians)
        target = self.yaw + radians
        self.torque(sign * TURN_TORQUE)
        for _ in range(limit):
            self.step_physics(speed)
            if (self.yaw - target) * sign >= 0:
                break
        self.torque(0.0)
        self.data.qvel[self.dof] = 0.0

    def step_physics(self, speed: float = 5.0) -> None:
        """One physics step and a coupling update, the nut's turn capped at ``speed`` rad/s."""
        mujoco.mj_step(self.sim.model, self.data)
        self.sim.coupling.update(self.data)
        w = self.data.qvel[self.dof[3]]
        self.data.qvel[self.dof[3]] = float(np.clip(w, -speed, speed))

    def drop_from(self, x: float, y: float, height_above_tip: float) -> None:
        """Release the thread and hold the nut upright, still, above the bolt's tip at (x, y)."""
        self.sim.coupling.release(self.data, 0)
        self.data.qpos[self.qpos[:3]] = [x, y, self.bolt.part.tip_z + height_above_tip]
        self.data.qpos[self.qpos[3:6]] = 0.0
        self.data.qvel[self.dof] = 0.0


@pytest.mark.parametrize("task", ["screw_nut_m12", "screw_nut_m16"])
def test_one_turn_advances_one_pitch(task):
    nut = Nut(task)
    assert nut.engaged
    z0, yaw0 = nut.z, nut.yaw
    nut.turn(-2 * math.pi)  # clockwise: screw down
    nut.step(3)
    turned = nut.yaw - yaw0
    assert turned == pytest.approx(-2 * math.pi, rel=0.05)
    assert nut.z - z0 == pytest.approx(-nut.pitch * abs(turned) / (2 * math.pi), rel=0.05)
    assert nut.z - z0 == pytest.approx(-nut.pitch, rel=0.05)


@pytest.mark.parametrize("task", ["screw_nut_m12", "screw_nut_m16"])
def test_engaged_nut_holds_under_gravity(task):
    nut = Nut(task, seed=1)
    z0 = nut.z
    nut.step(round(1.0 / nut.sim.control_dt))  # one second, nothing touching the nut
    assert nut.engaged
    assert abs(nut.z - z0) < 1e-4


def test_unscrewing_past_the_tip_releases_the_thread():
    nut = Nut("unscrew_nut_m12")
    assert nut.engaged
    tip = nut.bolt.part.tip_z
    released_at = None
    nut.torque(TURN_TORQUE)  # counter-clockwise: up the thread
    for _ in range(5000):
        nut.step_physics()
        if not nut.engaged:
            released_at = nut.bottom
            break
    nut.torque(0.0)
    assert released_at is not None and released_at > tip
    # Released: every lock is off and the thread crest is back on the tip, ready to catch the
    # nut again if it is lowered onto the bolt.
    pair = nut.sim.scene.threads[0]
    assert not nut.data.eq_active[list(pair.eq_ids)].any()
    np.testing.assert_allclose(
        nut.data.mocap_pos[pair.crest_mocap], nut.sim.scene.crest_home[pair.crest_mocap]
    )
    # Carried clear of the bolt, it stays free.
    x, y = nut.bolt.xy
    nut.drop_from(x + 0.03, y, 0.01)
    nut.step(5)
    assert not nut.engaged


@pytest.mark.parametrize(("offset", "engages"), [(0.0, True), (0.005, False)])
def test_nut_lowered_on_the_tip_engages_only_when_centred(offset, engages):
    nut = Nut("screw_nut_m12")
    x, y = nut.bolt.xy
    nut.drop_from(x + offset, y, 0.004)
    seen = False
    for _ in range(round(0.5 / nut.sim.control_dt)):
        nut.step()
        seen |= nut.engaged
    assert seen is engages
    if engages:
        assert abs(nut.data.qpos[nut.qpos[0]] - x) < 1e-3


def test_a_nut_upright_after_a_whole_turn_of_tilt_engages_and_stays_put():
    # The tilt hinges are unlimited: a nut that tumbled a whole turn round stands upright with
    # its hinge at 2 pi, and was never engaged on the bolt it sat centred on.
    nut = Nut("screw_nut_m12")
    x, y = nut.bolt.xy
    nut.drop_from(x, y, 0.004)
    nut.data.qpos[nut.qpos[4]] = 2 * math.pi
    seen = False
    for _ in range(round(0.5 / nut.sim.control_dt)):
        nut.step()
        seen |= nut.engaged
    assert seen
    # Engaged, the locks hold the tilt at 0: the hinge is unwound, not spun back a whole turn.
    assert abs(nut.data.qpos[nut.qpos[4]]) < 0.05
    assert abs(nut.data.qpos[nut.qpos[0]] - x) < 1e-3


def test_a_nut_threaded_on_another_bolt_is_not_engaged_on_its_own(tmp_path):
    # A task that moves the nut from one bolt to the other started out done: the nut counted as
    # engaged (and seated) on its bolt while it sat on the other one, 18 cm away.
    path = tmp_path / "move.toml"
    path.write_text(
        """[[task]]
id = "move_nut_m12"
family = "nutbolt"
kind = "basic"
command = "Move the nut to the other bolt"
skills = ["Place"]
actions = ["place"]
objects = ["nut_m12"]
fixtures = [{ part = "bolt_m12", xy = [0.55, 0.08] }, { part = "bolt_m12", xy = [0.55, -0.1] }]
object_fixture = [0]
max_steps = 30
success = "seated(0, 0.004)"
stages = [{ name = "place", done = "engaged(0)" }]
[task.init]
objects = [{ mode = "bolt", fixture = 1, turns = [1.0, 1.0] }]
"""
    )
    parts = load_parts(Path(str(resources.files("itskill.tasks") / "data" / "parts.toml")))
    (spec,) = load_task_file(path, parts)
    env = BatchEnv(spec.to_sim_task(), num_envs=1, seed=0, n_threads=1)
    env.reset()
    ctx = env.context()
    env.close()
    assert ctx["obj_pos"][0, 0, 1] < -0.09  # on the other bolt, threaded
    assert ctx["engaged"][0, 0] == 0.0 and ctx["insertion_depth"][0, 0] == 0.0
    assert not spec.success(ctx)[0]
