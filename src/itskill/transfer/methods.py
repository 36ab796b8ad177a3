"""The transfer methods by name: the paper's ITN and its ablations, and learning from scratch.

| name | network | sources | analyzer |
|---|---|---|---|
| ``itn`` | :class:`~itskill.transfer.itn.ITNPolicy` | all retrieved | prior of the attention |
| ``nia`` | :class:`~itskill.transfer.nia.NIAPolicy` | all retrieved | the fixed weights |
| ``dfs`` | :class:`~itskill.transfer.dfs.DFSPolicy` | all retrieved | not used |
| ``pst`` | :class:`~itskill.transfer.itn.ITNPolicy` | a subset (see ``pst.py``) | prior |
| ``no_transfer`` | :class:`~itskill.rl.policy.StagedActorCriticPolicy` | none | not used |
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from stable_baselines3.common.policies import ActorCriticPolicy

from itskill.rl.policy import StagedActorCriticPolicy
from itskill.transfer.config import TransferConfig
from itskill.transfer.dfs import DFSPolicy
from itskill.transfer.itn import ITNPolicy
from itskill.transfer.nia import NIAPolicy
from itskill.transfer.pst import select_sources

S = TypeVar("S")  # a source skill, or the name an experiment stored for it


def all_sources(sources: list[S], config: TransferConfig) -> list[S]:
    """Every resolved source: the choice of the methods that keep them all."""
    return sources


@dataclass(frozen=True)
class Method:
    """A transfer method: its policy class, whether it uses sources, which of the resolved
    sources it keeps, and the :class:`TransferConfig` fields that shape its network or its
    choice among them (``settings``, shown by the experiment report)."""

    name: str
    policy_class: type[ActorCriticPolicy]
    uses_sources: bool
    settings: tuple[str, ...] = ()
    select: Callable[[list[Any], TransferConfig], list[Any]] = all_sources

    @property
    def uses_prior(self) -> bool:
        """Whether its network takes the analyzer's contribution matrix (its policy class's
        ``uses_prior``)."""
        return bool(getattr(self.policy_class, "uses_prior", False))


_ATTENTION = ("attention_hidden", "prior_weight")
_FUSION = ("fusion_hidden", "residual")

METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method("itn", ITNPolicy, True, (*_ATTENTION, *_FUSION)),
        Method("nia", NIAPolicy, True, _FUSION),
        Method("dfs", DFSPolicy, True, ("residual",)),
        Method("pst", ITNPolicy, True, ("pst_keep", *_ATTENTION, *_FUSION), select_sources),
        Method("no_transfer", StagedActorCriticPolicy, False),
    )
}  # fmt: skip


def get_method(name: str) -> Method:
    """The method called ``name``, or ``ValueError`` listing the known ones."""
    if name not in METHODS:
        raise ValueError(f"unknown transfer method {name!r}; expected one of {', '.join(METHODS)}")
    return METHODS[name]


def used_settings(methods: Iterable[str], config: Mapping[str, Any]) -> dict[str, Any]:
    """The fields of ``config`` (:class:`TransferConfig`'s, by name) that any of ``methods``
    uses (:attr:`Method.settings`), in the methods' order."""
    return {
        name: config[name] for m in methods for name in get_method(m).settings if name in config
    }
