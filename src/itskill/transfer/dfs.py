"""DFS (Direct Feature Summation): ITN without attention and without fusion; after each target
stage the sources' stage features are added to the target's as they are."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from torch import nn

from itskill.transfer.fusion import FeatureSum
from itskill.transfer.lateral import TransferPolicy
from itskill.transfer.sources import IncompatibleSourceError


class DFSPolicy(TransferPolicy):
    """Frozen sources whose stage features are summed into the target's; no prior is used."""

    uses_prior = False

    @classmethod
    def check_sources(
        cls, sources: Sequence[Mapping[str, Any]], target_stages: Sequence[int]
    ) -> None:
        """As the other methods', and every source stage as wide as the target's: its features
        are added to the target's as they are."""
        super().check_sources(sources, target_stages)
        for spec in sources:
            widths = tuple(spec["policy"]["stages"])
            if widths != tuple(target_stages):
                raise IncompatibleSourceError(
                    f"direct feature summation needs every source stage as wide as the target's: "
                    f"source {spec['name']!r} has stages {list(widths)}, the target "
                    f"{list(target_stages)}"
                )

    def _build_parts(
        self, source_widths: list[tuple[int, ...]], action_dim: int
    ) -> tuple[nn.Module | None, nn.Module]:
        return None, FeatureSum()
