"""Find source skills for a new task: cosine similarity of sentence embeddings.

What is embedded for a skill (:func:`skill_text`) is its task command followed by its action
sequence with repeats dropped, e.g. ``"Pick up the M12 nut. Actions: approach, grasp, lift"``.

Why this text and not the command alone: the aim is a *source* for transfer, i.e. a skill whose
execution resembles part of the target, and the action sequence is the part of a skill that says
what it executes. With the command alone, the skill whose command is a paraphrase of the query wins
by wording even when it is the same multi-step task; with the actions appended, short skills whose
primitive matches a verb of the query (``insert``) rise to the top. Repeats are dropped because
composite skills list the same primitives several times (``approach`` twice in pick-place), and a
long repeated list otherwise dominates the sentence vector and drowns the description. Measured on
the 31 task commands of the time, query "Pick up the round peg and insert it into the round hole":
``insert_peg_round`` 0.874, ``pickplaceinsert_peg_round`` 0.802, ``insert_peg_rect`` 0.799. (With
repeats kept, the exact multi-step task falls to 4th; with the command alone it is 1st at 1.0 and
``insert_peg_round`` 2nd at 0.980.)

A user looking a skill up (``itskill skills search``) wants the skill whose command is the query
first, which the text with its actions does not give: "Pick up the round peg" ranked
``carry_peg_round`` first and ``pick_peg_round`` eighth, and 10 of the 47 shipped skills were
not first for their own command. The description is embedded alone too, and such a search
(``match_description``) scores each skill by the better of its two vectors: every shipped skill
is then first for its own command, and the query above still finds ``insert_peg_round`` first.
Source retrieval keeps the text alone, for the reasons above.

The query is embedded as given; stored skills are not re-embedded (their vectors are in the
database), except rows that have no vector or one from another model, which are filled in once.
A vector is stored only if the skill's text is still the one it was made from (see
:meth:`SkillSpace.set_embeddings`); the search itself ranks every skill as it read it.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import replace

import numpy as np

from itskill.skills import embeddings
from itskill.skills.store import Skill, SkillSpace, SkillSpaceError
from itskill.tasks import get_task


class EmptyQueryError(SkillSpaceError):
    """A blank search query: its embedding says nothing, so every skill would rank by chance."""


def skill_text(skill: Skill) -> str:
    """The text whose embedding represents ``skill`` in a search (see the module docstring)."""
    actions = list(dict.fromkeys(skill.actions))  # Ordered de-duplication.
    text = skill.description.strip().rstrip(".")
    return f"{text}. Actions: {', '.join(actions)}" if actions else text


def with_embeddings(skills: Sequence[Skill], needs: Callable[[Skill], bool]) -> list[Skill]:
    """``skills``, each one for which ``needs`` is true with the vectors of its
    :func:`skill_text` and of its description from the current model, the others as given."""
    todo = [i for i, s in enumerate(skills) if needs(s)]
    out = list(skills)
    if todo:
        # Two batches: a text's vector then comes out as it did before descriptions were
        # embedded too (batched with other texts, its last bits differ), so sources rank as then.
        texts = embeddings.embed([skill_text(skills[i]) for i in todo])
        described = embeddings.embed([skills[i].description for i in todo])
        for row, i in enumerate(todo):
            out[i] = replace(
                skills[i],
                embedding=texts[row],
                description_embedding=described[row],
                embedding_model=embeddings.MODEL_ID,
            )
    return out


def _lacks_current_vector(skill: Skill) -> bool:
    return (
        skill.embedding is None
        or skill.description_embedding is None
        or skill.embedding_model != embeddings.MODEL_ID
    )


def _ensure_embeddings(space: SkillSpace, skills: list[Skill]) -> list[Skill]:
    """Fill in vectors missing from old rows, or made by another model, and store them.

    The vectors are used for this search even where the store drops them because the skill's
    text changed meanwhile: each skill is ranked by the text it is returned with, as of the
    moment :func:`search` read the space, like every other field of the results. Re-reading
    would narrow that window, not close it, and would mix two reads of the space.
    """
    filled = with_embeddings(skills, _lacks_current_vector)
    fresh = [new for old, new in zip(skills, filled, strict=True) if _lacks_current_vector(old)]
    if fresh:  # Most searches have none, and need not take the write lock.
        space.set_embeddings(fresh)
    return filled


def check_search(query: str, exclude_tasks: Collection[str] = ()) -> None:
    """Raise :class:`EmptyQueryError` for a blank ``query`` and ``UnknownTaskError`` for a task
    id in ``exclude_tasks`` that no task has (a typo would exclude nothing, silently)."""
    if not query.strip():
        raise EmptyQueryError(
            'the query is empty: say what the robot should do, e.g. "Pick up the round peg"'
        )
    for task in exclude_tasks:
        get_task(task)


def search(
    space: SkillSpace,
    query: str,
    k: int = 5,
    exclude_tasks: Collection[str] = (),
    match_description: bool = False,
) -> list[tuple[Skill, float]]:
    """The ``k`` skills most similar to ``query``, best first, with their cosine similarity.

    ``exclude_tasks`` drops skills of these task ids, e.g. the target task itself when looking for
    transfer sources for it. ``match_description`` scores a skill by its description alone too,
    and keeps the better score (a user's look-up, see the module docstring). Ties are broken by
    serial number so the order is reproducible. Raises what :func:`check_search` raises for the
    query and the task ids.
    """
    check_search(query, exclude_tasks)
    if k <= 0:
        return []
    skills = [s for s in space.list() if s.task_id not in exclude_tasks]
    if not skills:
        return []
    skills = _ensure_embeddings(space, skills)
    matrix = np.stack([s.embedding for s in skills]).astype(np.float32)
    q = embeddings.embed([query])[0]
    scores = matrix @ q
    if match_description:
        described = np.stack([s.description_embedding for s in skills]).astype(np.float32)
        scores = np.maximum(scores, described @ q)
    # Stable sort on -score keeps id order among equal scores.
    order = np.argsort(-scores, kind="stable")[:k]
    return [(skills[i], float(scores[i])) for i in order]
