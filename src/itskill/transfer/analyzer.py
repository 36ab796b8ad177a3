"""The intelligent analyzer: a language model's contribution matrix, checked before it is used.

The matrix has one row per segment of the target task (its stages, in order) and one column per
source skill; entry ``(i, j)`` is how much source ``j`` should contribute while the target is in
segment ``i``. The reply must be a JSON object ``{"matrix": [[...], ...], "reasoning": "..."}``
(in a ```json fence, or bare with prose around it). It is validated (shape, finite, non-negative,
no zero row) and each row is normalised to sum to 1, since a language model's rows are rarely
exact. A reply that fails is sent back with the problem (the ``analyzer_retry`` prompt template,
which ``$ITSKILL_PROMPTS_DIR`` overrides like the others) up to ``retries`` times; then
:class:`AnalyzerError` says what was wrong with the last one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from itskill.llm.client import LLMClient, Message
from itskill.llm.prompts import analyzer_messages, analyzer_retry
from itskill.llm.replies import JSONReplyError, parse_json_reply


class AnalyzerError(ValueError):
    """The analyzer gave no valid contribution matrix, even after being told what was wrong."""


@dataclass(frozen=True)
class ContributionMatrix:
    """``matrix[i, j]``: contribution of source ``sources[j]`` in target segment ``segments[i]``.

    Rows are non-negative and sum to 1. ``client`` names who produced it (``"offline"``,
    ``"openai:MODEL"``).
    """

    matrix: np.ndarray
    segments: tuple[str, ...]
    sources: tuple[str, ...]
    reasoning: str = ""
    client: str = ""

    def __post_init__(self) -> None:
        matrix = np.asarray(self.matrix, dtype=np.float64)
        object.__setattr__(
            self, "matrix", validate_matrix(matrix, len(self.segments), len(self.sources))
        )
        object.__setattr__(self, "segments", tuple(self.segments))
        object.__setattr__(self, "sources", tuple(self.sources))

    def to_dict(self) -> dict[str, Any]:
        return {
            "matrix": self.matrix.tolist(),
            "segments": list(self.segments),
            "sources": list(self.sources),
            "reasoning": self.reasoning,
            "client": self.client,
        }


def validate_matrix(matrix: Any, m: int, n: int) -> np.ndarray:
    """``matrix`` as an ``(m, n)`` array with rows summing to 1; ``ValueError`` names a flaw."""
    try:
        arr = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as err:
        raise ValueError(f"the matrix is not a rectangular table of numbers ({err})") from err
    if arr.shape != (m, n):
        raise ValueError(
            f"the matrix has shape {arr.shape}, expected ({m}, {n}): "
            f"{m} rows (one per target segment) of {n} numbers (one per source)"
        )
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        i, j = bad[0]
        raise ValueError(f"entry [{i}][{j}] is {arr[i, j]}, every entry must be a finite number")
    neg = np.argwhere(arr < 0)
    if neg.size:
        i, j = neg[0]
        raise ValueError(f"entry [{i}][{j}] is {arr[i, j]}, every entry must be non-negative")
    # Scaled by each row's largest entry first: a row of finite entries near the float limit
    # would sum to inf and normalise to zeros.
    peak = arr.max(axis=1, keepdims=True)
    zero = np.flatnonzero(peak[:, 0] <= 0)
    if zero.size:
        raise ValueError(
            f"row {zero[0]} is all zeros: every target segment needs some contribution"
        )
    scaled = arr / peak
    return scaled / scaled.sum(axis=1, keepdims=True)


def parse_reply(
    reply: str, segments: Sequence[str], sources: Sequence[str]
) -> tuple[np.ndarray, str]:
    """The validated ``(matrix, reasoning)`` of one reply; ``ValueError`` says what is wrong."""
    try:
        data = parse_json_reply(reply)
    except JSONReplyError as err:
        raise ValueError(str(err)) from err
    if "matrix" not in data:
        raise ValueError('the JSON object has no "matrix" field')
    rows = data["matrix"]
    if not isinstance(rows, list) or not all(isinstance(r, list) for r in rows):
        raise ValueError('"matrix" must be a list of rows, each a list of numbers')
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"entry [{i}][{j}] is {v!r}, not a number")
    if len(rows) != len(segments) or any(len(r) != len(sources) for r in rows):
        lengths = sorted({len(r) for r in rows})
        raise ValueError(
            f"the matrix has {len(rows)} rows of length {lengths}, expected "
            f"{len(segments)} rows (segments {list(segments)}) of {len(sources)} numbers "
            f"(sources {list(sources)})"
        )
    reasoning = data.get("reasoning", "")
    return validate_matrix(rows, len(segments), len(sources)), str(reasoning)


def analyze(
    target: dict[str, Any],
    sources: list[dict[str, Any]],
    client: LLMClient,
    retries: int = 2,
) -> ContributionMatrix:
    """Ask ``client`` for the contribution matrix of ``sources`` to ``target``.

    ``target`` and each source are ``{"id", "description", "actions"}``; the target's actions are
    its segments (one row each). Raises :class:`AnalyzerError` after ``retries`` corrections.
    """
    segments = [str(a) for a in target["actions"]]
    names = [str(s["id"]) for s in sources]
    messages: list[Message] = analyzer_messages(target, sources)
    problem = ""
    reply = ""
    for _ in range(retries + 1):
        reply = client.complete(messages, 1, purpose="analyze")[0]
        try:
            matrix, reasoning = parse_reply(reply, segments, names)
        except ValueError as err:
            problem = str(err)
            messages = [
                *messages,
                {"role": "assistant", "content": reply},
                {"role": "user", "content": analyzer_retry(problem, len(segments), len(names))},
            ]
            continue
        return ContributionMatrix(matrix, tuple(segments), tuple(names), reasoning, client.name)
    raise AnalyzerError(
        f"the analyzer ({client.name}) gave no valid contribution matrix in {retries + 1} "
        f"attempt(s); last problem: {problem}; its reply began: {reply[:200]!r}"
    )
