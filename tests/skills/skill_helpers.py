"""Helpers shared by the skills tests (imported by name: pytest puts this folder on sys.path)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from itskill.skills import Skill


def random_unit(seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).standard_normal(384).astype(np.float32)
    return v / np.linalg.norm(v)


def make_skill(name: str, checkpoint: Path, seed: int = 0, **kw) -> Skill:
    """A skill with a given (random) embedding, so no test pays for the encoder unless it must."""
    return Skill(
        name=name,
        task_id=kw.pop("task_id", "pick_nut_m12"),
        description=kw.pop("description", "Pick up the M12 nut"),
        actions=kw.pop("actions", ("approach", "grasp", "lift")),
        checkpoint=str(checkpoint),
        embedding=kw.pop("embedding", random_unit(seed)),
        embedding_model=kw.pop("embedding_model", "sentence-transformers/all-MiniLM-L6-v2"),
        **kw,
    )


def measured(learned: str, success: float) -> Any:
    """A stand-in for ``measure_skill``: the held-out success of the run in directory ``learned``
    (``seed1``), 0.1 for the others, so which run learns does not depend on a 512-step training."""

    def measure(spec, policy_dir, config):
        rate = success if learned in Path(policy_dir).parts else 0.1
        return SimpleNamespace(success_rate=rate, ci_low=0.0, ci_high=1.0)

    return measure
