"""Shared helpers for the RL tests: a throwaway reach reward written to a file."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

torch.set_num_threads(1)

REACH_REWARD = """
import numpy as np

def compute_reward(ctx):
    d = np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
    close = 1.0 - np.tanh(10.0 * d)
    bonus = (d < 0.015).astype(float)
    return close + bonus, {"close": close, "bonus": bonus}
"""


@pytest.fixture
def reach_reward(tmp_path: Path) -> Path:
    path = tmp_path / "reach_reward.py"
    path.write_text(REACH_REWARD)
    return path
