"""NIA (No Intelligent Attention): ITN whose contribution values are fixed, the analyzer's row for
the current stage, with nothing learned in between; the feature fusion is ITN's."""

from __future__ import annotations

import numpy as np
from torch import nn

from itskill.rl.policy import ACTIVATIONS
from itskill.transfer.attention import FixedContribution
from itskill.transfer.fusion import FeatureFusion
from itskill.transfer.lateral import TransferPolicy


class NIAPolicy(TransferPolicy):
    """Frozen sources weighted by the analyzer's fixed values, feature fusion."""

    def _build_parts(
        self, source_widths: list[tuple[int, ...]], action_dim: int
    ) -> tuple[nn.Module | None, nn.Module]:
        cfg = self.config
        activation = ACTIVATIONS[cfg.target.activation]
        fusion = FeatureFusion(source_widths, cfg.target.stages, cfg.fusion_hidden, activation)
        return FixedContribution(np.asarray(cfg.prior)), fusion
