"""The network every transfer method shares: frozen sources laterally connected to a target network.

::

    raw obs ─┬─▶ source 1 (own normaliser) ─▶ SO_1^1, SO_1^2, SO_1^3 ─▶ action mean pi_1(s)
             ├─▶ ...                                                          │
             ├─▶ source n ─▶ SO_n^1, SO_n^2, SO_n^3 ─▶ pi_n(s) ───────────────┤
             │                                                        weighting (W)
             └─▶ target normaliser ─▶ stage 1 ─▶ merge_1 ─▶ stage 2 ─▶ merge_2 ─▶ stage 3 ─▶ merge_3
                                                                                          │
                                                                          action head ◀───┘

A method is a choice of ``weighting`` (intelligent attention, fixed analyzer values, none) and
``merge`` (fusion MLP, plain sum): :class:`TransferPolicy` subclasses supply them in
``_build_parts``. Design choices:

- **Sources see what they were trained on**: each is a whole frozen policy (its normaliser, actor
  trunk and action head), fed the raw observation with one change: the stage one-hot says the
  stage the source's own task would be in (``stage_map`` of its spec, from
  :mod:`itskill.transfer.stages`; a spec without one sees the target's stage, as checkpoints
  written before the map existed did). The rest is the target's, ``time_frac`` included: the
  episode's clock runs over the target's horizon, not the source's own, which moves a source's
  actions a little (a few hundredths on the nut's pick, less on its place). Its parameters
  have ``requires_grad = False``
  and are not given to the optimiser, its normaliser statistics never update, and it stays in
  eval mode through SB3's train/eval switches. Source outputs are computed without gradients:
  they are inputs to the target network, nothing upstream of them trains.
- **The critic** has its own trunk of the target's shape on the target-normalised observation
  (``shared_trunk = False``, the default): the sources were trained for other rewards, so their
  value is no estimate of this task's, and value-regression gradients stay out of the fused
  features the action is made from (the staged policy's reasoning). ``shared_trunk = True`` puts
  the value head on the fused actor features instead.
- **Source-action residual** (``performers``, optional): the action mean is the head's output
  plus the action of the source that performs the current stage (:func:`stage_performers`), so
  the untrained network acts like the sources run one after another and training learns a
  correction. The head starts near zero (gain 0.01). Without ``performers`` the action comes from
  the fused features alone, as in the paper.
- **Self-contained checkpoints**: source weights are part of the state dict, so ``model.zip`` and
  ``policy.safetensors`` of a transfer run need no source directory once written. A new policy
  reads its sources from their run directories (``sources[i]["run_dir"]``); one rebuilt for a
  saved state dict (:meth:`TransferPolicy.from_config`, or SB3 loading a ``model.zip`` whose
  sources have moved) gets them from that state dict, and refuses to act before it has.
- **Initialisation**: the target trunk, critic, fusion blocks and heads as SB3 does it
  (orthogonal, gains sqrt(2) / 0.01 / 1); the attention's final layer with gain 0.01, so the raw
  weights start near uniform and the analyzer's prior decides the initial ``W``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import PyTorchObs
from torch import nn

from itskill.rl.checkpoint import META_FILE, policy_from_meta, policy_sha256
from itskill.rl.policy import ACTIVATIONS, PolicyConfig, RunningNormalizer, StagedTrunk
from itskill.sim.layout import MAX_STAGES
from itskill.sim.vec_env import action_space, observation_space
from itskill.transfer.analyzer import validate_matrix
from itskill.transfer.config import TransferConfig, check_setting
from itskill.transfer.sources import IncompatibleSourceError, freeze, load_source
from itskill.transfer.stages import STAGE_SLICE, pad_stages

NOT_READY = (
    "the transfer policy's source weights were never loaded: a source's run directory is gone, or "
    "its weights changed since the network was specified (a skill retrained or replaced); build "
    "it from the current skills, or load a saved transfer checkpoint into it"
)


@dataclass(frozen=True)
class TransferPolicyConfig:
    """Shape of a transfer policy: the target network, its sources and the method's settings.

    ``sources`` are :meth:`itskill.transfer.sources.SourceSkill.spec` entries (name, task,
    run_dir, the source's policy class and shape, and optionally ``stage_map``); ``prior`` is the
    analyzer's contribution matrix (target stages x sources), None for methods that do not use
    it; ``performers`` is the source whose action the head adds to in each target stage (-1:
    none), None for no residual.
    """

    target: PolicyConfig
    sources: tuple[dict[str, Any], ...]
    prior: tuple[tuple[float, ...], ...] | None = None
    attention_hidden: int = TransferConfig.attention_hidden
    prior_weight: float = TransferConfig.prior_weight
    fusion_hidden: tuple[int, ...] = field(default=())
    performers: tuple[int, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        """The constructor keyword arguments, JSON-ready (``checkpoint.json``'s ``policy``)."""
        return {
            **self.target.to_dict(),
            "sources": [dict(s) for s in self.sources],
            "prior": None if self.prior is None else [list(r) for r in self.prior],
            "attention_hidden": self.attention_hidden,
            "prior_weight": self.prior_weight,
            "fusion_hidden": list(self.fusion_hidden),
            "performers": None if self.performers is None else list(self.performers),
        }


def stage_widths(policy: ActorCriticPolicy) -> tuple[int, ...]:
    """Widths of a staged or transfer policy's actor stages (the features it offers as a source)."""
    config = policy.config
    return tuple(getattr(config, "target", config).stages)


def _build_source(spec: Mapping[str, Any]) -> tuple[ActorCriticPolicy, bool]:
    """A frozen source policy and whether its trained weights are in it."""
    for key in ("name", "policy_class", "policy"):
        if key not in spec:
            raise ValueError(f"a source entry lacks {key!r}: {dict(spec)!r}")
    if weights_on_disk(spec):
        return load_source(dict(spec)), True
    # Gone, or retrained since the network was specified: built as recorded, so that the saved
    # checkpoint a resumed run or an evaluation loads next brings the weights it trained with.
    where = f"source {spec['name']!r}"
    return freeze(policy_from_meta(spec["policy_class"], spec["policy"], where)), False


def weights_on_disk(spec: Mapping[str, Any]) -> bool:
    """Whether the source's run directory holds the weights ``spec`` was made with (a spec
    written before it recorded their hash takes whatever is there): if not, a network built
    from ``spec`` has that source's shape but not its weights, and acts only once a saved
    checkpoint is loaded into it."""
    run_dir = spec.get("run_dir")
    if not run_dir or not (Path(run_dir) / META_FILE).is_file():
        return False
    recorded = spec.get("weights_sha256")
    try:
        return recorded is None or policy_sha256(run_dir) == recorded
    except OSError:
        return False


def _stage_table(rows: Sequence[int], width: int) -> torch.Tensor:
    """``(MAX_STAGES, width)`` 0/1 table whose row ``j`` selects column ``rows[j]`` (none for -1),
    padded (:func:`pad_stages`)."""
    table = torch.zeros(MAX_STAGES, width)
    for j, col in enumerate(pad_stages(rows)):
        if col >= 0:
            table[j, col] = 1.0
    return table


def _stage_remap(stage_map: Sequence[int] | None, name: str) -> torch.Tensor:
    """One source's target-stage -> own-stage one-hot map (identity without a ``stage_map``)."""
    if stage_map is None:
        return torch.eye(MAX_STAGES)
    stage_map = [int(s) for s in stage_map]
    if not 1 <= len(stage_map) <= MAX_STAGES or not all(0 <= s < MAX_STAGES for s in stage_map):
        raise ValueError(
            f"source {name!r}: stage_map must be 1 to {MAX_STAGES} stage indices in "
            f"[0, {MAX_STAGES}), got {stage_map}"
        )
    return _stage_table(stage_map, MAX_STAGES)


def source_pass(
    policy: ActorCriticPolicy, obs: torch.Tensor
) -> tuple[list[torch.Tensor], torch.Tensor]:
    """A staged or transfer policy's actor stage outputs and action mean for raw observations,
    from one pass: a transfer policy that is a source in turn runs its own sources once."""
    obs = obs.float()
    if not isinstance(policy, TransferPolicy):
        outs = policy.stage_outputs(obs)
        return outs, policy.action_net(outs[-1])
    ex = policy.mlp_extractor
    outs, actions = ex.actor_pass(obs)
    mean = policy.action_net(outs[-1])
    if ex.residual_pick is not None:
        mean = mean + ex.residual(obs, actions)
    return outs, mean


class LateralExtractor(nn.Module):
    """SB3's ``mlp_extractor``: target trunk with sources, weighting and merge; critic trunk.

    Its input is the raw observation (the policy does no normalisation of its own): the sources
    normalise it their way, the target with ``obs_norm``. With ``performers`` the actor's latent
    carries the residual action after the features (``latent_dim_pi`` is wider by the action
    size); :class:`TransferPolicy` splits it again.
    """

    def __init__(
        self,
        obs_dim: int,
        target: PolicyConfig,
        sources: Sequence[ActorCriticPolicy],
        weighting: nn.Module | None,
        merge: nn.Module,
        ready: bool,
        stage_maps: Sequence[Sequence[int] | None],
        source_names: Sequence[str],
        performers: Sequence[int] | None,
        action_dim: int,
    ) -> None:
        super().__init__()
        activation = ACTIVATIONS[target.activation]
        self.obs_norm = (
            RunningNormalizer(obs_dim, clip=target.obs_clip) if target.normalize_obs else None
        )
        self.actor = StagedTrunk(obs_dim, target.stages, activation)
        self.critic = (
            None if target.shared_trunk else StagedTrunk(obs_dim, target.stages, activation)
        )
        self.sources = nn.ModuleList(sources)
        self.weighting = weighting
        self.merge = merge
        self.register_buffer("sources_ready", torch.tensor(ready))
        # Not persistent: rebuilt from the config, so checkpoints from before these existed load.
        remaps = [_stage_remap(m, n) for m, n in zip(stage_maps, source_names, strict=True)]
        self.register_buffer("stage_remap", torch.stack(remaps), persistent=False)
        pick = None
        if performers is not None:
            if not 1 <= len(performers) <= MAX_STAGES or not all(
                -1 <= k < len(sources) for k in performers
            ):
                raise ValueError(
                    f"performers must be 1 to {MAX_STAGES} source indices in "
                    f"[-1, {len(sources)}), got {list(performers)}"
                )
            pick = _stage_table([int(k) for k in performers], len(sources))
        self.register_buffer("residual_pick", pick, persistent=False)
        self.latent_width = target.stages[-1]
        self.latent_dim_vf = self.latent_width
        self.latent_dim_pi = self.latent_width + (0 if performers is None else action_dim)

    def train(self, mode: bool = True) -> LateralExtractor:
        """Train mode for the target's modules; the frozen sources stay in eval mode, however
        the policy or this extractor is switched."""
        super().train(mode)
        self.sources.eval()
        return self

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return obs if self.obs_norm is None else self.obs_norm(obs.float())

    @torch.no_grad()
    def source_outputs(
        self, obs: torch.Tensor
    ) -> tuple[list[list[torch.Tensor]], list[torch.Tensor]]:
        """Each source's stage outputs and action mean for raw observations ``obs``."""
        if not bool(self.sources_ready):
            raise RuntimeError(NOT_READY)
        stage = obs[..., STAGE_SLICE]
        feats, actions = [], []
        for src, remap in zip(self.sources, self.stage_remap, strict=True):
            view = torch.cat(
                [obs[..., : STAGE_SLICE.start], stage @ remap, obs[..., STAGE_SLICE.stop :]], -1
            )
            outs, mean = source_pass(src, view)
            feats.append(outs)
            actions.append(mean)
        return feats, actions

    def residual(self, obs: torch.Tensor, actions: list[torch.Tensor]) -> torch.Tensor:
        """The action of the source performing each observation's stage (zero where none)."""
        pick = obs[..., STAGE_SLICE] @ self.residual_pick
        return torch.einsum("bn,nba->ba", pick, torch.stack(actions))

    def contribution(
        self, obs: torch.Tensor, actions: list[torch.Tensor]
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """``(raw, W)`` of the weighting (``(None, None)`` without one)."""
        return (None, None) if self.weighting is None else self.weighting(obs, actions)

    def actor_pass(self, obs: torch.Tensor) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """The merged output after each target stage, and the sources' actions."""
        feats, actions = self.source_outputs(obs)
        _, weights = self.contribution(obs, actions)
        x, outs = self.normalize(obs), []
        for j, stage in enumerate(self.actor.stages):
            x = self.merge(j, stage(x), [f[j] for f in feats], weights)
            outs.append(x)
        return outs, actions

    def actor_stages(self, obs: torch.Tensor) -> list[torch.Tensor]:
        """The merged output after each target stage; the last one is the actor's features."""
        return self.actor_pass(obs)[0]

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        outs, actions = self.actor_pass(features)
        if self.residual_pick is None:
            return outs[-1]
        return torch.cat([outs[-1], self.residual(features, actions)], -1)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        if self.critic is None:
            return self.actor_stages(features)[-1]
        return self.critic(self.normalize(features))

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        pi = self.forward_actor(features)
        if self.critic is None:
            return pi, pi[..., : self.latent_width]
        return pi, self.critic(self.normalize(features))


class TransferPolicy(ActorCriticPolicy):
    """SB3 actor-critic policy over a :class:`LateralExtractor`; subclasses are the methods.

    Keyword arguments: ``sources`` (source specs), ``prior`` (the contribution matrix, for
    methods with ``uses_prior``), the target's :class:`PolicyConfig` fields (``stages``,
    ``activation``, ``shared_trunk``, ``normalize_obs``, ``obs_clip``,
    ``log_std_init``, ``ortho_init``), ``attention_hidden``, ``prior_weight``,
    ``fusion_hidden`` and ``performers``; everything else is :class:`ActorCriticPolicy`'s.
    """

    uses_prior: ClassVar[bool] = True

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        lr_schedule,
        sources: Sequence[Mapping[str, Any]],
        prior: Sequence[Sequence[float]] | None = None,
        stages: Sequence[int] = PolicyConfig.stages,
        activation: str = PolicyConfig.activation,
        shared_trunk: bool = PolicyConfig.shared_trunk,
        normalize_obs: bool = PolicyConfig.normalize_obs,
        obs_clip: float = PolicyConfig.obs_clip,
        attention_hidden: int = TransferConfig.attention_hidden,
        prior_weight: float = TransferConfig.prior_weight,
        fusion_hidden: Sequence[int] = (),
        performers: Sequence[int] | None = None,
        **kwargs: Any,
    ) -> None:
        if not sources:
            raise ValueError(f"{type(self).__name__} needs at least one source")
        names = [s.get("name") for s in sources]
        if len(set(names)) != len(names):
            raise ValueError(f"a source is given twice: {names}")
        # Outside [0, 1] W is no convex combination: a source's weight can go negative.
        check_setting("prior_weight", prior_weight)
        if self.uses_prior:
            if prior is None:
                raise ValueError(f"{type(self).__name__} needs the analyzer's contribution matrix")
            matrix = np.asarray(prior, dtype=np.float64)
            prior = validate_matrix(matrix, matrix.shape[0] if matrix.ndim else 0, len(sources))
        target = PolicyConfig.of_policy(
            kwargs,
            stages=stages,
            activation=activation,
            shared_trunk=shared_trunk,
            normalize_obs=normalize_obs,
            obs_clip=obs_clip,
        )
        self.config = TransferPolicyConfig(
            target=target,
            sources=tuple(dict(s) for s in sources),
            prior=None if prior is None else tuple(tuple(float(v) for v in r) for r in prior),
            attention_hidden=int(attention_hidden),
            prior_weight=float(prior_weight),
            fusion_hidden=tuple(int(w) for w in fusion_hidden),
            performers=None if performers is None else tuple(int(k) for k in performers),
        )
        # Read by _build_mlp_extractor, which the base constructor calls; a plain list so the
        # modules are registered once, inside the extractor.
        self._new_sources = [_build_source(s) for s in self.config.sources]
        self.check_sources(self.config.sources, target.stages)
        kwargs["ortho_init"] = False  # _build initialises everything but the sources
        kwargs.setdefault("activation_fn", ACTIVATIONS[activation])
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        self.update_obs_stats = normalize_obs
        stage_counts = {len(performers)} if performers is not None else set()
        stage_counts |= {len(s["stage_map"]) for s in sources if s.get("stage_map") is not None}
        if self.config.prior is not None and stage_counts - {len(self.config.prior)}:
            # A short matrix lent its last row to the stages past it without a word.
            raise ValueError(
                f"the contribution matrix has {len(self.config.prior)} rows, the target "
                f"{max(stage_counts)} stages (its performers and stage maps): one row per stage"
            )

    @classmethod
    def check_sources(
        cls, sources: Sequence[Mapping[str, Any]], target_stages: Sequence[int]
    ) -> None:
        """:class:`IncompatibleSourceError` if one of ``sources`` (source specs, as recorded)
        cannot join this network over a target of ``target_stages``: lateral connections join
        stage j to stage j, so a source has as many stages as the target. Read from the recorded
        shapes, so that a run can be refused before the analyzer is asked or anything written."""
        for spec in sources:
            widths = tuple(spec["policy"]["stages"])
            if len(widths) != len(target_stages):
                raise IncompatibleSourceError(
                    f"source {spec['name']!r} has {len(widths)} stages, the target "
                    f"{len(target_stages)}: lateral connections join stage j to stage j"
                )

    # ------------------------------------------------------------------ construction
    def _build_parts(
        self, source_widths: list[tuple[int, ...]], action_dim: int
    ) -> tuple[nn.Module | None, nn.Module]:
        """The method's ``(weighting, merge)`` modules."""
        raise NotImplementedError

    def _build_mlp_extractor(self) -> None:
        sources = [src for src, _ in self._new_sources]
        ready = all(ok for _, ok in self._new_sources)
        del self._new_sources
        weighting, merge = self._build_parts(
            [stage_widths(s) for s in sources], int(np.prod(self.action_space.shape))
        )
        self.mlp_extractor = LateralExtractor(
            self.features_dim,
            self.config.target,
            sources,
            weighting,
            merge,
            ready,
            [s.get("stage_map") for s in self.config.sources],
            self.source_names,
            self.config.performers,
            int(np.prod(self.action_space.shape)),
        )

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        ex = self.mlp_extractor
        if ex.residual_pick is not None:
            if not isinstance(self.action_dist, DiagGaussianDistribution):
                raise ValueError("the source-action residual needs a Gaussian action distribution")
            # The head maps the features alone; the residual part of the latent is added to it.
            self.action_net = nn.Linear(ex.latent_width, self.action_space.shape[0])
        if self.config.target.ortho_init:
            gains: list[tuple[nn.Module | None, float]] = [
                (ex.actor, math.sqrt(2)),
                (ex.critic, math.sqrt(2)),
                (ex.merge, math.sqrt(2)),
                (ex.weighting, math.sqrt(2)),
                (getattr(ex.weighting, "mix", None), 0.01),
                (self.action_net, 0.01),
                (self.value_net, 1.0),
            ]
            for module, gain in gains:
                if module is not None:
                    module.apply(partial(self.init_weights, gain=gain))
        # Only target, fusion, attention and head parameters train.
        trainable = [p for p in self.parameters() if p.requires_grad]
        self.optimizer = self.optimizer_class(trainable, lr=lr_schedule(1), **self.optimizer_kwargs)

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> TransferPolicy:
        """An untrained policy of the shape ``config`` (:meth:`TransferPolicyConfig.to_dict`)
        describes, for a saved state dict to be loaded into; the sources are not read from disk."""
        kwargs = dict(config)
        kwargs["sources"] = [
            {k: v for k, v in s.items() if k != "run_dir"} for s in kwargs["sources"]
        ]
        kwargs["ortho_init"] = False
        return cls(observation_space(), action_space(), lambda _: 0.0, **kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.pop("net_arch", None)
        data.update(self.config.to_dict())
        return data

    # ------------------------------------------------------------------ SB3 hooks
    def _get_action_dist_from_latent(self, latent_pi: torch.Tensor):
        ex = self.mlp_extractor
        if ex.residual_pick is None:
            return super()._get_action_dist_from_latent(latent_pi)
        features, residual = latent_pi[..., : ex.latent_width], latent_pi[..., ex.latent_width :]
        mean = self.action_net(features) + residual
        return self.action_dist.proba_distribution(mean, self.log_std)

    def forward(self, obs: torch.Tensor, deterministic: bool = False):
        """SB3's rollout step; the only place the target normaliser's statistics are updated."""
        norm = self.mlp_extractor.obs_norm
        if norm is not None and self.update_obs_stats:
            norm.update(obs)
        return super().forward(obs, deterministic)

    # ------------------------------------------------------------------ transfer interface
    @property
    def source_names(self) -> list[str]:
        return [s["name"] for s in self.config.sources]

    def stage_outputs(self, obs: torch.Tensor) -> list[torch.Tensor]:
        """Merged stage outputs of the actor for raw observations: what this policy offers when
        it is a source in turn."""
        return self.mlp_extractor.actor_stages(obs.float())

    @torch.no_grad()
    def attention(self, obs: PyTorchObs | np.ndarray) -> dict[str, np.ndarray | None]:
        """Contribution weights for raw observations: ``raw`` (the learned softmax, None for
        fixed weights) and ``weights`` (``W``, what scales the source features)."""
        ex = self.mlp_extractor
        if ex.weighting is None:
            raise ValueError(f"{type(self).__name__} has no contribution weights")
        x = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        x = x.reshape(-1, self.features_dim)
        _, actions = ex.source_outputs(x)
        raw, weights = ex.contribution(x, actions)
        return {
            "raw": None if raw is None else raw.cpu().numpy(),
            "weights": weights.cpu().numpy(),
        }
