"""The pretrained skill library shipped inside the package, and opening a skill space with it.

``itskill skills pretrain --library src/itskill/skills/library`` writes the shipped library: each
skill's policy weights and normaliser (``policy.safetensors``, no optimiser state) with its
``checkpoint.json``, and a ``manifest.json`` with each skill's measured success and budget.
:func:`open_skill_space` registers each shipped skill in the skill space once (the database records
which it was given): a fresh install, or a new database, has the skills without training, an
upgrade that ships new skills adds those, and a user who removes a skill does not get it back.
A shipped skill's entry points at the package's own checkpoint (``package:<path>``, wherever the
package is installed), so when a release retrains one, its measured success and budget are updated
with it.
"""

from __future__ import annotations

import warnings
from pathlib import Path

from itskill.skills import store
from itskill.skills.manifest import (
    MANIFEST_NAME,
    REFINED_KEY,
    ManifestEntry,
    ManifestError,
    install_library,
    read_manifest,
    read_manifest_or_empty,
)
from itskill.skills.store import UPDATABLE_FIELDS, Skill, SkillSpace, SkillSpaceConfig


class ShippedLibraryWarning(UserWarning):
    """The package's skill library is damaged: the skill space opened without its upkeep."""


_DAMAGE_SHOWN: set[str] = set()
"""The shipped library's problems this process has warned of."""


def open_skill_space(
    path: Path | str | None = None, config: SkillSpaceConfig | None = None
) -> SkillSpace:
    """Open the skill space, registering the shipped skills it has not been offered yet.

    A damaged shipped library (its manifest unreadable, or the checkpoint of a shipped skill not
    yet registered gone) gives a :class:`ShippedLibraryWarning` and the space as it is: the
    user's own skills, and those registered before, stay usable while the installation is
    mended. (A registered skill whose checkpoint is gone fails where it is used, naming it.)
    """
    space = SkillSpace(path, config)
    try:
        library = store.SHIPPED_LIBRARY  # looked up per call: tests point it elsewhere
        if (library / MANIFEST_NAME).is_file() and (stored := _stored(space)) is not None:
            try:
                entries = read_manifest(library)
                _repoint_to_package(space, library, entries, stored)
                new = {e.name for e in entries} - space.offered_shipped()
                if new:
                    # The package's own policies are checked by its tests (every shipped
                    # skill loads and acts), not again at a first open, where it would cost
                    # 8 CPU-seconds.
                    install_library(space, library, only=new, check=False)
                    space.record_offered_shipped(new)
                _refresh_shipped(space, library, entries)
            except ManifestError as err:
                # Once per process and problem: a command opens the space from several places,
                # and Python's own once-per-line rule is reset by any catch_warnings.
                if str(err) not in _DAMAGE_SHOWN:
                    _DAMAGE_SHOWN.add(str(err))
                    warnings.warn(
                        f"the shipped skill library is damaged ({err}); its skills are left as "
                        "they are in the skill space: reinstall itskill to mend it",
                        ShippedLibraryWarning,
                        stacklevel=2,
                    )
    except BaseException:
        space.close()  # the caller gets no space to close
        raise
    return space


def _stored(space: SkillSpace) -> list[Skill] | None:
    """Every skill of ``space``; None if a row is damaged past reading. Such a row is named, with
    how to remove it, by the command's own read; the shipped library's upkeep, which reads every
    row, waits until it is gone (it failed every command, ``skills remove`` included)."""
    try:
        return space.list()
    except store.CorruptDatabaseError:
        return None


def shipped_budgets() -> dict[str, int]:
    """Env-steps each task's shipped skill was trained for before its last refinement (all of
    its training for a skill never refined), from the library's manifest: the budgets with which
    ``itskill skills pretrain`` rebuilds the library. A refined
    skill's is that of the policy its last refinement started from (``refined_from``: the first
    round's for a skill refined once); ``--refine`` then adds the last round."""
    entries = read_manifest_or_empty(store.SHIPPED_LIBRARY)
    budgets = {}
    for e in entries:
        steps = e.extra.get(REFINED_KEY, {}).get("steps", e.steps)
        if steps is not None:
            budgets[e.task] = int(steps)
    return budgets


def _repoint_to_package(
    space: SkillSpace, library: Path, entries: list[ManifestEntry], skills: list[Skill]
) -> None:
    """Point shipped skills recorded by the absolute path of some itskill install (releases
    before ``package:`` paths) at this package's copy, so a reinstall elsewhere keeps them.
    ``skills`` are the space's, as read at its opening."""
    stored = {s.name: s for s in skills}
    for entry in entries:
        skill = stored.get(entry.name)
        if skill is None or not Path(skill.checkpoint).is_absolute():
            continue
        tail = ("itskill", "skills", "library", *Path(entry.checkpoint).parts)
        # Not to a copy this install lacks (a damaged one): the space must still open.
        if (
            Path(skill.checkpoint).parts[-len(tail) :] == tail
            and (library / entry.checkpoint).is_file()
        ):
            space.set_checkpoint(skill.name, space.checkpoint_ref(library / entry.checkpoint))


def _refresh_shipped(space: SkillSpace, library: Path, entries: list[ManifestEntry]) -> None:
    """Give each space entry that uses a shipped checkpoint what this release's manifest says of
    it: its measurements, and its description and actions where a release changed them (which
    retrieval and the choice of transfer sources read)."""
    stored = {s.name: s for s in space.list()}
    for entry in entries:
        skill = stored.get(entry.name)
        if skill is None:
            continue
        if skill.checkpoint != space.checkpoint_ref(library / entry.checkpoint):
            continue  # the user's own skill under a shipped name, or a copy elsewhere
        shipped = entry.to_skill(skill.checkpoint)
        changes = {
            name: getattr(shipped, name)
            for name in UPDATABLE_FIELDS
            if getattr(shipped, name) != getattr(skill, name)
        }
        if changes:
            space.update(skill.name, **changes)
