"""Start a training run from a trained policy instead of random weights.

A skill that ends its training below its target can be trained on from where it is:
``itskill train TASK --init SKILL_DIR`` or ``itskill skills pretrain --refine`` (Carry (nut M12)
went from 93% to 99% of its held-out episodes in 100k env-steps more; docs/skills.md,
"Eighteenth pretraining"). Three things make that work:

1. the policy's weights and observation statistics are copied, all but its action noise, which
   is the run's (:class:`InitConfig`): a converged policy's noise is whatever its last updates
   left, and at the family's usual -0.5 PPO's first noisy rollouts undo a precise policy, as
   they undid the clones of the warm start (docs/training.md);
2. the normaliser keeps those statistics for the whole run (the trainer's part);
3. the critic is fitted to the policy's own returns before the first update
   (:func:`warm_up_critic`): a skill is shipped without its reward normaliser's statistics, so
   its critic's values are in another scale than the new run's rewards, and the advantages of
   the first updates would be mostly that error. Without it, Unscrew (nut M16) fell from 96% to
   68% of the evaluation episodes within 100k env-steps; with it, it stayed at 92-98% and
   its kept policy at 95% held-out (docs/training.md, "Training on from a trained policy").
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from itskill.rl.checkpoint import (
    META_FILE,
    POLICY_FILE,
    STAGED_POLICY_CLASS,
    best_policy_dir,
    load_policy,
    policy_sha256,
    read_meta,
)
from itskill.rl.demos import DemoConfig, collect_episodes, critic_targets, pretrain_policy
from itskill.rl.policy import StagedActorCriticPolicy
from itskill.sim.vec_env import BatchEnv
from itskill.tasks.evaluate import CheckpointError, PolicyActor

CRITIC_WARM_UP_FILE = "critic_warm_up.json"
"""The summary of :func:`warm_up_critic`, in the run directory of a run started from a policy."""

SHAPE_FIELDS = ("stages", "activation", "shared_trunk", "normalize_obs", "obs_clip")
"""The :class:`~itskill.rl.policy.PolicyConfig` fields two policies must share for one's weights
to fit the other."""


@dataclass(frozen=True)
class InitConfig:
    """How a run started from a trained policy explores and learns: the ``init`` table of the
    hyper-parameters, used instead of the policy table's ``log_std_init`` and the algorithm's
    ``learning_rate`` whenever a run is given a policy to start from."""

    log_std_init: float = -1.5
    """The action noise (a standard deviation of 0.22 of the action range)."""
    learning_rate: float = 1e-4
    critic_episodes: int = 64
    """Episodes the starting policy runs before the first update, to fit the critic to."""

    def __post_init__(self) -> None:
        if self.learning_rate <= 0 or self.critic_episodes < 1:
            raise ValueError(f"learning_rate must be > 0 and critic_episodes >= 1; got {self}")


def describe_init(source: str | Path) -> dict[str, Any]:
    """Check that ``source`` holds a policy a run can start from and describe it for the run's
    metadata: the directory used (a run's best policy if it was evaluated, else its last
    checkpoint; a skill directory as it is; a ``policy.safetensors`` named itself, its own
    directory's), its task, env-steps and the hash of its weights."""
    source = Path(source)
    if source.suffix == ".safetensors" and source.name != POLICY_FILE:
        raise CheckpointError(source, f"a run's or skill's weights are its {POLICY_FILE}")
    source_dir = source.parent if source.suffix == ".safetensors" else best_policy_dir(source)
    meta = read_meta(source_dir)
    if meta.get("policy_class", STAGED_POLICY_CLASS) != STAGED_POLICY_CLASS:
        raise CheckpointError(
            source_dir / META_FILE,
            f"holds a {meta['policy_class']}; a run can start only from a "
            f"{StagedActorCriticPolicy.__name__}",
        )
    weights = source_dir / POLICY_FILE
    if not weights.is_file():
        raise CheckpointError(weights, "missing policy weights")
    return {
        "path": str(source_dir.resolve()),
        "task": meta["task"],
        "num_timesteps": int(meta["num_timesteps"]),
        "sha256": policy_sha256(source_dir),
    }


def init_policy(policy: StagedActorCriticPolicy, init: Mapping[str, Any]) -> None:
    """Give ``policy`` the weights and observation statistics of the policy :func:`describe_init`
    described, all but its action noise (``log_std`` stays at ``policy``'s initial value)."""
    source = load_policy(init["path"])
    have = {k: source.config.to_dict()[k] for k in SHAPE_FIELDS}
    want = {k: policy.config.to_dict()[k] for k in SHAPE_FIELDS}
    if have != want:
        diff = ", ".join(f"{k} {have[k]!r} (run: {want[k]!r})" for k in have if have[k] != want[k])
        raise CheckpointError(
            Path(init["path"]) / META_FILE, f"policy shape does not fit this run's: {diff}"
        )
    state = {k: v for k, v in source.state_dict().items() if k != "log_std"}
    policy.load_state_dict(state, strict=False)


def warm_up_critic(
    model: OnPolicyAlgorithm,
    env: BatchEnv,
    train_env: VecEnv,
    gamma: float,
    config: InitConfig,
    seed: int,
) -> dict[str, Any]:
    """Fit the critic of ``model`` to the returns of its own policy, before its first update.

    The policy runs ``config.critic_episodes`` episodes on the training environments, sampling
    its actions with the run's noise as its rollouts will; the reward normaliser is seeded from
    them and the critic alone regresses on their discounted returns in its units (the actions
    are not touched). Returns a summary for the run directory, with the critic's squared error on
    those returns before the fit (``critic_mse_before``) and on its last batch after.
    """
    start = time.perf_counter()
    actor = PolicyActor(model.policy, deterministic=False)
    runs, succeeded = collect_episodes(env, actor, config.critic_episodes, successes_only=False)
    assert runs is not None  # every episode is kept
    returns = critic_targets(runs, train_env, gamma)
    with torch.no_grad():
        values = model.policy.predict_values(torch.as_tensor(runs.obs)).squeeze(-1).numpy()
    losses = pretrain_policy(model.policy, runs, returns, DemoConfig(), seed, clone=False)
    return {
        "episodes_run": runs.attempted,
        "successes": succeeded,
        "transitions": len(runs.obs),
        "env_steps": runs.env_steps,
        "critic_mse_before": float(np.mean((values - returns) ** 2)),
        "critic_mse": losses["critic_mse"],
        "wall_s": round(time.perf_counter() - start, 2),
    }
