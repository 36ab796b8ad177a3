"""Warm start from demonstrations: the task's scripted controller shows the policy what to do.

Some basic skills are all but unreachable by exploration alone: PPO from scratch knocks the
4 mm round peg over on nearly every approach and never finds the grasp (docs/skills.md). Every
task ships a scripted waypoint controller (:mod:`itskill.tasks.scripted`) that succeeds from the
task's starts, so before reinforcement learning begins the trainer can

1. run that controller for ``episodes`` episodes on the training environments (training starts
   included) and keep the successful ones;
2. fit the observation normaliser to their observations (the trainer then keeps it fixed);
3. regress the actor's mean action onto the controller's actions (behaviour cloning), and the
   critic onto the demonstrations' discounted returns in the units the algorithm will see them
   (the reward normaliser's statistics are seeded from the same returns), so the first
   advantages are measured against the values of the demonstrated behaviour, not a random
   critic's.

Reinforcement learning then continues from the clone with the task's reward. It needs little
action noise and a small step: at the family's log-std -0.5 and 3e-4, PPO's first updates undo a
clone of Pick (round peg) from 92% to 8% within 200k env-steps; at -3 and 1e-4 it stayed at
92-100% on that seed, and raised weaker clones to 98-100% on others, but took one perfect clone
down to 34% (docs/training.md, "Warm start from demonstrations"; docs/skills.md). So the run
evaluates the clone before its first update, and the best-policy selection keeps it when RL
does not improve on it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from itskill.files import read_json
from itskill.rl.policy import StagedActorCriticPolicy
from itskill.sim.vec_env import BatchEnv
from itskill.tasks.evaluate import Policy
from itskill.tasks.scripted import ScriptedPolicy
from itskill.tasks.spec import TaskSpec


class DemoError(ValueError):
    """A warm start that cannot be made: the task has no script, or its script never succeeded."""


DEMOS_FILE = "demos.json"
"""A warm-started run's summary (:func:`warm_start`), in its run directory."""


def read_demo_summary(run_dir: str | Path) -> dict[str, Any] | None:
    """The warm start's summary of the run in ``run_dir``, or None if it started from scratch."""
    path = Path(run_dir) / DEMOS_FILE
    return read_json(path) if path.is_file() else None


@dataclass(frozen=True)
class DemoConfig:
    """Behaviour-cloning warm start; ``episodes = 0`` (the default) turns it off."""

    episodes: int = 0
    """Scripted episodes to run; only the successful ones are learned from."""
    epochs: int = 100
    """Passes over the demonstrations. At 30, clones of Pick (round peg) from 200 episodes
    scored 100%, 20% and 90% on seeds 0-2 before any RL; at 100, 64%, 100%, 100% and 88% on
    seeds 0-3, and each run's kept policy 100% held-out (docs/skills.md)."""
    batch_size: int = 256
    learning_rate: float = 1e-3
    """Adam's step size for the warm start only (the algorithm keeps its own optimiser)."""

    def __post_init__(self) -> None:
        if self.episodes < 0 or self.epochs < 1 or self.batch_size < 1 or self.learning_rate <= 0:
            raise ValueError(
                f"episodes must be >= 0, epochs and batch_size >= 1, learning_rate > 0; got {self}"
            )


@dataclass
class Demonstrations:
    """Transitions of successful scripted episodes, concatenated in episode order."""

    obs: np.ndarray
    """(N, obs_dim) observations the actions were taken from."""
    actions: np.ndarray
    """(N, act_dim) the controller's actions, within [-1, 1]."""
    rewards: np.ndarray
    """(N,) the training reward of each transition."""
    episode_ends: np.ndarray
    """Index one past each episode's last transition."""
    attempted: int
    """Episodes run, successful or not."""
    env_steps: int
    """Simulator steps taken to collect them, over all environments."""

    @property
    def episodes(self) -> int:
        return len(self.episode_ends)

    def episode_rewards(self) -> list[np.ndarray]:
        """The rewards of each episode, in order (views into ``rewards``)."""
        return np.split(self.rewards, self.episode_ends[:-1])


def collect_episodes(
    env: BatchEnv, actor: Policy, episodes: int, successes_only: bool
) -> tuple[Demonstrations | None, int]:
    """Run ``actor`` on ``env`` until ``episodes`` episodes have ended; returns their transitions
    (the successful ones only, with ``successes_only``; None if no episode is kept) and how many
    succeeded.

    ``env`` is the training environment (its reward and starts); it is reset first and left
    mid-episode, so the caller resets it before training on it.
    """
    n = env.num_envs
    ongoing: list[list[tuple[np.ndarray, np.ndarray, float]]] = [[] for _ in range(n)]
    kept: list[list[tuple[np.ndarray, np.ndarray, float]]] = []
    attempted = steps = succeeded = 0
    obs = env.reset()
    actor.reset()
    while attempted < episodes:
        actions = np.asarray(actor(env.context()), dtype=np.float32)
        next_obs, rewards, dones, infos = env.step(actions)
        steps += n
        for e in range(n):
            ongoing[e].append((obs[e].copy(), actions[e].copy(), float(rewards[e])))
        for e in np.flatnonzero(dones):
            if attempted < episodes:
                attempted += 1
                success = bool(infos[e].get("is_success"))
                succeeded += success
                if success or not successes_only:
                    kept.append(ongoing[e])
            ongoing[e] = []
        actor.reset(np.flatnonzero(dones))
        obs = next_obs
    if not kept:
        return None, succeeded
    flat = [step for episode in kept for step in episode]
    demos = Demonstrations(
        obs=np.stack([s[0] for s in flat]).astype(np.float32),
        actions=np.clip(np.stack([s[1] for s in flat]), -1.0, 1.0).astype(np.float32),
        rewards=np.array([s[2] for s in flat], dtype=np.float64),
        episode_ends=np.cumsum([len(ep) for ep in kept]),
        attempted=attempted,
        env_steps=steps,
    )
    return demos, succeeded


def collect_demos(spec: TaskSpec, env: BatchEnv, episodes: int) -> Demonstrations:
    """Run ``spec``'s script on ``env`` until ``episodes`` episodes have ended and keep the
    successful ones (:func:`collect_episodes`)."""
    if not spec.script:
        raise DemoError(f"task {spec.id!r} has no script to demonstrate it; train without demos")
    demos, _ = collect_episodes(env, ScriptedPolicy(spec, env.num_envs), episodes, True)
    if demos is None:
        raise DemoError(
            f"task {spec.id!r}: its script succeeded in none of {episodes} episodes, "
            "so there is nothing to learn from; train without demos"
        )
    return demos


def discounted_returns(demos: Demonstrations, gamma: float) -> np.ndarray:
    """Each transition's discounted return to its episode's end.

    Scripted episodes end on the time limit with the task done and the hand holding still, and
    the trainer bootstraps at time limits, so the value past the end is taken as the last reward
    kept up for ever: ``r_last / (1 - gamma)``. Undiscounted (``gamma`` 1) that tail has no finite
    value, so the returns then stop at the episode's end.
    """
    returns = []
    for rewards in demos.episode_rewards():
        out = np.empty_like(rewards)
        g = rewards[-1] / (1.0 - gamma) if gamma < 1.0 else 0.0
        for t in range(len(rewards) - 1, -1, -1):
            g = rewards[t] + gamma * g
            out[t] = g
        returns.append(out)
    return np.concatenate(returns)


def seed_reward_normalizer(env: VecNormalize, demos: Demonstrations) -> None:
    """Feed the demonstrations' running returns to ``env``'s reward normaliser, as
    :class:`VecNormalize` would have seen them had it stepped through the episodes."""
    for rewards in demos.episode_rewards():
        running = 0.0
        acc = np.empty_like(rewards)
        for i, r in enumerate(rewards):
            running = running * env.gamma + r
            acc[i] = running
        env.ret_rms.update(acc)


def critic_targets(demos: Demonstrations, train_env: VecEnv, gamma: float) -> np.ndarray:
    """Each transition's discounted return in the units the algorithm's critic will regress on:
    where ``train_env`` normalises rewards (a :class:`VecNormalize`), its statistics are seeded
    from these episodes and the returns divided by the scale they give."""
    returns = discounted_returns(demos, gamma)
    if isinstance(train_env, VecNormalize):
        seed_reward_normalizer(train_env, demos)
        returns = returns / np.sqrt(train_env.ret_rms.var + train_env.epsilon)
    return returns


def pretrain_policy(
    policy: StagedActorCriticPolicy,
    demos: Demonstrations,
    value_targets: np.ndarray,
    config: DemoConfig,
    seed: int = 0,
    clone: bool = True,
) -> dict[str, float]:
    """Fit ``policy``'s normaliser, actor mean and critic to ``demos``; returns final losses.

    ``value_targets`` are the returns in the units the algorithm's critic will regress on (after
    reward normalisation). The action head's log standard deviation is left as configured. With
    ``clone`` False only the critic learns (its own trunk and the value head; the value head
    alone over a shared trunk): the actions and the normaliser stay as they are.
    """
    obs = torch.as_tensor(demos.obs)
    actions = torch.as_tensor(demos.actions)
    targets = torch.as_tensor(value_targets, dtype=torch.float32)
    if clone and policy.obs_norm is not None:
        policy.obs_norm.update(obs)
    if clone:
        named = policy.named_parameters()
    else:
        named = policy.value_net.named_parameters()
        if policy.mlp_extractor.critic is not None:
            named = [*named, *policy.mlp_extractor.critic.named_parameters()]
    params = [p for name, p in named if name != "log_std" and p.requires_grad]
    optimiser = torch.optim.Adam(params, lr=config.learning_rate)
    generator = torch.Generator().manual_seed(seed)
    policy.set_training_mode(True)
    actor_loss = critic_loss = torch.zeros(())
    for _ in range(config.epochs):
        order = torch.randperm(len(obs), generator=generator)
        for idx in order.split(config.batch_size):
            features = policy.extract_features(obs[idx])
            latent_pi, latent_vf = policy.mlp_extractor(features)
            actor_loss = torch.nn.functional.mse_loss(policy.action_net(latent_pi), actions[idx])
            critic_loss = torch.nn.functional.mse_loss(
                policy.value_net(latent_vf).squeeze(-1), targets[idx]
            )
            optimiser.zero_grad()
            (actor_loss + critic_loss if clone else critic_loss).backward()
            optimiser.step()
    policy.set_training_mode(False)
    return {"actor_mse": actor_loss.item(), "critic_mse": critic_loss.item()}


def warm_start(
    model: OnPolicyAlgorithm,
    spec: TaskSpec,
    env: BatchEnv,
    train_env: VecEnv,
    config: DemoConfig,
    gamma: float,
    seed: int,
) -> dict[str, Any]:
    """Collect ``config.episodes`` scripted episodes on ``env`` and pretrain ``model``'s policy
    on the successful ones (module docstring). ``train_env`` is what the algorithm steps:
    ``env`` itself or a :class:`VecNormalize` around it, whose reward statistics are seeded.
    Returns a summary for the run directory."""
    start = time.perf_counter()
    demos = collect_demos(spec, env, config.episodes)
    returns = critic_targets(demos, train_env, gamma)
    losses = pretrain_policy(model.policy, demos, returns, config, seed)
    return {
        "episodes_run": demos.attempted,
        "episodes_kept": demos.episodes,
        "transitions": len(demos.obs),
        "env_steps": demos.env_steps,
        **losses,
        "wall_s": round(time.perf_counter() - start, 2),
    }
