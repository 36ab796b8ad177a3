"""``TaskEnv``: one task environment with Gymnasium's API, for users and their tools.

It is a ``BatchEnv`` of one, so a single environment and a batch can never behave differently.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from itskill.sim.scene import offscreen_renderer
from itskill.sim.task import RewardFn, SimTask
from itskill.sim.vec_env import BatchEnv, action_space, observation_space


class TaskEnv(gym.Env):
    """A single ``SimTask`` environment (``reset(seed=...)``, ``step``, ``render``)."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: SimTask,
        reward_fn: RewardFn | None = None,
        render_mode: str | None = None,
        camera: str = "front",
        width: int = 640,
        height: int = 480,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            # "human" silently rendered nothing.
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.task = task
        self.batch = BatchEnv(task, num_envs=1, reward_fn=reward_fn, n_threads=1)
        self.observation_space = observation_space()
        self.action_space = action_space()
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1 / self.batch.sim.control_dt)}
        self._camera, self._size = camera, (width, height)
        self._renderer: mujoco.Renderer | None = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.batch.seed(seed)
        self.batch._reset_env(0)
        return self.batch.observe()[0], {}

    def step(self, action: np.ndarray):
        res = self.batch.advance(np.asarray(action).reshape(1, 5))
        info = {
            "is_success": bool(res.success[0]),
            "stage": int(res.context["stage"][0]),
            "reward_components": {k: float(np.asarray(v)[0]) for k, v in res.components.items()},
            # The physics diverged: the episode is truncated, not timed out (BatchSim.unstable).
            "unstable": bool(self.batch.sim.unstable[0]),
        }
        return (
            res.obs[0],
            float(res.reward[0]),
            bool(res.terminated[0]),
            bool(res.truncated[0]),
            info,
        )

    def context(self) -> dict[str, np.ndarray]:
        """The reward context of the current state (batched with N = 1)."""
        return self.batch.context()

    @property
    def data(self) -> mujoco.MjData:
        return self.batch.sim.datas[0]

    @property
    def model(self) -> mujoco.MjModel:
        return self.batch.sim.model

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = offscreen_renderer(self.model, *self._size)
        self._renderer.update_scene(self.data, camera=self._camera)
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.batch.close()
