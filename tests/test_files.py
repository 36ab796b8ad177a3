"""Atomic writes: a file is either its old self or complete, and a failed write leaves nothing."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from itskill.files import write_text


def test_a_write_that_fails_keeps_the_old_file_and_leaves_no_temporary(
    tmp_path: Path, monkeypatch
) -> None:
    path = tmp_path / "config.json"
    write_text(path, "old")

    def disk_full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space"):
        write_text(path, "new")
    # A leftover temporary made `learn --resume` take an empty run for a started one.
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == [path.name]
