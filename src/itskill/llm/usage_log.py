"""A run's language-model usage across its sessions, kept in a JSON file beside the run.

A resumed run makes a new client, whose counts start at zero; a client handed from one step to
the next (``itskill learn`` plans, then searches, then analyzes) has counted the steps before.
So each session records what its client consumed since the log was opened, and the file adds the
sessions up: a run's total is neither the last session's alone nor a step's counted twice.
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from itskill.files import check_shape, read_json, write_json
from itskill.llm.client import LLMClient, Usage

USAGE_KEYS = tuple(f.name for f in fields(Usage))
_SESSION = {f"{key}?": float for key in (*USAGE_KEYS, "wall_s")}
"""A recorded session: the numbers the total adds up (each may be absent)."""


class UsageLog:
    """The usage file ``path`` of a run whose current session uses ``client``: what it consumed
    since ``since`` (a copy of its usage taken when the run's work began; default: now)."""

    def __init__(self, path: Path, client: LLMClient, since: Usage | None = None) -> None:
        self.path, self.client = Path(path), client
        self._start = replace(since if since is not None else client.usage)
        self._started = time.monotonic()
        self._earlier: list[dict[str, Any]] = []
        if self.path.is_file():
            data = read_json(self.path)
            check_shape(self.path, data, {"sessions": [_SESSION]})
            self._earlier = data["sessions"]
        self._session = {"started": datetime.now(timezone.utc).isoformat(timespec="seconds")}

    def save(self) -> dict[str, Any]:
        """Write this session's usage so far and the total over every session; returns both."""
        used = self.client.usage.since(self._start)
        self._session.update(wall_s=round(time.monotonic() - self._started, 1), **used.to_dict())
        sessions = [*self._earlier, self._session]
        total: dict[str, Any] = {k: sum(s.get(k, 0) for s in sessions) for k in USAGE_KEYS}
        total["wall_s"] = round(sum(s.get("wall_s", 0.0) for s in sessions), 1)
        data = {
            "llm": self.client.name,
            "offline": self.client.offline,
            "total": total,
            "sessions": sessions,
        }
        write_json(self.path, data)
        return data
