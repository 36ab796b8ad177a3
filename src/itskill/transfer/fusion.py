"""How source features enter the target network after each of its stages.

``FeatureFusion`` (ITN, NIA; the paper's eqs. 5-7): the weighted source features and the target's
own are concatenated, ``F_j = (w_1 SO_1^j, ..., w_n SO_n^j, SO_t^j)``, and an MLP maps ``F_j`` to
the input of target stage ``j + 1`` (the last block's output feeds the action head). Each block
ends in the activation and has the target stage's width, so the next stage sees what it would
see without transfer.

``FeatureSum`` (DFS): no weights, no MLP; the source features are added to the target's,
``SO_t^j + sum_i SO_i^j``, which needs every source stage to have the target stage's width.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn


class FeatureFusion(nn.Module):
    """One MLP per target stage over ``[w_i * SO_i^j ..., SO_t^j]``."""

    def __init__(
        self,
        source_widths: Sequence[Sequence[int]],
        target_widths: Sequence[int],
        hidden: Sequence[int],
        activation: type[nn.Module],
    ) -> None:
        super().__init__()
        blocks = []
        for j, width in enumerate(target_widths):
            layers: list[nn.Module] = []
            prev = sum(src[j] for src in source_widths) + width
            for h in (*hidden, width):
                layers += [nn.Linear(prev, h), activation()]
                prev = h
            blocks.append(nn.Sequential(*layers))
        self.blocks = nn.ModuleList(blocks)

    def forward(
        self,
        stage: int,
        target: torch.Tensor,
        sources: list[torch.Tensor],
        weights: torch.Tensor | None,
    ) -> torch.Tensor:
        if weights is None:
            raise RuntimeError("feature fusion needs contribution weights")
        parts = [weights[:, i : i + 1] * f for i, f in enumerate(sources)]
        return self.blocks[stage](torch.cat([*parts, target], dim=-1))


class FeatureSum(nn.Module):
    """DFS: the target's stage output plus every source's, unweighted (the sources' widths are
    checked against the target's by :meth:`itskill.transfer.dfs.DFSPolicy.check_sources`)."""

    def forward(
        self,
        stage: int,
        target: torch.Tensor,
        sources: list[torch.Tensor],
        weights: torch.Tensor | None,
    ) -> torch.Tensor:
        return target + torch.stack(sources).sum(0)
