"""A skill library on disk: policy checkpoints plus a ``manifest.json`` that describes them.

This is how pretrained skills are shipped and shared. The manifest lists each skill with its task,
command, action sequence, checkpoint file (relative to the library directory, so the directory can
be moved or packaged), measured success and training budget. :func:`install_library` registers the
entries in a :class:`SkillSpace`; only entries whose checkpoint exists are accepted, because a
skill without a trained policy is not a skill.

Format (``format`` is bumped on incompatible changes)::

    {"format": 1, "skills": [{"name": "pick_nut_m12", "task": "pick_nut_m12",
      "description": "Pick up the M12 nut", "actions": ["approach", "grasp", "lift"],
      "checkpoint": "pick_nut_m12.zip", "success": 0.97, "success_ci": [0.92, 0.99],
      "budget": {"steps": 200000, "wall_s": 900.0}, "algo": "ppo", "seed": 0}]}
"""

from __future__ import annotations

import json
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from itskill.datafile import NotUTF8Error, is_count, is_number, utf8_text
from itskill.files import directory_lock, write_text
from itskill.skills.admission import InadmissibleSkillError, check_admissible
from itskill.skills.store import (
    SQLITE_INTEGER_MAX,
    InvalidMeasurementError,
    InvalidSkillNameError,
    Skill,
    SkillSpace,
    SkillSpaceError,
    check_skill_name,
    check_success,
)
from itskill.tasks import UnknownTaskError

MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = 1


REFINED_KEY = "refined_from"
"""Entry field of a skill trained on from an earlier one (``itskill skills pretrain --refine``):
that skill's env-steps and wall seconds (counting any round before it), seed and held-out
success, the env-steps the critic warm-up took and, since the paired test, the held-out episodes
each won and the test's p-value. The entry's own budget counts both rounds."""


class ManifestError(SkillSpaceError):
    """A manifest that cannot be read, or that names checkpoints that are not there."""


@dataclass(frozen=True)
class ManifestEntry:
    """One skill of a library. ``checkpoint`` is relative to the library directory."""

    name: str
    task: str
    description: str
    actions: tuple[str, ...]
    checkpoint: str
    success: float | None = None
    success_ci: tuple[float, float] | None = None
    steps: int | None = None
    wall_s: float | None = None
    algo: str | None = None
    seed: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)  # Unknown keys, kept on rewrite.

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "task": self.task,
            "description": self.description,
            "actions": list(self.actions),
            "checkpoint": self.checkpoint,
            "success": self.success,
            "success_ci": list(self.success_ci) if self.success_ci else None,
            "budget": {"steps": self.steps, "wall_s": self.wall_s},
            "algo": self.algo,
            "seed": self.seed,
            **self.extra,
        }

    @classmethod
    def from_json(cls, data: Any, where: str) -> ManifestEntry:
        """The entry ``data`` (an item of the manifest's ``skills``, found at ``where``), every
        field checked as the skill space checks a skill it is given: a :class:`ManifestError`
        names the place, the skill and the field."""
        if not isinstance(data, dict):
            raise ManifestError(f"{where}: bad skill entry (expected an object, got {data!r})")
        name = _string(data, "name", where)
        try:
            check_skill_name(name)
        except InvalidSkillNameError as err:
            raise ManifestError(f"{where}: name: {err}") from err
        where = f"{where} (skill {name!r})"
        actions = _required(data, "actions", where)
        if not isinstance(actions, list) or not actions:
            raise ManifestError(
                f"{where}: actions: a skill needs at least one action; expected a list of "
                f"action names, got {actions!r}"
            )
        if not all(isinstance(a, str) for a in actions):
            raise ManifestError(f"{where}: actions: expected action names, got {actions!r}")
        success = _number(data.get("success"), "success", where)
        ci = data.get("success_ci")
        if ci is not None:
            if not isinstance(ci, list) or len(ci) != 2:
                raise ManifestError(f"{where}: success_ci: expected [low, high], got {ci!r}")
            ci = (_number(ci[0], "success_ci", where), _number(ci[1], "success_ci", where))
        try:
            check_success(success, ci)
        except InvalidMeasurementError as err:
            raise ManifestError(f"{where}: {err}") from err
        budget = data.get("budget")
        if budget is None:
            budget = {}
        if not isinstance(budget, dict):
            raise ManifestError(
                f"{where}: budget: expected an object with steps and wall_s, got {budget!r}"
            )
        algo = data.get("algo")
        if algo is not None and not isinstance(algo, str):
            raise ManifestError(f"{where}: algo: expected a string, got {algo!r}")
        known = {"name", "task", "description", "actions", "checkpoint", "success"}
        known |= {"success_ci", "budget", "algo", "seed"}
        return cls(
            name=name,
            task=_string(data, "task", where),
            description=_string(data, "description", where),
            actions=tuple(actions),
            checkpoint=_string(data, "checkpoint", where),
            success=success,
            success_ci=ci,
            steps=_count(budget.get("steps"), "budget.steps", where),
            wall_s=_number(budget.get("wall_s"), "budget.wall_s", where, minimum=0.0),
            algo=algo,
            seed=_count(data.get("seed"), "seed", where),
            extra={k: v for k, v in data.items() if k not in known},
        )

    def to_skill(self, checkpoint: str) -> Skill:
        return Skill(
            name=self.name,
            task_id=self.task,
            description=self.description,
            actions=self.actions,
            checkpoint=checkpoint,
            success_rate=self.success,
            success_ci=self.success_ci,
            train_steps=self.steps,
            train_wall_s=self.wall_s,
            algo=self.algo,
            seed=self.seed,
        )


def _required(data: dict[str, Any], key: str, where: str) -> Any:
    if key not in data:
        raise ManifestError(f"{where}: {key}: missing")
    return data[key]


def _string(data: dict[str, Any], key: str, where: str) -> str:
    value = _required(data, key, where)
    if not isinstance(value, str):
        raise ManifestError(f"{where}: {key}: expected a string, got {value!r}")
    return value


def _number(value: Any, key: str, where: str, minimum: float = -math.inf) -> float | None:
    """``value`` as a float, None where it is not recorded. Strings and booleans are refused,
    and so are NaN and Infinity, which Python's JSON reader takes."""
    if value is None:
        return None
    if not is_number(value) or value < minimum:
        at_least = "" if minimum == -math.inf else f" of at least {minimum:g}"
        raise ManifestError(f"{where}: {key}: expected a finite number{at_least}, got {value!r}")
    return float(value)


def _count(value: Any, key: str, where: str) -> int | None:
    """``value`` as a whole number of at least 0 (None: not recorded)."""
    if value is None:
        return None
    if not is_count(value) or value > SQLITE_INTEGER_MAX:
        # Larger than SQLite's integers, it passed here and failed with an OverflowError
        # traceback when the skill was installed.
        raise ManifestError(
            f"{where}: {key}: expected a whole number from 0 to {SQLITE_INTEGER_MAX:,}, "
            f"got {value!r}"
        )
    return value


def read_manifest(library_dir: Path | str) -> list[ManifestEntry]:
    """The entries of ``<library_dir>/manifest.json``."""
    path = Path(library_dir) / MANIFEST_NAME
    try:
        data = json.loads(utf8_text(path.read_bytes()))
    except FileNotFoundError as err:
        if not Path(library_dir).is_dir():
            raise ManifestError(f"{library_dir}: no such directory") from err
        raise ManifestError(f"{path}: no manifest (not a skill library directory)") from err
    except OSError as err:
        raise ManifestError(f"{path}: cannot be read: {err.strerror or err}") from err
    except NotUTF8Error as err:
        raise ManifestError(f"{path}: {err}") from err
    except json.JSONDecodeError as err:
        raise ManifestError(f"{path}: not valid JSON ({err})") from err
    if not isinstance(data, dict) or not isinstance(data.get("skills"), list):
        raise ManifestError(f"{path}: expected an object with a 'skills' list")
    fmt = data.get("format", MANIFEST_FORMAT)
    if not isinstance(fmt, int) or isinstance(fmt, bool):
        raise ManifestError(f"{path}: 'format' must be a whole number, got {fmt!r}")
    if fmt > MANIFEST_FORMAT:
        raise ManifestError(
            f"{path}: manifest format {data['format']} is newer than this itskill supports "
            f"({MANIFEST_FORMAT})"
        )
    entries = [
        ManifestEntry.from_json(e, f"{path}: skills[{i}]") for i, e in enumerate(data["skills"])
    ]
    first: dict[str, int] = {}
    for i, entry in enumerate(entries):
        # An install kept the first and dropped the other without a word.
        if entry.name in first:
            raise ManifestError(
                f"{path}: skills[{i}]: name {entry.name!r} is taken by skills[{first[entry.name]}]"
            )
        first[entry.name] = i
    return entries


def read_manifest_or_empty(library_dir: Path | str) -> list[ManifestEntry]:
    """The library's manifest entries; none for a library not yet written."""
    return read_manifest(library_dir) if (Path(library_dir) / MANIFEST_NAME).is_file() else []


def write_manifest(library_dir: Path | str, entries: Sequence[ManifestEntry]) -> Path:
    """Write ``<library_dir>/manifest.json`` atomically (a reader never sees half a file)."""
    library_dir = Path(library_dir)
    library_dir.mkdir(parents=True, exist_ok=True)
    path = library_dir / MANIFEST_NAME
    text = json.dumps(
        {"format": MANIFEST_FORMAT, "skills": [e.to_json() for e in entries]}, indent=2
    )
    write_text(path, text + "\n")
    return path


def update_manifest(library_dir: Path | str, entry: ManifestEntry) -> Path:
    """Put ``entry`` in ``<library_dir>/manifest.json``, replacing an entry of the same name.

    The read and the write happen under a lock on the library, so two processes recording skills
    into one library at once (two ``itskill skills pretrain`` commands) keep each other's
    entries."""
    library_dir = Path(library_dir)
    with directory_lock(library_dir, "manifest"):
        entries = [e for e in read_manifest_or_empty(library_dir) if e.name != entry.name]
        return write_manifest(library_dir, [*entries, entry])


def install_library(
    space: SkillSpace,
    library_dir: Path | str,
    only: Collection[str] | None = None,
    check: bool = True,
) -> list[Skill]:
    """Register the manifest entries of ``library_dir`` in ``space`` (those named in ``only``, if
    given); returns the added skills.

    Every checkpoint must exist, or nothing is installed and the error names each missing file.
    With ``check``, every entry to add must also pass
    :func:`~itskill.skills.admission.check_admissible` (its task known, its checkpoint a policy
    of that task, an action named), or nothing is installed and the error names the entry.
    Entries whose name is already in the space are skipped (so installing twice, or from two
    processes opening a new space at once, is harmless). Checkpoints are
    stored as :meth:`SkillSpace.checkpoint_ref` says: relative inside the space's own library
    directory or the package's shipped library (each relocatable), absolute otherwise.
    """
    library_dir = Path(library_dir).expanduser().resolve()
    entries = [e for e in read_manifest(library_dir) if only is None or e.name in only]
    missing = [str(library_dir / e.checkpoint) for e in entries]
    missing = [m for m in missing if not Path(m).is_file()]
    if missing:
        raise ManifestError(
            f"{library_dir / MANIFEST_NAME}: {len(missing)} checkpoint file(s) missing: "
            + ", ".join(missing)
        )
    existing = {s.name for s in space.list()}
    entries = [e for e in entries if e.name not in existing]
    for e in entries if check else ():
        try:
            check_admissible(e.task, library_dir / e.checkpoint, e.actions)
        except (InadmissibleSkillError, UnknownTaskError) as err:
            raise ManifestError(f"{library_dir / MANIFEST_NAME}: skill {e.name!r}: {err}") from err
    todo = [e.to_skill(space.checkpoint_ref(library_dir / e.checkpoint)) for e in entries]
    return space.add_many(todo, on_conflict="skip")
