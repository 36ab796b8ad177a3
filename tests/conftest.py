"""Fixtures shared by the test packages: the state of a run directory and of its lock."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import Timeout

from itskill.files import directory_lock


@pytest.fixture
def lock_held() -> Callable[[Path, str], bool]:
    """Whether someone holds ``directory``'s lock of ``kind`` (asks for it and lets it go)."""

    def held(directory: Path, kind: str) -> bool:
        lock = directory_lock(directory, kind)
        try:
            lock.acquire(timeout=0)
        except Timeout:
            return True
        lock.release()
        return False

    return held


@pytest.fixture
def file_tree() -> Callable[[Path], dict[Path, bytes | None]]:
    """Every path under a directory with its bytes (None for a directory): what a refused call
    must leave as it was."""

    def tree(directory: Path) -> dict[Path, bytes | None]:
        return {p: p.read_bytes() if p.is_file() else None for p in directory.rglob("*")}

    return tree
