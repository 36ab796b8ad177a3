"""Shared fixtures for the reward-loop tests; the tiny search budget is in search_helpers.py."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest
from rich.console import Console

# The local OpenAI-compatible server of the llm tests (tests/llm/fake_openai.py).
sys.path.insert(0, str(Path(__file__).parents[1] / "llm"))


@pytest.fixture
def quiet() -> Console:
    """A console that keeps the search's progress out of the test output."""
    return Console(file=io.StringIO(), width=120)
