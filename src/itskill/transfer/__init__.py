"""Transfer of learned skills to a new task: the Intelligent Transfer Network and its ablations.

Sources come from the skill space (:mod:`~itskill.transfer.sources`), the analyzer turns a
language model's judgement into a contribution matrix (:mod:`~itskill.transfer.analyzer`), and
each method is a policy class over frozen sources (:mod:`~itskill.transfer.methods`) trained by
:func:`itskill.rl.train.train` through :func:`~itskill.transfer.train.train_transfer`.
"""

from __future__ import annotations

from itskill.transfer.analyzer import AnalyzerError, ContributionMatrix, analyze
from itskill.transfer.config import TransferConfig, TransferConfigError, load_transfer_config
from itskill.transfer.dfs import DFSPolicy
from itskill.transfer.itn import ITNPolicy
from itskill.transfer.lateral import TransferPolicy, TransferPolicyConfig
from itskill.transfer.methods import METHODS, Method, get_method
from itskill.transfer.nia import NIAPolicy
from itskill.transfer.sources import SourceError, SourceSkill, resolve_sources
from itskill.transfer.trace import attention_trace, recorded_attention_trace
from itskill.transfer.train import (
    TRANSFER_FILE,
    analyze_sources,
    prepare_transfer,
    read_transfer,
    search_network,
    target_entry,
    train_transfer,
    transfer_network,
)

__all__ = [
    "METHODS",
    "TRANSFER_FILE",
    "AnalyzerError",
    "ContributionMatrix",
    "DFSPolicy",
    "ITNPolicy",
    "Method",
    "NIAPolicy",
    "SourceError",
    "SourceSkill",
    "TransferConfig",
    "TransferConfigError",
    "TransferPolicy",
    "TransferPolicyConfig",
    "analyze",
    "analyze_sources",
    "attention_trace",
    "get_method",
    "load_transfer_config",
    "prepare_transfer",
    "read_transfer",
    "recorded_attention_trace",
    "resolve_sources",
    "search_network",
    "target_entry",
    "train_transfer",
    "transfer_network",
]
