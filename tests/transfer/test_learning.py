"""Slow: the ITN learns the pick-and-place task from the shipped pick and place skills."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from itskill.rl.logger import LoggerConfig
from itskill.transfer import train_transfer

STEPS = 300_000


@pytest.mark.slow
def test_itn_improves_on_its_sources_on_pick_and_place(home: Path, tmp_path: Path) -> None:
    # With the source-action residual the network starts near its sources chained (about 20%
    # success); PPO has to lift that, not merely keep it (seed 0 measured 20% at 50k, 64% at
    # 300k; docs/experiments.md).
    out = tmp_path / "itn"
    train_transfer(
        "pickplace_nut_m12", "itn", "auto", seed=0, steps=STEPS, algo="ppo", out=out,
        eval_every=STEPS // 6, eval_episodes=50,
        logger=LoggerConfig(progress=False, tensorboard=False),
    )  # fmt: skip
    with open(out / "eval.csv", newline="") as fh:
        success = [float(row["success"]) for row in csv.DictReader(fh)]
    assert len(success) >= 6
    assert success[-1] >= 0.45
    assert success[-1] > success[0] + 0.2
