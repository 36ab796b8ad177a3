"""Screw threads as switchable equality constraints.

A nut resting on its bolt's tip, centred and upright, engages the thread: five joint equalities
lock it onto the bolt axis, keep it upright and tie its height to its turn,
``z = seat + lead * yaw`` with ``lead = pitch / 2 pi`` (right-hand thread: turning clockwise seen
from above drives it down). Engaged, the nut can only advance by turning, one pitch per turn, and
holds against gravity (its turn has friction, so the thread is self-locking). Unscrewed past the
tip, the coupling releases and the nut is free again.

The coupling equation has a fixed phase, but a hex nut looks the same every 60 degrees: on
engagement the nut's yaw coordinate is shifted by whole sixths of a turn (which moves no geometry)
so the equation holds to within a twelfth of a pitch, which the constraint then closes, as a real
thread catches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco

from itskill.sim.parts import HEX_SYMMETRY
from itskill.sim.scene import PARKED_Z, Scene


@dataclass(frozen=True)
class ThreadConfig:
    """Engagement tolerances (metres, radians)."""

    radial_tolerance: float = 0.002
    tilt_tolerance: float = math.radians(12)
    engage_above: float = 0.001
    """A nut engages when its bottom is at most this far above the tip ..."""
    engage_below: float = 0.003
    """... and at most this far below it."""
    release_above: float = 0.0015
    """An engaged nut whose bottom rises this far above the tip comes off. It must exceed
    ``engage_above`` plus the engagement snap (at most a twelfth of a pitch), or a nut caught just
    above the tip comes off again at the next step and flickers between engaged and free."""


class ThreadCoupling:
    """Switches each environment's thread constraints from the nut and bolt poses."""

    def __init__(self, scene: Scene, config: ThreadConfig | None = None) -> None:
        self.scene = scene
        self.config = config or ThreadConfig()
        self._tips = []
        self._nut_half_height = []
        for pair in scene.threads:
            placed = scene.spec.fixtures[pair.fixture]
            self._tips.append((placed.xy[0], placed.xy[1], placed.part.tip_z))
            self._nut_half_height.append(scene.spec.objects[pair.obj].height / 2)
        # qpos addresses of each pair's nut chain: x, y, z, yaw, tilt x, tilt y.
        self._nut_qpos = [scene.obj_qpos[pair.obj][:6] for pair in scene.threads]

    def engaged(self, data: mujoco.MjData) -> list[bool]:
        """Per thread pair: is it engaged in this environment?"""
        return [bool(data.eq_active[pair.eq_ids[0]]) for pair in self.scene.threads]

    def engage(self, data: mujoco.MjData, index: int) -> None:
        """Couple pair ``index``: shift the nut's yaw by whole turns, switch the locks on."""
        pair = self.scene.threads[index]
        adr = self.scene.obj_qpos[pair.obj]
        z, yaw = data.qpos[adr[2]], data.qpos[adr[3]]
        sixths = round(((z - pair.seat_center_z) / pair.lead - yaw) / HEX_SYMMETRY)
        data.qpos[adr[3]] = yaw + HEX_SYMMETRY * sixths
        # The locks hold the tilt hinges at 0: one wound a whole turn round would be spun back.
        data.qpos[adr[4:6]] = [math.remainder(a, 2 * math.pi) for a in data.qpos[adr[4:6]]]
        data.eq_active[list(pair.eq_ids)] = 1
        data.mocap_pos[pair.crest_mocap, 2] = PARKED_Z

    def release(self, data: mujoco.MjData, index: int) -> None:
        pair = self.scene.threads[index]
        data.eq_active[list(pair.eq_ids)] = 0
        data.mocap_pos[pair.crest_mocap] = self.scene.crest_home[pair.crest_mocap]

    def update(self, data: mujoco.MjData) -> None:
        """Engage or release every pair of one environment from its current state.

        Runs once per environment per control step, so it reads plain floats (one ``tolist`` per
        nut) rather than indexing NumPy arrays element by element.
        """
        cfg = self.config
        active = data.eq_active
        # Nuts engaged at the start of the update: a nut released below cannot catch another
        # bolt's thread in the same update.
        busy_nuts = {p.obj for p in self.scene.threads if active[p.eq_ids[0]]}
        for k, pair in enumerate(self.scene.threads):
            x, y, z, _, tilt_x, tilt_y = data.qpos[self._nut_qpos[k]].tolist()
            # The hinges are unlimited: a nut tumbled a whole turn round stands upright at 2 pi.
            tilt = math.hypot(
                math.remainder(tilt_x, 2 * math.pi), math.remainder(tilt_y, 2 * math.pi)
            )
            bottom = z - self._nut_half_height[k]
            tip_x, tip_y, tip_z = self._tips[k]
            if active[pair.eq_ids[0]]:
                if bottom > tip_z + cfg.release_above:
                    self.release(data, k)
                continue
            if pair.obj in busy_nuts:
                continue
            if (
                math.hypot(x - tip_x, y - tip_y) <= cfg.radial_tolerance
                and tilt <= cfg.tilt_tolerance
                and tip_z - cfg.engage_below <= bottom <= tip_z + cfg.engage_above
            ):
                self.engage(data, k)
                busy_nuts.add(pair.obj)
