"""Provenance names the code: the git commit of a checkout, marked when it was modified."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from itskill.experiments.provenance import code_commit

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="needs git")


def git(repo: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *args],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip


def test_commit_of_a_checkout_is_marked_dirty_when_a_tracked_file_changes(tmp_path: Path):
    repo = tmp_path / "repo"
    repo.mkdir()
    git(repo, "init", "-q")
    (repo / "a.py").write_text("x = 1\n")
    git(repo, "add", "a.py")
    git(repo, "commit", "-qm", "first")
    head = git(repo, "rev-parse", "HEAD")
    assert code_commit(repo) == head
    (repo / "notes.txt").write_text("untracked files do not change the code\n")
    assert code_commit(repo) == head
    (repo / "a.py").write_text("x = 2\n")
    assert code_commit(repo) == head + "+dirty"


def test_no_commit_outside_a_checkout(tmp_path: Path):
    assert code_commit(tmp_path) is None
