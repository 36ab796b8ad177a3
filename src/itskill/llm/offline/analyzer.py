"""The offline transfer analyzer: a contribution matrix from action-sequence overlap.

Target segment ``s`` is the target's ``s``-th action. Source ``j`` scores, for that segment, its
best occurrence of the same action: 1, plus 0.5 if the action before it matches the target's
previous action and 0.5 if the one after matches the target's next action (the same action in the
same context counts most). A source without the action scores ``FLOOR``: never exactly zero, so
the attention can still use it. Each row is normalised to sum to 1.
"""

from __future__ import annotations

import json

from itskill.llm.offline.backend import BACKEND

FLOOR = 0.05
CONTEXT_BONUS = 0.5


def segment_score(target: list[str], s: int, source: list[str]) -> float:
    """How much a source with action sequence ``source`` fits target segment ``s``."""
    before = target[s - 1] if s > 0 else None
    after = target[s + 1] if s + 1 < len(target) else None
    best = 0.0
    for k, action in enumerate(source):
        if action != target[s]:
            continue
        score = 1.0
        score += CONTEXT_BONUS * ((source[k - 1] if k > 0 else None) == before)
        score += CONTEXT_BONUS * ((source[k + 1] if k + 1 < len(source) else None) == after)
        best = max(best, score)
    return best or FLOOR


def contribution(target: dict, sources: list[dict]) -> dict:
    """``{"matrix": m x n rows summing to 1, "segments": target actions, "reasoning": ...}``."""
    actions = [str(a) for a in target["actions"]]
    matrix, reasons = [], []
    for s, action in enumerate(actions):
        scores = [segment_score(actions, s, [str(a) for a in src["actions"]]) for src in sources]
        total = sum(scores)
        matrix.append([round(v / total, 6) for v in scores])
        top = [str(src["id"]) for src, v in zip(sources, scores, strict=True) if v == max(scores)]
        if max(scores) == FLOOR:
            reasons.append(f"segment {s} ({action}): no source does it; spread evenly")
        elif len(top) > 1:
            reasons.append(f"segment {s} ({action}): {', '.join(top)} do it alike")
        else:
            reasons.append(f"segment {s} ({action}): {top[0]} does it most alike")
    return {
        "matrix": matrix,
        "segments": actions,
        "reasoning": f"{BACKEND} (not a language model): action-sequence overlap; "
        + "; ".join(reasons),
    }


def reply(target_text: str | None, sources_text: str | None) -> str:
    """The analyzer's reply text: one ```json fence."""
    if target_text is None or sources_text is None:
        result: dict = {"error": f"{BACKEND}: the prompt has no <target> or <sources> block"}
    else:
        try:
            result = contribution(json.loads(target_text), json.loads(sources_text))
        except (ValueError, KeyError, TypeError, ZeroDivisionError) as err:
            result = {"error": f"{BACKEND}: cannot read the target or sources: {err}"}
    return "```json\n" + json.dumps(result) + "\n```\n"
