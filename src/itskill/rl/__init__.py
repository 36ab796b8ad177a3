"""Reinforcement learning on ``BatchEnv``: staged actor-critic policies, A2C/PPO training,
metrics and checkpoints (Stable-Baselines3 underneath)."""

from __future__ import annotations

from itskill.rl.checkpoint import TrainedPolicy, as_policy, load_policy, read_meta
from itskill.rl.config import A2CConfig, HyperparamError, Hyperparams, PPOConfig, load_hyperparams
from itskill.rl.policy import PolicyConfig, StagedActorCriticPolicy
from itskill.rl.train import RewardLoadError, RewardSource, TrainResult, train

__all__ = [
    "A2CConfig",
    "HyperparamError",
    "Hyperparams",
    "PPOConfig",
    "PolicyConfig",
    "RewardLoadError",
    "RewardSource",
    "StagedActorCriticPolicy",
    "TrainResult",
    "TrainedPolicy",
    "as_policy",
    "load_hyperparams",
    "load_policy",
    "read_meta",
    "train",
]
