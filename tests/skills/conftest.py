"""Every skills test gets its own ITSKILL_HOME so nothing touches the user's skill space."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    home = tmp_path / "home"
    monkeypatch.setenv("ITSKILL_HOME", str(home))
    return home


@pytest.fixture
def checkpoint(tmp_path: Path) -> Path:
    """A stand-in policy file: the store only checks that the checkpoint exists."""
    path = tmp_path / "dummy_policy.zip"
    path.write_bytes(b"not a real policy")
    return path


@pytest.fixture(autouse=True)
def no_shipped_library(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Skill spaces start empty in tests, whatever library the checkout ships."""
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", tmp_path / "no-shipped-library")
