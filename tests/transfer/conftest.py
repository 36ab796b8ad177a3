"""Shared fixtures: tiny random source checkpoints, a skill space with the shipped library."""

from __future__ import annotations

from pathlib import Path

import pytest
from transfer_helpers import make_source


@pytest.fixture
def tiny_sources(tmp_path: Path) -> list[dict]:
    return [make_source(tmp_path / f"src{i}", seed=i) for i in range(2)]


@pytest.fixture(scope="session")
def skill_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An $ITSKILL_HOME whose skill space holds the shipped library (embedded once)."""
    from itskill.skills import open_skill_space

    home = tmp_path_factory.mktemp("itskill_home")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ITSKILL_HOME", str(home))
        with open_skill_space() as space:
            space.list()
    return home


@pytest.fixture
def home(skill_home: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("ITSKILL_HOME", str(skill_home))
    return skill_home
