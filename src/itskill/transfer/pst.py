"""PST (Partial Skills Transfer): the ITN network over only part of the retrieved sources.

Which part is data: ``[pst] keep`` in ``transfer.toml`` keeps the first ``keep`` sources in the
order ``auto`` chose them (default 1: the skill that performs most of the target's steps, for
the nut pick-and-place the pick); sources named explicitly keep the order given. The analyzer
is then asked about those sources only; about one source it is not asked (every stage is that
source's), and the attention over it weights it 1 whatever its settings (``attention_hidden``,
``prior_weight``), which then change nothing.
"""

from __future__ import annotations

from typing import TypeVar

from itskill.transfer.config import TransferConfig
from itskill.transfer.sources import SourceError

S = TypeVar("S")


def select_sources(sources: list[S], config: TransferConfig) -> list[S]:
    """The sources PST transfers from: the first ``config.pst_keep`` (of :class:`SourceSkill`
    objects, or of the names an experiment stored for its task).

    Keeping every source would train ITN itself under another name: :class:`SourceError`.
    """
    if len(sources) <= config.pst_keep:
        # A smaller keep helps only where more than one source is given.
        smaller = " or a smaller [pst] keep" if len(sources) > 1 else ""
        raise SourceError(
            f"PST keeps {config.pst_keep} of the {len(sources)} source(s): that is ITN itself; "
            f"give more sources (k, or the sources named){smaller}",
            setting="pst_keep",
        )
    return sources[: config.pst_keep]
