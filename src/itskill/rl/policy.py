"""Actor-critic policy with an explicit staged network and observation normalisation inside it.

Network (the transfer network later takes lateral connections from stages 1-3 of a frozen copy)::

    obs ─▶ normaliser ─▶ stage1 ─▶ stage2 ─▶ stage3 ─▶ output
                         Linear+Tanh blocks, 256 / 256 / 128 by default

Design choices:

- **Separate actor and critic trunks** (``PolicyConfig.shared_trunk = False``, the default). The
  actor's stage features are what a target task fuses from its sources, so they should describe how
  to act, untouched by value-regression gradients; the critic has its own trunk of the same shape.
  ``shared_trunk = True`` gives one trunk feeding both heads (half the parameters).
- **The normaliser is part of the policy**: running mean and variance are buffers, so they are in
  the state dict (SB3 zip, ``policy.safetensors``) and a frozen source normalises exactly as it did
  while it was trained. Statistics are updated only in :meth:`forward`, which SB3 calls once per
  collected observation during rollouts, and only while ``update_obs_stats`` is true; evaluation
  (``predict``), the training loss (``evaluate_actions``) and :meth:`stage_outputs` never update
  them. A loaded or frozen policy has ``update_obs_stats = False``.
- **A frozen source stays frozen**: the transfer network freezes each source it loads
  (:func:`itskill.transfer.sources.freeze`) and keeps them in eval mode through SB3's switches
  between train and eval mode around every update (``TransferPolicy.train``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import PyTorchObs
from torch import nn

ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


@dataclass(frozen=True)
class PolicyConfig:
    """Shape of :class:`StagedActorCriticPolicy`.

    ``stages`` are the widths of the three feature stages (the paper's network has three stages
    before the output layer). ``obs_clip`` bounds normalised observations; ``log_std_init`` is the
    initial log standard deviation of the Gaussian action distribution.
    """

    stages: tuple[int, ...] = (256, 256, 128)
    activation: str = "tanh"
    shared_trunk: bool = False
    normalize_obs: bool = True
    obs_clip: float = 10.0
    log_std_init: float = -0.5
    ortho_init: bool = True

    def __post_init__(self) -> None:
        if not self.stages or any(int(w) < 1 for w in self.stages):
            raise ValueError(f"stages must be positive widths, got {self.stages!r}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"activation must be one of {list(ACTIVATIONS)}, got {self.activation!r}"
            )
        object.__setattr__(self, "stages", tuple(int(w) for w in self.stages))

    @classmethod
    def of_policy(cls, sb3_kwargs: Mapping[str, Any], **shape: Any) -> PolicyConfig:
        """The config of a policy built with ``shape`` (``stages``, ``activation``, ...) and
        ``sb3_kwargs``, the keyword arguments its Stable-Baselines3 base class takes, whose own
        defaults stand where they leave ``log_std_init`` or ``ortho_init`` out."""
        return cls(
            **shape,
            log_std_init=sb3_kwargs.get("log_std_init", 0.0),
            ortho_init=sb3_kwargs.get("ortho_init", True),
        )

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "stages": list(self.stages)}

    def policy_kwargs(self) -> dict[str, Any]:
        """``policy_kwargs`` for ``PPO``/``A2C`` with :class:`StagedActorCriticPolicy`."""
        return {
            "stages": self.stages,
            "activation": self.activation,
            "shared_trunk": self.shared_trunk,
            "normalize_obs": self.normalize_obs,
            "obs_clip": self.obs_clip,
            "log_std_init": self.log_std_init,
            "ortho_init": self.ortho_init,
        }


class RunningNormalizer(nn.Module):
    """Observation normaliser with running mean and variance kept as buffers.

    ``update`` merges a batch into the statistics (Chan et al.'s parallel algorithm, in float64);
    ``forward`` returns ``clip((x - mean) / sqrt(var + eps))`` and never changes the statistics.
    """

    def __init__(self, size: int, clip: float = 10.0, eps: float = 1e-8) -> None:
        super().__init__()
        self.clip, self.eps = float(clip), float(eps)
        self.register_buffer("mean", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("var", torch.ones(size, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        x = x.reshape(-1, self.mean.shape[0]).to(torch.float64)
        n = x.shape[0]
        if n == 0:
            return
        batch_mean = x.mean(0)
        batch_var = x.var(0, unbiased=False)
        total = self.count + n
        delta = batch_mean - self.mean
        self.mean += delta * (n / total)
        m2 = self.var * self.count + batch_var * n + delta.square() * self.count * n / total
        self.var.copy_(m2 / total)
        self.count.fill_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = self.mean.to(x.dtype)
        std = torch.sqrt(self.var + self.eps).to(x.dtype)
        return torch.clamp((x - mean) / std, -self.clip, self.clip)


class StagedTrunk(nn.Module):
    """``Linear + activation`` stages; :meth:`stage_outputs` returns each one's output."""

    def __init__(self, in_dim: int, widths: tuple[int, ...], activation: type[nn.Module]) -> None:
        super().__init__()
        blocks, prev = [], in_dim
        for width in widths:
            blocks.append(nn.Sequential(nn.Linear(prev, width), activation()))
            prev = width
        self.stages = nn.ModuleList(blocks)
        self.out_dim = prev

    def stage_outputs(self, x: torch.Tensor) -> list[torch.Tensor]:
        outs = []
        for stage in self.stages:
            x = stage(x)
            outs.append(x)
        return outs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for stage in self.stages:
            x = stage(x)
        return x


class StagedExtractor(nn.Module):
    """SB3's ``mlp_extractor`` contract (``latent_dim_pi``/``_vf``, ``forward_actor``/``_critic``)
    over one :class:`StagedTrunk` per head, or one shared trunk."""

    def __init__(
        self, in_dim: int, widths: tuple[int, ...], activation: type[nn.Module], shared: bool
    ) -> None:
        super().__init__()
        self.actor = StagedTrunk(in_dim, widths, activation)
        self.critic = None if shared else StagedTrunk(in_dim, widths, activation)
        self.latent_dim_pi = self.actor.out_dim
        self.latent_dim_vf = self.actor.out_dim

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        pi = self.actor(features)
        return pi, (pi if self.critic is None else self.critic(features))

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.actor(features)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.actor(features) if self.critic is None else self.critic(features)


class StagedActorCriticPolicy(ActorCriticPolicy):
    """SB3 actor-critic policy: normaliser -> stage1 -> stage2 -> stage3 -> action / value heads.

    Extra keyword arguments (everything else is :class:`ActorCriticPolicy`'s): ``stages``,
    ``activation`` (a name in :data:`ACTIVATIONS`), ``shared_trunk``, ``normalize_obs``,
    ``obs_clip``. Pass ``ortho_init=False`` when pretrained weights will be loaded into it.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        lr_schedule,
        stages: tuple[int, ...] = PolicyConfig.stages,
        activation: str = PolicyConfig.activation,
        shared_trunk: bool = PolicyConfig.shared_trunk,
        normalize_obs: bool = PolicyConfig.normalize_obs,
        obs_clip: float = PolicyConfig.obs_clip,
        **kwargs: Any,
    ) -> None:
        # Read by _build_mlp_extractor, which the base constructor calls.
        self.config = PolicyConfig.of_policy(
            kwargs,
            stages=stages,
            activation=activation,
            shared_trunk=shared_trunk,
            normalize_obs=normalize_obs,
            obs_clip=obs_clip,
        )
        kwargs.setdefault("activation_fn", ACTIVATIONS[activation])
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        obs_size = int(gym.spaces.flatdim(observation_space))
        self.obs_norm = RunningNormalizer(obs_size, clip=obs_clip) if normalize_obs else None
        self.update_obs_stats = normalize_obs

    # ------------------------------------------------------------------ construction
    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = StagedExtractor(
            self.features_dim,
            self.config.stages,
            ACTIVATIONS[self.config.activation],
            self.config.shared_trunk,
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.pop("net_arch", None)
        data.update(
            stages=self.config.stages,
            activation=self.config.activation,
            shared_trunk=self.config.shared_trunk,
            normalize_obs=self.config.normalize_obs,
            obs_clip=self.config.obs_clip,
        )
        return data

    # ------------------------------------------------------------------ normalisation
    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        """Observations as the network sees them (unchanged if normalisation is off)."""
        return obs if self.obs_norm is None else self.obs_norm(obs.float())

    def extract_features(self, obs: PyTorchObs, features_extractor=None):  # type: ignore[override]
        return super().extract_features(self.normalize(obs), features_extractor)

    # SB3 reaches the features through three paths: ``extract_features`` (forward,
    # evaluate_actions) and ``BasePolicy.extract_features`` called directly from get_distribution
    # (predict) and predict_values (rollout bootstrap). All three must normalise, exactly once.
    def get_distribution(self, obs: PyTorchObs):
        return super().get_distribution(self.normalize(obs))

    def predict_values(self, obs: PyTorchObs) -> torch.Tensor:
        return super().predict_values(self.normalize(obs))

    def forward(self, obs: torch.Tensor, deterministic: bool = False):
        """SB3's rollout step; the only place the normaliser's statistics are updated."""
        if self.obs_norm is not None and self.update_obs_stats:
            self.obs_norm.update(obs)
        return super().forward(obs, deterministic)

    # ------------------------------------------------------------------ transfer interface
    def stage_outputs(self, obs: torch.Tensor, trunk: str = "actor") -> list[torch.Tensor]:
        """Outputs of stages 1..k of the actor (default) or critic trunk for raw observations."""
        features = super().extract_features(self.normalize(obs), self.pi_features_extractor)
        if trunk == "actor":
            return self.mlp_extractor.actor.stage_outputs(features)
        if trunk == "critic":
            net = self.mlp_extractor.critic or self.mlp_extractor.actor
            return net.stage_outputs(features)
        raise ValueError(f"trunk must be 'actor' or 'critic', got {trunk!r}")
