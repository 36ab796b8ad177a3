"""A run's LLM usage over its sessions: each session's own share, added up."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.files import CorruptFileError
from itskill.llm import OfflineClient, Usage
from itskill.llm.usage_log import UsageLog


def test_each_session_counts_what_its_client_used_since_the_run_began(tmp_path: Path) -> None:
    path = tmp_path / "usage.json"
    client = OfflineClient()
    client.usage.requests = 2  # the steps before (a plan, an analysis) asked this client first
    log = UsageLog(path, client)  # a step of its own: it counts from here
    client.usage.requests += 3
    assert log.save()["total"]["requests"] == 3
    # A second session whose caller asked the model for the run before opening the log (the
    # reward search's plan and network): counted from the given point.
    fresh = OfflineClient()
    fresh.usage.requests = 4
    total = UsageLog(path, fresh, since=Usage()).save()
    assert [s["requests"] for s in total["sessions"]] == [3, 4]
    assert total["total"]["requests"] == 7


def test_a_damaged_usage_file_is_named(tmp_path: Path) -> None:
    # A list, or sessions that are not numbers, were a TypeError where the total is added up.
    path = tmp_path / "usage.json"
    path.write_text('{"sessions": [{"requests": "many"}]}')
    with pytest.raises(CorruptFileError, match=r"usage.json.*sessions\[0\]\.requests"):
        UsageLog(path, OfflineClient())
