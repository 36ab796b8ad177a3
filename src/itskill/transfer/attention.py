"""How much each source contributes: the intelligent attention (ITN) and fixed contributions (NIA).

Both look up the analyzer's contribution row for the current segment of the target task. The
segment is the task stage, read from the observation's ``stage_onehot`` slice (the same stage
predicates that drive the task's progress), so the prior changes exactly when a stage is done.

Intelligent attention (the paper's eqs. 1-3)::

    h_i  = MLP_i(pi_i(s))                          each source's action mean through its own MLP
    w'   = softmax(Linear(h_1, ..., h_n))          raw weights
    W    = (1 - beta) * w' + beta * g(stage)       g: the analyzer's row for the current stage

The paper adds the analyzer's term to the raw weights; both sum to 1, so with ``beta = 0.5`` (the
default) ``W`` is that sum renormalised, and ``W`` stays a convex combination for any ``beta`` in
[0, 1]. The raw weights are learned; the prior is fixed: it steers ``W`` towards the analyzer's
judgement in each stage while the learned part adapts within it.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from itskill.sim.layout import MAX_STAGES
from itskill.transfer.stages import STAGE_SLICE, pad_stages


class StagePrior(nn.Module):
    """The analyzer's contribution row for each observation's current stage.

    ``prior`` is ``(m, n)`` for a target with ``m`` stages (padded, :func:`pad_stages`).
    """

    def __init__(self, prior: np.ndarray) -> None:
        super().__init__()
        prior = np.asarray(prior, dtype=np.float32)
        if prior.ndim != 2 or not 1 <= prior.shape[0] <= MAX_STAGES:
            raise ValueError(f"prior must be (stages <= {MAX_STAGES}, sources), got {prior.shape}")
        self.register_buffer("table", torch.as_tensor(np.stack(pad_stages(prior))))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return obs[..., STAGE_SLICE].to(self.table.dtype) @ self.table


class IntelligentAttention(nn.Module):
    """Learned raw weights from the sources' actions, corrected by the analyzer's stage prior.

    ``forward`` returns ``(raw, W)``.
    """

    def __init__(
        self,
        n_sources: int,
        action_dim: int,
        hidden: int,
        activation: type[nn.Module],
        prior: np.ndarray,
        prior_weight: float,
    ) -> None:
        super().__init__()
        self.encoders = nn.ModuleList(
            nn.Sequential(nn.Linear(action_dim, hidden), activation()) for _ in range(n_sources)
        )
        self.mix = nn.Linear(n_sources * hidden, n_sources)
        self.prior = StagePrior(prior)
        if self.prior.table.shape[1] != n_sources:
            raise ValueError(
                f"the prior has {self.prior.table.shape[1]} columns for {n_sources} sources"
            )
        self.prior_weight = float(prior_weight)

    def forward(
        self, obs: torch.Tensor, source_actions: list[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        h = torch.cat(
            [enc(a) for enc, a in zip(self.encoders, source_actions, strict=True)], dim=-1
        )
        raw = torch.softmax(self.mix(h), dim=-1)
        weights = (1.0 - self.prior_weight) * raw + self.prior_weight * self.prior(obs)
        return raw, weights


class FixedContribution(nn.Module):
    """NIA's weights: the analyzer's row for the current stage, nothing learned (no ``raw``)."""

    def __init__(self, prior: np.ndarray) -> None:
        super().__init__()
        self.prior = StagePrior(prior)

    def forward(
        self, obs: torch.Tensor, source_actions: list[torch.Tensor]
    ) -> tuple[None, torch.Tensor]:
        return None, self.prior(obs)
