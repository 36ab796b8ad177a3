"""The skill space: learned skills in SQLite, sentence embeddings, retrieval, shipped libraries.

The embedding model loads on the first embedding only. Importing the package loads the
simulator and PyTorch (through the task suite, which checks a skill's task): about 3 s.
"""

from __future__ import annotations

from itskill.skills.library import open_skill_space
from itskill.skills.manifest import (
    ManifestEntry,
    ManifestError,
    install_library,
    read_manifest,
    update_manifest,
    write_manifest,
)
from itskill.skills.retrieval import search, skill_text
from itskill.skills.store import (
    SHIPPED_LIBRARY,
    CorruptDatabaseError,
    DuplicateSkillError,
    MigrationError,
    MissingCheckpointError,
    SchemaVersionError,
    Skill,
    SkillSpace,
    SkillSpaceConfig,
    SkillSpaceError,
    UnknownSkillError,
    itskill_home,
)

__all__ = [
    "SHIPPED_LIBRARY",
    "CorruptDatabaseError",
    "DuplicateSkillError",
    "ManifestEntry",
    "ManifestError",
    "MigrationError",
    "MissingCheckpointError",
    "SchemaVersionError",
    "Skill",
    "SkillSpace",
    "SkillSpaceConfig",
    "SkillSpaceError",
    "UnknownSkillError",
    "install_library",
    "itskill_home",
    "open_skill_space",
    "read_manifest",
    "search",
    "skill_text",
    "update_manifest",
    "write_manifest",
]
