"""Reply cache: a rerun replays the replies it already paid for instead of asking again.

One JSON file per request under the cache directory, named by a SHA-256 of what determines the
reply: the model, the messages, ``n``, the sampling temperature, the purpose and the request's
*occurrence index*. The endpoint URL is left out on purpose, so moving from one server to another
serving the same model keeps the cache. The occurrence index counts identical requests within one
client's lifetime (0 for the first, 1 for the second, ...): asking the same question twice in a run
still gets two independent samples, and a rerun that asks the same sequence of questions gets the
same sequence of replies back. Files are written atomically (temporary file, then ``os.replace``),
so a run killed mid-write never leaves a truncated entry. Processes sharing a cache (an
experiment's cells) ask one at a time (:meth:`ReplyCache.lock`): of two asking the same question,
the second replays the first's reply instead of drawing another sample of its own.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from pathlib import Path
from typing import Any

from filelock import FileLock

from itskill.files import directory_lock, write_text

CACHE_VERSION = 1


def request_key(
    model: str, messages: list[dict[str, str]], n: int, temperature: float, purpose: str
) -> str:
    """SHA-256 (hex) of everything that determines a request's replies, except the occurrence."""
    payload = json.dumps(
        {
            "version": CACHE_VERSION,
            "model": model,
            "messages": messages,
            "n": n,
            "temperature": round(float(temperature), 6),
            "purpose": purpose,
        },
        sort_keys=True,
        ensure_ascii=False,
    )
    return hashlib.sha256(payload.encode()).hexdigest()


class ReplyCache:
    """Replies on disk, one file per request (``<cache_dir>/<key>.json``)."""

    def __init__(self, cache_dir: Path) -> None:
        self.dir = Path(cache_dir)
        self._seen: Counter[str] = Counter()

    def occurrence_key(self, key: str) -> str:
        """The key of the next occurrence of request ``key`` in this client's lifetime."""
        index = self._seen[key]
        self._seen[key] += 1
        return hashlib.sha256(f"{key}:{index}".encode()).hexdigest()

    def path(self, key: str) -> Path:
        return self.dir / f"{key}.json"

    def lock(self) -> FileLock:
        """The cache's lock across processes, held from a lookup to its write
        (:func:`~itskill.files.directory_lock`: its file is among the user's locks, not in the
        cache, which may be read-only).

        Without it, cells started together (an ITN and an NIA cell asking the analyzer the same
        question) each missed the cache and got replies of their own, so their priors differed
        with the number of workers."""
        return directory_lock(self.dir, "llm-cache")

    def get(self, key: str, n: int) -> list[str] | None:
        """The cached replies for ``key``, or None if absent or unusable (then it is re-asked)."""
        try:
            data = json.loads(self.path(key).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        replies = data.get("replies") if isinstance(data, dict) else None
        if (
            not isinstance(replies, list)
            or len(replies) != n
            or not all(isinstance(r, str) for r in replies)
        ):
            return None
        return replies

    def put(self, key: str, replies: list[str], meta: dict[str, Any]) -> None:
        record = {**meta, "version": CACHE_VERSION, "replies": replies}
        write_text(self.path(key), json.dumps(record, indent=1, ensure_ascii=False))
