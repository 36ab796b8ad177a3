"""The pretrained skill library shipped inside the package, and opening a skill space with it.

``itskill skills pretrain --library src/itskill/skills/library`` writes the shipped library: each
skill's policy weights and normaliser (``policy.safetensors``, no optimiser state) with its
``checkpoint.json``, and a ``manifest.json`` with each skill's measured success and budget.
:func:`open_skill_space` registers it in a new skill space once, so a fresh install has the
skills without training; a user who later removes some does not get them back.
"""

from __future__ import annotations

from pathlib import Path

from itskill.skills.manifest import MANIFEST_NAME, install_library
from itskill.skills.store import SkillSpace, SkillSpaceConfig

SHIPPED_LIBRARY = Path(__file__).resolve().parent / "library"


def open_skill_space(
    path: Path | str | None = None, config: SkillSpaceConfig | None = None
) -> SkillSpace:
    """Open the skill space; the first time, register the shipped library in it."""
    space = SkillSpace(path, config)
    marker = space.path.with_name(space.path.name + ".shipped-library-installed")
    if not marker.exists() and (SHIPPED_LIBRARY / MANIFEST_NAME).is_file():
        install_library(space, SHIPPED_LIBRARY)
        marker.write_text(str(SHIPPED_LIBRARY) + "\n")
    return space
