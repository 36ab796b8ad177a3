"""Which stage of its own task a source skill is in while the target task is in a given stage.

A source policy was trained with its own task's stage in the observation (``stage_onehot``). In a
target task the stage index means something else: stage 3 of "pick up the nut and place it on the
bolt" is the approach to the bolt, the first stage of the Place skill and a stage the Pick skill
never saw. So each source is shown the stage its own task would be in, found by lining the
source's stage names up with the target's:

- where the source's stages occur in the target's as a contiguous run, a target stage inside a
  run is the source stage at the same offset; after a run the source has done its part and stays
  in its last stage; before the first run it is in its first stage;
- otherwise the names are matched in order, never going back (a stage whose name the source does
  not have keeps the source where it was).

The same runs say which source *performs* a target stage (:func:`stage_performers`): the first
source, in the order given, with a run covering it. A stage no source's stage names cover is
given to the first source whose *action sequence* covers it, where the target has one action per
stage: a one-stage Place skill (actions approach, place) also performs the approach to the
fixture that precedes the target's place stage.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from itskill.sim.layout import MAX_STAGES, OBSERVATION_LAYOUT

STAGE_SLICE = OBSERVATION_LAYOUT["stage_onehot"]
"""Where an observation holds the one-hot of its task's current stage."""

Row = TypeVar("Row")


def pad_stages(rows: Sequence[Row]) -> list[Row]:
    """``rows``, one per stage of a target, padded to the layout's ``MAX_STAGES`` with the last:
    a table indexed by the stage one-hot needs a row for each entry, and those past the target's
    last stage are never read (the stage index stops there)."""
    return [*rows, *[rows[-1]] * (MAX_STAGES - len(rows))]


def runs(target: Sequence[str], source: Sequence[str]) -> list[int]:
    """Start indices of the contiguous occurrences of ``source`` in ``target`` (none for an empty
    ``source``)."""
    n = len(source)
    if n == 0:
        return []
    return [i for i in range(len(target) - n + 1) if tuple(target[i : i + n]) == tuple(source)]


def stage_map(target: Sequence[str], source: Sequence[str]) -> tuple[int, ...]:
    """For each target stage, the index of the source stage a source skill should see.

    ``target`` and ``source`` are the two tasks' stage names, in order.
    """
    if not target or not source:
        raise ValueError("stage_map needs the stage names of both tasks")
    n = len(source)
    starts = runs(target, source)
    if starts:
        out = []
        for j in range(len(target)):
            begun = [i for i in starts if i <= j]
            out.append(min(j - max(begun), n - 1) if begun else 0)
        return tuple(out)
    out, pos = [], 0
    for name in target:
        if name in source[pos:]:
            pos = source.index(name, pos)
        out.append(pos)
    return tuple(out)


def stage_performers(
    target: Sequence[str], sources: Sequence[Sequence[str] | None]
) -> tuple[int, ...]:
    """For each target stage, the index of the first source whose stages cover it as part of a
    contiguous run, or -1 where none does (a source given as None, stages unknown, covers none)."""
    out = [-1] * len(target)
    for k, source in enumerate(sources):
        for i in runs(target, source or ()):
            for j in range(i, i + len(source)):
                if out[j] < 0:
                    out[j] = k
    return tuple(out)


def fill_performers(
    performers: Sequence[int],
    target_actions: Sequence[str],
    source_actions: Sequence[Sequence[str]],
) -> tuple[int, ...]:
    """``performers`` with each uncovered stage (-1) given to the first source whose action
    sequence covers it (:func:`stage_performers` on actions); unchanged unless the target has
    exactly one action per stage."""
    if len(target_actions) != len(performers):
        return tuple(performers)
    by_action = stage_performers(target_actions, source_actions)
    return tuple(p if p >= 0 else a for p, a in zip(performers, by_action, strict=True))
