"""Where an ``itskill learn`` run keeps its steps' files, and how its records name them.

Records name the files relative to the run directory, so a run still reads them once moved or
copied to ``results/``; records of older runs hold absolute paths, found where the layout puts
them when they no longer exist (:func:`itskill.files.run_path`).
"""

from __future__ import annotations

from pathlib import Path, PureWindowsPath
from typing import Any

from itskill.files import run_path

LEARN_FILE = "learn.json"
USAGE_FILE = "usage.json"
REWARD_DIR = "reward"
"""The reward search's run directory."""
TRANSFER_DIR = "transfer"
"""The final training's run directory."""
BEST_REWARD = f"{REWARD_DIR}/best_reward.py"
"""The chosen reward (the search's ``best_reward.py``)."""
BEST_POLICY = f"{TRANSFER_DIR}/best"
"""The best evaluated policy of the final training (its ``best/``)."""


def best_reward_file(run_dir: Path, reward: dict[str, Any]) -> Path:
    """The chosen reward's file, from ``reward.json`` (``reward``)."""
    return run_path(run_dir, reward["best_path"], BEST_REWARD)


def transfer_dir(run_dir: Path, transfer: dict[str, Any]) -> Path:
    """The final training's run directory, from the ``transfer`` part of ``summary.json``."""
    return run_path(run_dir, transfer["run_dir"], TRANSFER_DIR)


def policy_dir(run_dir: Path, transfer: dict[str, Any]) -> Path:
    """The kept policy's directory, from the ``transfer`` part of ``summary.json`` (runs from
    before the best policy was kept evaluated their last checkpoint, the training's own)."""
    recorded = transfer.get("policy_dir", transfer["run_dir"])
    # PureWindowsPath reads both separators: a record written on Windows names transfer\best.
    best = PureWindowsPath(recorded).name == Path(BEST_POLICY).name
    usual = BEST_POLICY if best else TRANSFER_DIR
    return run_path(run_dir, recorded, usual)


def in_run(path: Path, run_dir: Path) -> str:
    """``path`` relative to ``run_dir`` where it lies in it (an older run's record may name a
    path elsewhere, kept as written)."""
    return (path.relative_to(run_dir) if path.is_relative_to(run_dir) else path).as_posix()


def kept_policy_words(run_dir: Path, transfer: dict[str, Any]) -> str:
    """Where the kept policy is, for a message: ``the run's transfer/best``, or the path where an
    older run's record names one outside the run."""
    path = policy_dir(run_dir, transfer)
    # Resolved: an older record may name a path relative to where its command ran, or one
    # that climbs out of the run ("../old/transfer/best"), and neither is the run's.
    where, root = path.resolve(), Path(run_dir).resolve()
    if where.is_relative_to(root):
        return f"the run's {where.relative_to(root).as_posix()}"
    return path.as_posix()
