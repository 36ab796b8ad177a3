"""ITN, the Intelligent Transfer Network: intelligent attention weights the frozen sources' stage
features, and a fusion MLP after each target stage joins them with the target's own
(:mod:`itskill.transfer.lateral` for the network, :mod:`~itskill.transfer.attention` for ``W``)."""

from __future__ import annotations

import numpy as np
from torch import nn

from itskill.rl.policy import ACTIVATIONS
from itskill.transfer.attention import IntelligentAttention
from itskill.transfer.fusion import FeatureFusion
from itskill.transfer.lateral import TransferPolicy


class ITNPolicy(TransferPolicy):
    """Frozen sources, intelligent attention corrected by the analyzer, feature fusion."""

    def _build_parts(
        self, source_widths: list[tuple[int, ...]], action_dim: int
    ) -> tuple[nn.Module | None, nn.Module]:
        cfg = self.config
        activation = ACTIVATIONS[cfg.target.activation]
        attention = IntelligentAttention(
            len(source_widths),
            action_dim,
            cfg.attention_hidden,
            activation,
            np.asarray(cfg.prior),
            cfg.prior_weight,
        )
        fusion = FeatureFusion(source_widths, cfg.target.stages, cfg.fusion_hidden, activation)
        return attention, fusion
