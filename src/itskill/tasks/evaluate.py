"""Success-rate evaluation of a policy on a task: scripted controllers and trained checkpoints.

A policy is anything with ``reset(env_ids)`` and ``__call__(ctx) -> actions`` (:class:`Policy`); the
observation a trained network sees is a pure function of the reward context, so checkpoints fit the
same interface as the scripted controllers.
"""

from __future__ import annotations

import argparse
import time
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from stable_baselines3 import A2C, PPO

from itskill.errors import PicklableError
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.stats import wilson_interval
from itskill.tasks import make_batch_env
from itskill.tasks.scripted import ScriptedPolicy
from itskill.tasks.spec import TaskSpec

SCRIPTED = "scripted"
HELD_OUT_SEED = 10_000
"""Seed of the held-out episodes, which no training run trains or evaluates on (a run's own
episodes come from its seed, its evaluations' from 20,000 on): the library's success rates,
``itskill learn``'s final figure and an experiment's held-out check are measured on them."""
HELD_OUT_ENVS = 25
"""Environments the held-out episodes are run in together: which episodes a seed gives depends
on it too, so every held-out figure uses this one."""


@runtime_checkable
class Policy(Protocol):
    """Acts for a batch of environments; ``reset`` restarts the given environments' episodes."""

    def reset(self, env_ids: np.ndarray | None = None) -> None: ...

    def __call__(self, ctx: dict[str, np.ndarray]) -> np.ndarray: ...


PolicyFactory = Callable[[TaskSpec, int], Policy]
"""``factory(spec, num_envs) -> Policy``."""


class RandomPolicy:
    """Uniformly random actions in [-1, 1]^5, seeded: the success a task gives away by chance."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def reset(self, env_ids: np.ndarray | None = None) -> None:
        """Nothing to reset: the actions do not depend on the past."""

    def __call__(self, ctx: dict[str, np.ndarray]) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, (len(ctx["ee_pos"]), 5))


class NoiseError(ValueError, argparse.ArgumentTypeError):
    """An action-noise standard deviation that is not one; argparse shows its message as is."""


def noise_sigma(value: str | float) -> float:
    """``value`` as an action-noise standard deviation: a finite number of 0 or more, else
    :class:`NoiseError`. Also an argparse ``type=`` for a benchmark's ``--noise``."""
    try:
        sigma = float(value)
    except (TypeError, ValueError):
        raise NoiseError(f"the action noise must be a number, got {value!r}") from None
    if not 0.0 <= sigma < float("inf"):
        raise NoiseError(
            f"the action noise must be a finite standard deviation of 0 or more, got {value}"
        )
    return sigma + 0.0  # -0.0 as 0.0


class NoisyPolicy:
    """``policy``'s actions plus Gaussian noise of standard deviation ``sigma``, clipped to
    [-1, 1], seeded: how a policy fares under the noise a learner explores with around it (a
    transfer target acting through its sources adds its own ``exp(log_std)``)."""

    def __init__(self, policy: Policy, sigma: float, seed: int = 0) -> None:
        self.policy, self.sigma = policy, noise_sigma(sigma)
        self.rng = np.random.default_rng(seed)

    def reset(self, env_ids: np.ndarray | None = None) -> None:
        self.policy.reset(env_ids)

    def __call__(self, ctx: dict[str, np.ndarray]) -> np.ndarray:
        actions = np.asarray(self.policy(ctx), dtype=np.float64)
        return np.clip(actions + self.rng.normal(0.0, self.sigma, actions.shape), -1.0, 1.0)


class CheckpointError(PicklableError, ValueError):
    """A policy checkpoint that is missing, unreadable or does not fit the observation layout."""

    def __init__(self, path: str | Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem


class PolicyActor:
    """A Stable-Baselines3 policy (anything with SB3's ``predict``) acting deterministically
    (the mean action), or sampling its actions with ``deterministic=False``."""

    def __init__(self, policy: Any, deterministic: bool = True) -> None:
        self.policy, self.deterministic = policy, deterministic

    def reset(self, env_ids: np.ndarray | None = None) -> None:
        """Nothing to reset: PPO and A2C policies are feed-forward, without memory."""

    def __call__(self, ctx: dict[str, np.ndarray]) -> np.ndarray:
        obs = OBSERVATION_LAYOUT.build(ctx)
        actions, _ = self.policy.predict(obs, deterministic=self.deterministic)
        return np.asarray(actions)


class CheckpointPolicy(PolicyActor):
    """A Stable-Baselines3 PPO or A2C checkpoint (``.zip``) acting deterministically."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        super().__init__(_load_sb3(self.path).policy)


def _load_sb3(path: Path) -> Any:
    """Load ``path`` as PPO, else as A2C (both predict the same way; the zip does not say which)."""
    if path.is_dir():
        raise CheckpointError(
            path,
            "a training run directory: resolve it with itskill.rl.as_policy first "
            "(the itskill CLI does; tasks/ does not import the rl layer)",
        )
    if not path.is_file():
        raise CheckpointError(
            path,
            f"no such file or directory (expected {SCRIPTED!r}, a training run directory, "
            "skill:NAME or a Stable-Baselines3 .zip)",
        )
    if not zipfile.is_zipfile(path):
        raise CheckpointError(path, "not a Stable-Baselines3 checkpoint (not a zip archive)")
    errors = []
    for algo in (PPO, A2C):
        try:
            model = algo.load(path, device="cpu")
            break
        except Exception as err:  # SB3 raises many kinds for a damaged or foreign archive
            errors.append(f"{algo.__name__}: {type(err).__name__}: {err}")
    else:
        raise CheckpointError(path, "could not load as PPO or A2C: " + "; ".join(errors))
    shape = getattr(model.observation_space, "shape", None)
    if shape != (OBSERVATION_LAYOUT.size,):
        raise CheckpointError(
            path, f"observation shape {shape}, the task layout has ({OBSERVATION_LAYOUT.size},)"
        )
    return model


def make_policy(
    policy: str | Path | Policy | PolicyFactory, spec: TaskSpec, num_envs: int
) -> Policy:
    """Resolve ``"scripted"``, a checkpoint path, a policy factory or a policy into a ``Policy``.

    A ready ``Policy`` is used as it is and must act for ``num_envs`` environments.
    """
    if isinstance(policy, str | Path):
        if str(policy) == SCRIPTED:
            return ScriptedPolicy(spec, num_envs)
        return CheckpointPolicy(policy)
    # A class has ``reset`` and ``__call__`` too, so it would pass the protocol check: it is a
    # factory.
    if isinstance(policy, Policy) and not isinstance(policy, type):
        return policy
    return policy(spec, num_envs)


def describe_policy(policy: str | Path | Policy | PolicyFactory) -> str:
    """A short name for reports: ``scripted``, the checkpoint path, or the class name."""
    if isinstance(policy, str | Path):
        return str(policy)
    return getattr(policy, "__name__", type(policy).__name__)


def with_noise(
    policy: str | Path | Policy | PolicyFactory, sigma: float, seed: int = 0
) -> str | Path | Policy | PolicyFactory:
    """``policy`` with :class:`NoisyPolicy`'s noise of standard deviation ``sigma`` on its
    actions, as a factory: each policy it makes draws the noise afresh from ``seed``, and one
    that :func:`make_policy` builds (``"scripted"``, a checkpoint, a factory) is built for the
    environments :func:`evaluate` runs, fewer where episodes are fewer (a ready ``Policy`` is
    wrapped as it is). ``policy`` itself where ``sigma`` is 0."""
    sigma = noise_sigma(sigma)
    if not sigma:
        return policy

    def noisy(spec: TaskSpec, num_envs: int) -> Policy:
        return NoisyPolicy(make_policy(policy, spec, num_envs), sigma, seed)

    noisy.__name__ = f"{describe_policy(policy)} with action noise {sigma:g}"
    return noisy


@dataclass(frozen=True)
class EvalResult:
    """Outcome of :func:`evaluate`; ``ci_low``/``ci_high`` are the 95% Wilson interval."""

    task: str
    episodes: int
    successes: int
    success_rate: float
    ci_low: float
    ci_high: float
    mean_length: float
    wall_s: float
    policy: str
    mean_stages_done: float
    """Subtasks (stages) finished at the end of an episode, averaged: progress where success is
    still 0 (``n_stages`` on success)."""
    n_stages: int
    stage_steps: list[float]
    """Steps an episode spent in each stage, averaged: where a policy loses its time. The last
    stage also counts the steps after it is done (a task's stage index stops at its last)."""
    outcomes: list[bool] = field(default_factory=list)
    """Each counted episode's success, environment by environment and each environment's
    episodes in turn: the same episode sits at the same index whatever the policy, so two
    policies measured with the same ``seed`` and ``num_envs`` can be compared episode by episode."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def episode_quotas(episodes: int, num_envs: int) -> np.ndarray:
    """How many episodes each environment runs so that exactly ``episodes`` are counted."""
    quotas = np.full(num_envs, episodes // num_envs, dtype=np.int64)
    quotas[: episodes % num_envs] += 1
    return quotas


def evaluate(
    spec: TaskSpec,
    policy: str | Path | Policy | PolicyFactory = SCRIPTED,
    episodes: int = 100,
    seed: int = 0,
    num_envs: int = 16,
) -> EvalResult:
    """Run exactly ``episodes`` episodes of ``spec`` and report the success rate.

    Environment ``i`` runs the first ``quota[i]`` episodes of its own seeded sequence
    (:func:`episode_quotas`), so the set of counted episodes depends only on ``seed`` and
    ``num_envs``, never on which environment happens to finish first. At most ``episodes``
    environments run: an environment with no episode to count would only cost time, so 10
    episodes asked of 16 environments are those of 10.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be positive, got {episodes}")
    num_envs = max(1, min(num_envs, episodes))
    quotas = episode_quotas(episodes, num_envs)
    first_index = np.cumsum(quotas) - quotas  # where each environment's episodes go in outcomes
    start = time.perf_counter()
    env = make_batch_env(spec, num_envs=num_envs, seed=seed)
    try:
        actor = make_policy(policy, spec, num_envs)
        env.reset()
        actor.reset()
        done_count = np.zeros(num_envs, dtype=np.int64)
        running_length = np.zeros(num_envs, dtype=np.int64)
        running_stage_steps = np.zeros((num_envs, len(spec.stages)))
        outcomes = np.zeros(episodes, dtype=bool)
        lengths, stages, stage_steps = [], [], []
        while (done_count < quotas).any():
            ctx = env.context()
            running_stage_steps[np.arange(num_envs), ctx["stage"]] += 1
            _, _, dones, infos = env.step(actor(ctx))
            running_length += 1
            for e in np.flatnonzero(dones):
                if done_count[e] < quotas[e]:
                    outcomes[first_index[e] + done_count[e]] = bool(infos[e]["is_success"])
                    stages.append(infos[e]["stages_done"])
                    lengths.append(running_length[e])
                    stage_steps.append(running_stage_steps[e].copy())
                done_count[e] += 1
            if dones.any():
                running_length[dones] = 0
                running_stage_steps[dones] = 0.0
                actor.reset(np.flatnonzero(dones))
    finally:
        env.close()
    successes = int(outcomes.sum())
    low, high = wilson_interval(successes, episodes)
    return EvalResult(
        task=spec.id,
        episodes=episodes,
        successes=successes,
        success_rate=successes / episodes,
        ci_low=low,
        ci_high=high,
        mean_length=float(np.mean(lengths)),
        wall_s=time.perf_counter() - start,
        policy=describe_policy(policy),
        mean_stages_done=float(np.mean(stages)),
        n_stages=len(spec.stages),
        stage_steps=[float(x) for x in np.mean(stage_steps, axis=0)],
        outcomes=outcomes.tolist(),
    )
