"""DFS (Direct Feature Summation): ITN without attention and without fusion; after each target
stage the sources' stage features are added to the target's as they are."""

from __future__ import annotations

from torch import nn

from itskill.transfer.fusion import FeatureSum
from itskill.transfer.lateral import TransferPolicy


class DFSPolicy(TransferPolicy):
    """Frozen sources whose stage features are summed into the target's; no prior is used."""

    uses_prior = False

    def _build_parts(
        self, source_widths: list[tuple[int, ...]], action_dim: int
    ) -> tuple[nn.Module | None, nn.Module]:
        return None, FeatureSum(source_widths, self.config.target.stages)
