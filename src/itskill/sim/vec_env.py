"""``BatchEnv``: N task environments stepped together, as a Stable-Baselines3 ``VecEnv``.

Episodes end on success (if the task says so) or on the time limit; a finished environment is reset
at once and its last observation is returned in ``infos[i]["terminal_observation"]``, with
``infos[i]["TimeLimit.truncated"]`` telling a time limit from a real end, as SB3 expects.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from itskill.sim.batch import BatchSim
from itskill.sim.controller import ControllerConfig
from itskill.sim.layout import MAX_STAGES, OBSERVATION_LAYOUT
from itskill.sim.task import RewardFn, SimTask, TrainingStart


def observation_space() -> gym.spaces.Box:
    """The observation space every task shares (:data:`OBSERVATION_LAYOUT`)."""
    return gym.spaces.Box(-np.inf, np.inf, shape=(OBSERVATION_LAYOUT.size,), dtype=np.float32)


def action_space() -> gym.spaces.Box:
    """The action space every task shares: end-effector x, y, z and yaw steps, and the
    gripper (closed above 0), each in [-1, 1]."""
    return gym.spaces.Box(-1.0, 1.0, shape=(5,), dtype=np.float32)


class StepResult:
    """What one control step produced for every environment, before any automatic reset."""

    __slots__ = ("components", "context", "obs", "reward", "success", "terminated", "truncated")

    def __init__(self, obs, reward, success, terminated, truncated, components, context) -> None:
        self.obs = obs
        self.reward = reward
        self.success = success
        self.terminated = terminated
        self.truncated = truncated
        self.components = components
        self.context = context


class BatchEnv(VecEnv):
    """``num_envs`` copies of ``task``, stepped together on ``n_threads`` threads.

    ``reward_fn`` overrides the task's own reward (the trainer passes the reward under test);
    with neither, the reward is zero and only success is reported. With ``training=True`` each
    episode starts from one of the task's ``training_starts`` with its share of probability, and
    such an episode's final ``info`` says so (``"training_start"``) so that logs can leave it out
    of the task's success rate; evaluation environments leave ``training`` off.
    """

    def __init__(
        self,
        task: SimTask,
        num_envs: int = 8,
        seed: int | None = None,
        reward_fn: RewardFn | None = None,
        n_threads: int | None = None,
        controller: ControllerConfig | None = None,
        training: bool = False,
    ) -> None:
        if task.n_stages > MAX_STAGES:
            raise ValueError(f"{task.name}: {task.n_stages} stages, the layout holds {MAX_STAGES}")
        self.task = task
        self.sim = BatchSim(task, num_envs, n_threads=n_threads, controller=controller)
        self.reward_fn = reward_fn or task.reward_fn
        self.training = training
        self.from_training_start = np.zeros(num_envs, dtype=bool)
        self.steps = np.zeros(num_envs, dtype=np.int64)
        self.episode_return = np.zeros(num_envs)
        self._actions = np.zeros((num_envs, 5))
        self.last_components: dict[str, np.ndarray] = {}
        """The reward components of the last step (``advance``/``step_wait``), for metrics."""
        self._rngs = self._make_rngs(seed)
        self.render_mode = None
        super().__init__(num_envs, observation_space(), action_space())

    # -------------------------------------------------------------- VecEnv API
    def _make_rngs(self, seed: int | None) -> list[np.random.Generator]:
        children = np.random.SeedSequence(seed).spawn(self.sim.num_envs)
        return [np.random.default_rng(c) for c in children]

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        self._rngs = self._make_rngs(seed)
        return [None] * self.num_envs

    def reset(self) -> np.ndarray:
        self._reset_seeds()
        self._reset_options()
        for e in range(self.num_envs):
            self._reset_env(e)
        return self.observe()

    def _reset_env(self, e: int) -> None:
        start = self._draw_start(self._rngs[e])
        self.from_training_start[e] = start is not None
        self.sim.reset_env(e, self._rngs[e], start.init if start else None)
        self.steps[e] = 0
        self.episode_return[e] = 0.0

    def _draw_start(self, rng: np.random.Generator) -> TrainingStart | None:
        """A training start with its share of probability, or None for the task's own start.

        Draws nothing from ``rng`` when not training, so evaluation episodes are the same whether
        or not the task has training starts.
        """
        if not (self.training and self.task.training_starts):
            return None
        u = rng.random()
        for start in self.task.training_starts:
            if u < start.share:
                return start
            u -= start.share
        return None

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        res = self.advance(self._actions)
        dones = res.terminated | res.truncated
        infos: list[dict[str, Any]] = []
        obs = res.obs
        for e in range(self.num_envs):
            info: dict[str, Any] = {}
            if dones[e]:
                info["terminal_observation"] = obs[e].copy()
                # A diverged env's state is MuJoCo's reset pose, which says nothing of where the
                # episode was: a learner bootstrapping a value from it would learn noise, so it
                # ends as terminal (no value after it), not as timed out.
                info["TimeLimit.truncated"] = bool(
                    res.truncated[e] and not res.terminated[e] and not self.sim.unstable[e]
                )
                info["is_success"] = bool(res.success[e])
                # The reward function's own sum: a wrapper may rescale what the learner sees.
                info["episode_return"] = float(self.episode_return[e])
                # Subtasks finished when the episode ended: all of them on success, else the
                # index of the stage it was in (progress where success is still 0).
                info["stages_done"] = (
                    self.task.n_stages if res.success[e] else int(res.context["stage"][e])
                )
                if self.from_training_start[e]:
                    info["training_start"] = True
                if self.sim.unstable[e]:
                    info["unstable"] = True
                self._reset_env(e)
            infos.append(info)
        if dones.any():
            obs = self.observe()
        return obs, res.reward.astype(np.float32), dones, infos

    def advance(self, actions: np.ndarray) -> StepResult:
        """One control step for every environment; no automatic reset."""
        self.sim.step(np.asarray(actions).reshape(self.num_envs, 5))
        self.steps += 1
        ctx = self.context()
        success = np.asarray(self.task.success_fn(ctx), dtype=bool)
        if self.reward_fn is not None:
            reward, components = self.reward_fn(ctx)
            reward = np.asarray(reward, dtype=np.float64).reshape(self.num_envs)
        else:
            reward, components = np.zeros(self.num_envs), {}
        self.episode_return += reward
        self.last_components = components
        terminated = success if self.task.terminate_on_success else np.zeros_like(success)
        # A diverged environment (see BatchSim.unstable) ends its episode: truncated here (the
        # Gymnasium env's view), terminal for a learner (step_wait's TimeLimit.truncated).
        truncated = (self.steps >= self.task.max_steps) | self.sim.unstable
        obs = OBSERVATION_LAYOUT.build(ctx)
        return StepResult(obs, reward, success, terminated, truncated, components, ctx)

    def context(self) -> dict[str, np.ndarray]:
        """The reward context of the current state, ``stage`` included."""
        ctx = self.sim.context(self.steps)
        ctx["stage"] = np.asarray(self.task.stage_fn(ctx), dtype=np.int64)
        return ctx

    def observe(self) -> np.ndarray:
        return OBSERVATION_LAYOUT.build(self.context())

    def close(self) -> None:
        self.sim.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        self._whole_batch(indices, "set_attr")
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        self._whole_batch(indices, "env_method")
        return [getattr(self, method_name)(*args, **kwargs)] * self.num_envs

    def _whole_batch(self, indices, what: str) -> None:
        # The environments share one simulator object: what a VecEnv does to some of them
        # would change (or reset) all of them.
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise NotImplementedError(
                f"{what} acts on all {self.num_envs} environments of a BatchEnv together, not "
                "on some of them"
            )

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._get_indices(indices))

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs
