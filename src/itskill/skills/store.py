"""The skill space: every learned skill in one SQLite database.

A skill is a policy the robot has already learned, with what is needed to pick it as a transfer
source: a serial number, a unique name, the task command it solves (its description), the action
sequence it executes, the checkpoint of the trained policy, how well it does, what it cost to train,
and the sentence embedding of its text (stored, so a search embeds only the query).

Concurrency: the file is opened in WAL mode with a busy timeout and every write is one
``BEGIN IMMEDIATE`` transaction, so several training processes can add skills at the same time
without losing any (SQLite serialises the writers; readers are never blocked).

Schema changes are a list of migration steps; ``PRAGMA user_version`` records how many have been
applied. Opening a database applies the missing ones in a single transaction; a database written by
a newer itskill (a higher version than this code knows) is refused rather than misread.
"""

from __future__ import annotations

import difflib
import functools
import json
import os
import sqlite3
import time
import unicodedata
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Concatenate, Literal, ParamSpec, TypeVar

import numpy as np

from itskill.datafile import is_count, is_number
from itskill.errors import PicklableError

HOME_ENV = "ITSKILL_HOME"
EMBEDDING_DIM = 384
# The pretrained library inside the installed package. Its checkpoints are stored as
# ``package:<path inside it>``: an absolute path would tie a skill space to the checkout or
# virtualenv it was first opened from, and break when itskill is reinstalled elsewhere.
SHIPPED_LIBRARY = Path(__file__).resolve().parent / "library"
PACKAGE_PREFIX = "package:"
# Up to schema version 2 the shipped skills a space had been given were listed in a file beside
# the database (``skills.sqlite`` + this); the upgrade to version 3 reads it into the database.
OFFERED_MARKER_SUFFIX = ".shipped-library-installed"


@dataclass(frozen=True)
class SkillSpaceConfig:
    """Where the skill space lives and how it waits for other writers.

    ``home`` None means :func:`itskill_home` (``$ITSKILL_HOME`` or the user's data directory).
    """

    home: Path | None = None
    db_name: str = "skills.sqlite"
    # Checkpoints named by a relative path live here (the installed pretrained library).
    library_subdir: str = "library"
    # Long enough for another process to finish a batch insert (embedding happens before the
    # transaction, so writers hold the lock for milliseconds, not seconds).
    busy_timeout_s: float = 30.0


def is_serial_number(key: str) -> bool:
    """Whether ``key`` reads as a skill's serial number: ASCII digits only (``str.isdigit`` alone
    also takes "²" and "①", which ``int`` refuses)."""
    return key.isascii() and key.isdigit()


def itskill_home() -> Path:
    """The itskill data directory: ``$ITSKILL_HOME``, else ``$XDG_DATA_HOME/itskill``.

    ``XDG_DATA_HOME`` defaults to ``~/.local/share`` (the XDG base-directory rule, which is what
    platformdirs returns on Linux); deriving it here avoids a dependency for one path. Either
    variable set to the empty string counts as unset, as ``$OPENAI_BASE_URL`` does.
    """
    env = os.environ.get(HOME_ENV)
    if env:
        # Absolute, because a relative checkpoint path in the database means "inside the
        # library directory": a relative home would make every path under it relative too.
        return Path(env).expanduser().resolve()
    xdg = os.environ.get("XDG_DATA_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".local" / "share"
    return base.resolve() / "itskill"


# ---------------------------------------------------------------------------- errors
class SkillSpaceError(PicklableError, RuntimeError):
    """Any problem with the skill database that the user has to act on."""


class SchemaVersionError(SkillSpaceError):
    """The database was written by a newer itskill than this one."""


class MigrationError(SkillSpaceError):
    """A schema upgrade step failed; the transaction is rolled back, the file is unchanged."""


class CorruptDatabaseError(SkillSpaceError):
    """The file is not a readable SQLite skill database."""


class DuplicateSkillError(SkillSpaceError):
    """A skill with this name already exists (names are unique)."""

    def __init__(self, name: str) -> None:
        super().__init__(f"a skill named {name!r} already exists")
        self.name = name


class InvalidSkillNameError(SkillSpaceError):
    """A name that cannot be looked up as written: blank, with surrounding whitespace (which
    ``--sources`` strips), or all digits (a serial number)."""


class InvalidMeasurementError(SkillSpaceError, ValueError):
    """A measurement that no evaluation or training run gives: a rate or interval outside
    [0, 1], an interval whose low is above its high or that leaves out its rate, a budget that is
    negative or not finite. ``field`` is the :class:`Skill` field (``success`` for its
    ``success_rate``); ``problem`` says what is wrong with it."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"{field}: {problem}")
        self.field, self.problem = field, problem


class MissingCheckpointError(SkillSpaceError):
    """A skill whose policy checkpoint file does not exist: a skill must be learned to be added."""


class UnknownSkillError(SkillSpaceError, KeyError):
    """No skill has this id or name; the message lists close names."""

    def __init__(self, key: str | int, known: Sequence[str]) -> None:
        super().__init__(str(key))
        self.key = key
        self.close = difflib.get_close_matches(str(key), list(known), n=5, cutoff=0.4)

    def __str__(self) -> str:
        hint = f" Did you mean: {', '.join(self.close)}?" if self.close else ""
        return f"unknown skill {self.key!r}.{hint} (`itskill skills list` shows them all)"


_UNPRINTABLE = frozenset(
    "\u061c\u200e\u200f\u2028\u2029"
    + "".join(map(chr, range(0x202A, 0x202F)))
    + "".join(map(chr, range(0x2066, 0x206A)))
)
"""What moves the text a name is printed in, besides control characters: line and paragraph
separators, and the text-direction marks and overrides (not joiners, which some scripts and
emoji need)."""


def check_skill_name(name: str) -> None:
    """Raise :class:`InvalidSkillNameError` unless ``name`` can name a skill wherever a skill is
    named: not blank, no whitespace around it (a name in ``--sources`` is stripped, so " pick"
    could never be given there), not all digits (``get`` and ``remove`` would take it for a
    serial number), no comma (``--sources`` separates names with commas), no control character
    (a newline or a terminal escape in a name breaks every table and message it is printed in)."""
    if not name.strip():
        raise InvalidSkillNameError(f"skill name {name!r} is blank; give it a name with a letter")
    if name != name.strip():
        raise InvalidSkillNameError(
            f"skill name {name!r} has whitespace around it, which lookups by name do not "
            f"match; give it as {name.strip()!r}"
        )
    if is_serial_number(name):
        raise InvalidSkillNameError(
            f"skill name {name!r} is all digits, which reads as a serial number; "
            "give it a name with a letter"
        )
    if "," in name:
        raise InvalidSkillNameError(
            f"skill name {name!r} has a comma, which --sources reads as two names; "
            f"give it as {name.replace(',', '-')!r}"
        )
    if any(unicodedata.category(c) == "Cc" or c in _UNPRINTABLE for c in name):
        raise InvalidSkillNameError(
            f"skill name {name!r} has a control character (a newline, tab, terminal escape, line "
            "separator or text-direction mark), which breaks every table and message it is "
            "printed in; give it printable characters"
        )


def check_success(success: float | None, ci: tuple[float, float] | None) -> None:
    """Raise :class:`InvalidMeasurementError` unless ``success`` and each end of ``ci`` (either
    may be None: not measured) are rates in [0, 1], ``ci`` is ``(low, high)`` in that order and,
    where both are measured, ``success`` lies inside ``ci`` (an evaluation's interval is around
    its own rate)."""
    if success is not None and not 0 <= success <= 1:  # also refuses NaN
        raise InvalidMeasurementError("success", f"{success} is not a rate in [0, 1]")
    if ci is None:
        return
    low, high = ci
    if not (0 <= low <= 1 and 0 <= high <= 1):
        raise InvalidMeasurementError(
            "success_ci", f"[{low}, {high}] is not an interval of rates in [0, 1]"
        )
    if low > high:
        raise InvalidMeasurementError(
            "success_ci", f"low {low} is above high {high}; the interval is [low, high]"
        )
    if success is not None and not low <= success <= high:
        raise InvalidMeasurementError(
            "success", f"{success} is outside its own interval [{low}, {high}]"
        )


def check_budget(steps: int | None, wall_s: float | None) -> None:
    """Raise :class:`InvalidMeasurementError` unless ``steps`` is a whole number of 0 or more and
    ``wall_s`` a finite number of 0 or more (either may be None: not recorded): no run takes
    forever, and JSON has no infinity to list it with."""
    if steps is not None and not _is_stored_count(steps):
        raise InvalidMeasurementError(
            "train_steps",
            f"{steps!r} is not a whole number of env-steps from 0 to {SQLITE_INTEGER_MAX:,}",
        )
    if wall_s is not None and not (is_number(wall_s) and wall_s >= 0):
        raise InvalidMeasurementError(
            "train_wall_s", f"{wall_s!r} is not a finite number of seconds of 0 or more"
        )


def check_measurements(skill: Skill) -> None:
    """Raise :class:`InvalidMeasurementError` unless ``skill``'s success and training budget pass
    :func:`check_success` and :func:`check_budget`, and its algorithm is a name and its seed a
    whole number (either may be None: not recorded): what every write to the space checks."""
    check_success(skill.success_rate, skill.success_ci)
    check_budget(skill.train_steps, skill.train_wall_s)
    if skill.algo is not None and not isinstance(skill.algo, str):
        raise InvalidMeasurementError("algo", f"{skill.algo!r} is not an algorithm's name")
    if skill.seed is not None and not _is_stored_count(skill.seed):
        raise InvalidMeasurementError(
            "seed", f"{skill.seed!r} is not a whole number from 0 to {SQLITE_INTEGER_MAX:,}"
        )


def _is_stored_count(value: Any) -> bool:
    """Whether ``value`` is a whole number of 0 or more that fits an SQLite integer (past it,
    the insert fails with an OverflowError, not an error of the space's)."""
    return is_count(value) and value <= SQLITE_INTEGER_MAX


UPDATABLE_FIELDS = (
    "task_id",
    "description",
    "actions",
    "success_rate",
    "success_ci",
    "train_steps",
    "train_wall_s",
    "algo",
    "seed",
)
"""What :meth:`SkillSpace.update` may change; the name and checkpoint stay. The algorithm and
seed go with the measurements: a release that retrains a shipped skill changes all of them."""


# ---------------------------------------------------------------------------- the record
@dataclass(frozen=True)
class Skill:
    """One learned skill as stored.

    ``checkpoint`` is stored as given: an absolute path, a path relative to the space's library
    directory, or ``package:<path>`` inside the package's shipped library (see
    :meth:`SkillSpace.checkpoint_path` and :meth:`SkillSpace.checkpoint_ref`), so neither the
    space nor the package is tied to where it was first installed.
    ``embedding`` is the normalised vector of :func:`itskill.skills.retrieval.skill_text` and
    ``description_embedding`` that of the description alone, or None for a row that predates them
    (they are filled in by the first search).
    ``train_steps`` and ``train_wall_s`` are the budget as the skill's maker recorded it, in two
    senses: ``skills pretrain`` (so the shipped library) counts its whole run, every round of a
    refined skill included, though the policy it keeps is its best evaluation's, often earlier;
    ``skills add`` and ``itskill learn`` count up to the kept policy (what its run's
    ``checkpoint.json`` records). The same policy added both ways shows two budgets.
    """

    name: str
    task_id: str
    description: str
    actions: tuple[str, ...]
    checkpoint: str
    success_rate: float | None = None
    success_ci: tuple[float, float] | None = None
    train_steps: int | None = None
    train_wall_s: float | None = None
    algo: str | None = None
    seed: int | None = None
    id: int | None = None
    created: float | None = None  # Unix time
    embedding: np.ndarray | None = field(default=None, repr=False, compare=False)
    embedding_model: str | None = None
    description_embedding: np.ndarray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (without the embedding vector, which is data, not information)."""
        return {
            "id": self.id,
            "name": self.name,
            "task_id": self.task_id,
            "description": self.description,
            "actions": list(self.actions),
            "checkpoint": self.checkpoint,
            "success_rate": self.success_rate,
            "success_ci": list(self.success_ci) if self.success_ci else None,
            "train_steps": self.train_steps,
            "train_wall_s": self.train_wall_s,
            "algo": self.algo,
            "seed": self.seed,
            "created": self.created,
            "embedding_model": self.embedding_model,
        }


# ---------------------------------------------------------------------------- schema
# Each entry is one migration: the statements that take the schema from version i to i + 1.
# Never edit a released step; append a new one. Version 1 is the paper's four attributes plus the
# bookkeeping a first version needs; version 2 adds training metadata and stored embeddings;
# version 3 the names of the shipped skills the space was given
# (:meth:`SkillSpace.offered_shipped`), which were in a file beside the database before: a new
# database, wherever the old one went, is given the whole library; version 4 never reuses a
# serial number.
MIGRATIONS: list[list[str]] = [
    [
        """CREATE TABLE skills (
            id INTEGER PRIMARY KEY,
            name TEXT NOT NULL UNIQUE,
            task_id TEXT NOT NULL,
            description TEXT NOT NULL,
            actions TEXT NOT NULL,          -- JSON list of action names
            checkpoint TEXT NOT NULL,
            success_rate REAL,
            created REAL NOT NULL
        )""",
        "CREATE INDEX skills_task ON skills(task_id)",
    ],
    [
        "ALTER TABLE skills ADD COLUMN success_ci_low REAL",
        "ALTER TABLE skills ADD COLUMN success_ci_high REAL",
        "ALTER TABLE skills ADD COLUMN train_steps INTEGER",
        "ALTER TABLE skills ADD COLUMN train_wall_s REAL",
        "ALTER TABLE skills ADD COLUMN algo TEXT",
        "ALTER TABLE skills ADD COLUMN seed INTEGER",
        "ALTER TABLE skills ADD COLUMN embedding BLOB",  # float32, little-endian
        "ALTER TABLE skills ADD COLUMN embedding_model TEXT",
    ],
    ["CREATE TABLE shipped_offered (name TEXT PRIMARY KEY)"],
    [
        # AUTOINCREMENT: a serial number is never given out twice, so one recorded elsewhere
        # (`skill.json` of `itskill learn`, `--sources 3,5`, a note) cannot come to name another
        # skill after the highest was removed. SQLite adds it only by rebuilding the table.
        """CREATE TABLE skills_v4 (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            name TEXT NOT NULL UNIQUE,
            task_id TEXT NOT NULL,
            description TEXT NOT NULL,
            actions TEXT NOT NULL,
            checkpoint TEXT NOT NULL,
            success_rate REAL,
            created REAL NOT NULL,
            success_ci_low REAL,
            success_ci_high REAL,
            train_steps INTEGER,
            train_wall_s REAL,
            algo TEXT,
            seed INTEGER,
            embedding BLOB,
            embedding_model TEXT
        )""",
        "INSERT INTO skills_v4 SELECT id, name, task_id, description, actions, checkpoint, "
        "success_rate, created, success_ci_low, success_ci_high, train_steps, train_wall_s, algo, "
        "seed, embedding, embedding_model FROM skills",
        "DROP TABLE skills",
        "ALTER TABLE skills_v4 RENAME TO skills",
        "CREATE INDEX skills_task ON skills(task_id)",
    ],
    # The description's own vector: a user's search for a skill's command finds that skill
    # first (the text with its actions ranks a one-action neighbour above it).
    ["ALTER TABLE skills ADD COLUMN description_embedding BLOB"],
]
SCHEMA_VERSION = len(MIGRATIONS)
OFFERED_TABLE_VERSION = 3

_COLUMNS = (
    "id, name, task_id, description, actions, checkpoint, success_rate, success_ci_low, "
    "success_ci_high, train_steps, train_wall_s, algo, seed, created, embedding, embedding_model, "
    "description_embedding"
)


def _row_to_skill(row: sqlite3.Row) -> Skill:
    ci = None
    if row["success_ci_low"] is not None and row["success_ci_high"] is not None:
        ci = (row["success_ci_low"], row["success_ci_high"])

    def vector(blob: bytes | None) -> np.ndarray | None:
        # A vector of another size is damage: None has the next search embed the text again.
        if blob is None or len(blob) != 4 * EMBEDDING_DIM:
            return None
        return np.frombuffer(blob, dtype="<f4").copy()

    try:
        actions = json.loads(row["actions"])
        if not isinstance(actions, list) or not all(isinstance(a, str) for a in actions):
            raise ValueError(f"expected a list of action names, got {actions!r}")
    except ValueError as err:
        raise CorruptDatabaseError(
            f"skill {row['name']!r} (id {row['id']}): its actions cannot be read ({err}); "
            f"remove it (itskill skills remove {row['id']}) and add it again"
        ) from err

    return Skill(
        id=row["id"],
        name=row["name"],
        task_id=row["task_id"],
        description=row["description"],
        actions=tuple(actions),
        checkpoint=row["checkpoint"],
        success_rate=row["success_rate"],
        success_ci=ci,
        train_steps=row["train_steps"],
        train_wall_s=row["train_wall_s"],
        algo=row["algo"],
        seed=row["seed"],
        created=row["created"],
        embedding=vector(row["embedding"]),
        embedding_model=row["embedding_model"],
        description_embedding=vector(row["description_embedding"]),
    )


SQLITE_INTEGER_MAX = 2**63 - 1
"""SQLite's largest integer: ids are 64-bit, and binding a larger number raises OverflowError."""


def _sqlite_integer(serial: int | str) -> int | None:
    """``serial`` (an int, or a string of ASCII digits) as an int SQLite can hold, or None where
    it is beyond SQLite's 64-bit integers and so no skill's id. A string's length is checked
    first: ``int`` refuses more than 4,300 digits."""
    if isinstance(serial, str):
        digits = serial.lstrip("0") or "0"
        if len(digits) > len(str(SQLITE_INTEGER_MAX)):
            return None
        serial = int(digits)
    return serial if -SQLITE_INTEGER_MAX - 1 <= serial <= SQLITE_INTEGER_MAX else None


def _actions_json(actions: Sequence[str]) -> str:
    # One serialisation for every write: set_embeddings matches rows on this text.
    return json.dumps(list(actions))


def _blob(vec: np.ndarray | None) -> bytes | None:
    if vec is None:
        return None
    arr = np.asarray(vec, dtype="<f4").reshape(-1)
    if arr.shape[0] != EMBEDDING_DIM:
        raise ValueError(f"embedding must have {EMBEDDING_DIM} values, got {arr.shape[0]}")
    return arr.tobytes()


# ---------------------------------------------------------------------------- the database
P = ParamSpec("P")
R = TypeVar("R")


def _reporting_sqlite_errors(
    method: Callable[Concatenate[SkillSpace, P], R],
) -> Callable[Concatenate[SkillSpace, P], R]:
    """``method`` with SQLite's errors turned into a :class:`SkillSpaceError` naming the file: a
    database damaged below its header opens fine and fails only when a page is read."""

    @functools.wraps(method)
    def wrapper(self: SkillSpace, *args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return method(self, *args, **kwargs)
        except sqlite3.DatabaseError as err:
            raise self._sqlite_error(err) from err

    return wrapper


class SkillSpace:
    """The skill database at ``<home>/skills.sqlite``; opening it creates or upgrades it.

    Use as a context manager or call :meth:`close`. One instance per thread (sqlite3 connections
    are not shared across threads); separate processes may each open the same file.
    """

    def __init__(self, path: Path | str | None = None, config: SkillSpaceConfig | None = None):
        self.config = config or SkillSpaceConfig()
        home = self.config.home or itskill_home()
        self.path = Path(path) if path is not None else home / self.config.db_name
        self.library_dir = self.path.parent / self.config.library_subdir
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise SkillSpaceError(
                f"cannot use {self.path.parent} for the skill space ({err.strerror or err}); "
                f"point {HOME_ENV} at a writable directory"
            ) from err
        try:
            # isolation_level=None: no implicit transactions; every write below opens its own
            # BEGIN IMMEDIATE so that the write lock is taken up front, not upgraded mid-way
            # (an upgrade can fail with SQLITE_BUSY regardless of the busy timeout).
            self._conn = sqlite3.connect(
                self.path, timeout=self.config.busy_timeout_s, isolation_level=None
            )
            self._conn.row_factory = sqlite3.Row
            self._conn.execute(f"PRAGMA busy_timeout = {int(self.config.busy_timeout_s * 1000)}")
            self._open_retrying_while_busy()
        except sqlite3.DatabaseError as err:
            if hasattr(self, "_conn"):
                self._conn.close()
            raise self._sqlite_error(err) from err
        except SkillSpaceError:
            self._conn.close()
            raise

    def _sqlite_error(self, err: sqlite3.DatabaseError) -> SkillSpaceError:
        """``err`` as the user reads it. SQLite reports what keeps it from using a path (it cannot
        be opened or created, as a directory or a place without write access; the file is
        read-only, locked past the busy timeout, the disk full) as an OperationalError, which
        moving the file aside would not cure; anything else is damage to the file itself."""
        if isinstance(err, sqlite3.OperationalError) and "locked" in str(err):
            # Another process held it past the busy timeout: nothing is wrong with the path.
            return SkillSpaceError(
                f"{self.path} is in use by another process (the skill database stayed locked "
                f"for {self.config.busy_timeout_s:g} s); try again when that itskill command "
                "has finished"
            )
        if isinstance(err, sqlite3.OperationalError):
            return SkillSpaceError(
                f"cannot use {self.path} as the skill database ({err}); check the path, or point "
                f"{HOME_ENV} at a writable directory"
            )
        return CorruptDatabaseError(
            f"{self.path}: not a readable itskill skill database ({err}). Move it aside or "
            f"point {HOME_ENV} elsewhere."
        )

    def _open_retrying_while_busy(self) -> None:
        """Switch to WAL and migrate. Processes creating the file at the same moment can get
        "database is locked" at once (switching the journal mode does not wait on the busy
        timeout), so that error is retried until the timeout, not reported as corruption."""
        deadline = time.monotonic() + self.config.busy_timeout_s
        while True:
            try:
                self._conn.execute("PRAGMA journal_mode = WAL")
                self._migrate()
                return
            except sqlite3.OperationalError as err:
                busy = "locked" in str(err) or "busy" in str(err)
                if not busy or time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

    # -- lifecycle
    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> SkillSpace:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction: all of it lands or none of it does."""
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            yield self._conn
        except BaseException:
            # SQLite has rolled back itself after some errors (a full disk): a ROLLBACK then
            # fails and its error would hide the one that happened.
            if self._conn.in_transaction:
                self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")

    def _migrate(self) -> None:
        version = self.schema_version
        if version > SCHEMA_VERSION:
            raise SchemaVersionError(
                f"{self.path}: skill database schema version {version} is newer than this "
                f"itskill supports ({SCHEMA_VERSION}); upgrade itskill to open it."
            )
        if version == SCHEMA_VERSION:
            return
        with self._write() as conn:
            # Re-read under the write lock: another process may have migrated meanwhile.
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            for number, step in enumerate(MIGRATIONS[version:], start=version + 1):
                try:
                    for statement in step:
                        conn.execute(statement)
                except sqlite3.DatabaseError as err:
                    raise MigrationError(
                        f"{self.path}: upgrading the skill database to schema version {number} "
                        f"failed ({err}); the file is left at version {version}."
                    ) from err
            if 0 < version < OFFERED_TABLE_VERSION:
                self._adopt_offered_marker(conn)
            # user_version is part of the transaction: a failed step leaves the old version.
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    def _adopt_offered_marker(self, conn: sqlite3.Connection) -> None:
        """Record the shipped skills that the marker file of a database older than the
        ``shipped_offered`` table lists. The oldest markers held only the library's path; for
        those, the skills now in the space count as offered (one removed before the upgrade comes
        back once: such a marker cannot tell it from a skill a new release added).

        Only an upgrade reads the file: a new database beside a marker left from one moved aside
        or deleted gets the whole library. The file stays, so an old copy of the database put
        back is upgraded the same way.
        """
        marker = self.path.with_name(self.path.name + OFFERED_MARKER_SUFFIX)
        if not marker.exists():
            return
        try:
            names = json.loads(marker.read_text())
        except ValueError:  # not JSON: the library's path
            names = None
        except OSError as err:
            raise MigrationError(
                f"{self.path}: cannot read {marker} to upgrade the skill database "
                f"({err.strerror or err}); the file is left at its version."
            ) from err
        if isinstance(names, list) and all(isinstance(n, str) for n in names):
            conn.executemany(
                "INSERT OR IGNORE INTO shipped_offered (name) VALUES (?)", [(n,) for n in names]
            )
        else:
            conn.execute("INSERT OR IGNORE INTO shipped_offered (name) SELECT name FROM skills")

    @property
    def schema_version(self) -> int:
        return int(self._conn.execute("PRAGMA user_version").fetchone()[0])

    # -- paths
    def checkpoint_path(self, skill: Skill) -> Path:
        """The checkpoint file of ``skill``: ``package:`` paths are inside the shipped library,
        other relative paths inside the space's library directory."""
        if skill.checkpoint.startswith(PACKAGE_PREFIX):
            return SHIPPED_LIBRARY / skill.checkpoint[len(PACKAGE_PREFIX) :]
        p = Path(skill.checkpoint).expanduser()
        return p if p.is_absolute() else self.library_dir / p

    def checkpoint_ref(self, path: Path | str) -> str:
        """How the space stores the checkpoint file at ``path`` (the inverse of
        :meth:`checkpoint_path`): relative inside its library directory, ``package:`` inside the
        shipped library, absolute anywhere else."""
        path = Path(path).expanduser().resolve()
        for base, prefix in ((self.library_dir, ""), (SHIPPED_LIBRARY, PACKAGE_PREFIX)):
            base = base.expanduser().resolve()
            if path.is_relative_to(base):
                return prefix + path.relative_to(base).as_posix()
        return str(path)

    # -- writes
    def _require_checkpoint(self, skill: Skill) -> None:
        if not self.checkpoint_path(skill).is_file():
            raise MissingCheckpointError(
                f"skill {skill.name!r}: checkpoint {self.checkpoint_path(skill)} does not exist "
                "(only learned skills, with a trained policy, go into the skill space)"
            )

    def add(self, skill: Skill) -> Skill:
        """Add one skill (embedding it first if it has no embedding); returns it with its id."""
        return self.add_many([skill])[0]

    @_reporting_sqlite_errors
    def add_many(
        self, skills: Iterable[Skill], on_conflict: Literal["error", "skip", "replace"] = "error"
    ) -> list[Skill]:
        """Add several skills in one transaction (all or none); returns those added.

        Raises :class:`MissingCheckpointError` if a checkpoint file does not exist,
        :class:`InvalidSkillNameError` for a name :func:`check_skill_name` refuses,
        :class:`InvalidMeasurementError` for measurements :func:`check_measurements` refuses and,
        where a name is taken by the time the transaction runs (another process may have added it
        while this one was embedding), what ``on_conflict`` says: ``error`` raises
        :class:`DuplicateSkillError`, ``skip`` leaves the skill out, ``replace`` deletes the old
        skill in the same transaction, so there is no moment without one and two processes
        replacing the same skill leave the later one; the new record keeps the old one's serial
        number.
        """
        skills = list(skills)
        for s in skills:
            check_skill_name(s.name)
            check_measurements(s)
            self._require_checkpoint(s)
            # Before embedding, which takes seconds (the model loads first): a taken name is
            # known now. The check in the transaction still catches one taken meanwhile.
            if on_conflict == "error" and self._taken(self._conn, s.name):
                raise DuplicateSkillError(s.name)
        # Imported here: retrieval imports this module.
        from itskill.skills.retrieval import with_embeddings

        # Outside the transaction: the model is slow. A vector given with a skill is kept, even
        # another model's: the first search replaces that one.
        skills = with_embeddings(skills, lambda s: s.embedding is None)
        now = time.time()
        added: list[Skill] = []
        with self._write() as conn:
            for s in skills:
                taken = self._taken(conn, s.name)
                if taken and on_conflict == "skip":
                    continue
                serial = None  # a new one
                if taken and on_conflict == "replace":
                    # The skill keeps its serial number: `--sources 3`, a learn run's
                    # skill.json and notes that name it by number still mean it.
                    (serial,) = conn.execute(
                        "SELECT id FROM skills WHERE name = ?", (s.name,)
                    ).fetchone()
                    conn.execute("DELETE FROM skills WHERE name = ?", (s.name,))
                ci_low, ci_high = s.success_ci if s.success_ci else (None, None)
                created = s.created if s.created is not None else now
                try:
                    cur = conn.execute(
                        "INSERT INTO skills (id, name, task_id, description, actions, "
                        "checkpoint, success_rate, success_ci_low, success_ci_high, "
                        "train_steps, train_wall_s, algo, seed, created, embedding, "
                        "embedding_model, description_embedding) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (
                            serial,
                            s.name,
                            s.task_id,
                            s.description,
                            _actions_json(s.actions),
                            s.checkpoint,
                            s.success_rate,
                            ci_low,
                            ci_high,
                            s.train_steps,
                            s.train_wall_s,
                            s.algo,
                            s.seed,
                            created,
                            _blob(s.embedding),
                            s.embedding_model,
                            _blob(s.description_embedding),
                        ),
                    )
                except sqlite3.IntegrityError as err:
                    if "UNIQUE constraint failed: skills.name" in str(err):
                        raise DuplicateSkillError(s.name) from err
                    raise SkillSpaceError(f"skill {s.name!r} cannot be stored: {err}") from err
                added.append(replace(s, id=cur.lastrowid, created=created))
        return added

    @_reporting_sqlite_errors
    def __contains__(self, name: object) -> bool:
        """Whether a skill is named ``name``."""
        return isinstance(name, str) and self._taken(self._conn, name)

    @staticmethod
    def _taken(conn: sqlite3.Connection, name: str) -> bool:
        return conn.execute("SELECT 1 FROM skills WHERE name = ?", (name,)).fetchone() is not None

    @_reporting_sqlite_errors
    def set_embeddings(self, skills: Iterable[Skill]) -> None:
        """Store the ``embedding``, ``description_embedding`` and ``embedding_model`` of existing
        skills (to fill rows that have no vectors, or another model's), each only where the row
        still has the skill's description and actions.

        Embedding takes seconds, and another process may change the text meanwhile (which clears
        the row's vector, see :meth:`update`): the vector of the old text, stored under the
        current model, would never be replaced, so it is dropped and the next search embeds the
        new text. An id is reused only by a retraining of the same skill (``add_many`` with
        ``replace``), and a row is matched on its description and actions too, so a row removed
        meanwhile cannot take another skill's vector.
        """
        with self._write() as conn:
            conn.executemany(
                "UPDATE skills SET embedding = ?, embedding_model = ?, description_embedding = ? "
                "WHERE id = ? AND description = ? AND actions = ?",
                [
                    (
                        _blob(s.embedding),
                        s.embedding_model,
                        _blob(s.description_embedding),
                        s.id,
                        s.description,
                        _actions_json(s.actions),
                    )
                    for s in skills
                ],
            )

    @_reporting_sqlite_errors
    def offered_shipped(self) -> set[str]:
        """Names of the shipped skills this space was given once (:func:`itskill.skills.library.
        open_skill_space` does not give them again, so a skill the user removed stays removed)."""
        return {row[0] for row in self._conn.execute("SELECT name FROM shipped_offered")}

    @_reporting_sqlite_errors
    def record_offered_shipped(self, names: Iterable[str]) -> None:
        """Add ``names`` to :meth:`offered_shipped`."""
        with self._write() as conn:
            conn.executemany(
                "INSERT OR IGNORE INTO shipped_offered (name) VALUES (?)", [(n,) for n in names]
            )

    @_reporting_sqlite_errors
    def remove(self, key: int | str) -> Skill:
        """Delete a skill by id or name; returns what was deleted. The checkpoint file stays.
        A row damaged past reading is removed too (what a :class:`CorruptDatabaseError` about
        it advises), returned without its actions."""
        with self._write() as conn:
            row = self._get_row(conn, key)
            conn.execute("DELETE FROM skills WHERE id = ?", (row["id"],))
        try:
            return _row_to_skill(row)
        except CorruptDatabaseError:
            return Skill(
                row["name"], row["task_id"], row["description"], (), row["checkpoint"],
                id=row["id"],
            )  # fmt: skip

    @_reporting_sqlite_errors
    def set_checkpoint(self, key: int | str, checkpoint: str) -> Skill:
        """Point a skill at another checkpoint (stored as given; the file must exist)."""
        with self._write() as conn:
            skill = replace(self._get(conn, key), checkpoint=checkpoint)
            self._require_checkpoint(skill)
            conn.execute("UPDATE skills SET checkpoint = ? WHERE id = ?", (checkpoint, skill.id))
        return skill

    @_reporting_sqlite_errors
    def update(self, key: int | str, **changes: Any) -> Skill:
        """Replace the given fields of a skill: ``task_id``, ``description``, ``actions`` or its
        measurements and their training (``success_rate``, ``success_ci``, ``train_steps``,
        ``train_wall_s``, ``algo``, ``seed``).

        A new description or action sequence clears the stored embedding, so the next search
        embeds the new text instead of retrieving the skill by the old one. Measurements that
        :func:`check_measurements` refuses raise :class:`InvalidMeasurementError`; an unknown
        field, or None for the task, description or actions, ``TypeError``.
        """
        unknown = set(changes) - set(UPDATABLE_FIELDS)
        if unknown:
            raise TypeError(f"cannot update {sorted(unknown)}; fields: {list(UPDATABLE_FIELDS)}")
        required = [f for f in ("task_id", "description", "actions") if f in changes]
        for name in required:
            if changes[name] is None:
                # The database refuses it too, in words that blame the file.
                raise TypeError(f"a skill's {name} cannot be None")
        if changes.get("actions") is not None:
            changes["actions"] = tuple(changes["actions"])
        if changes.get("success_ci") is not None:
            changes["success_ci"] = tuple(changes["success_ci"])
        with self._write() as conn:
            skill = self._get(conn, key)
            new = replace(skill, **changes)
            check_measurements(new)
            if (new.description, new.actions) != (skill.description, skill.actions):
                new = replace(new, embedding=None, embedding_model=None, description_embedding=None)
            ci_low, ci_high = new.success_ci if new.success_ci else (None, None)
            conn.execute(
                "UPDATE skills SET task_id = ?, description = ?, actions = ?, success_rate = ?, "
                "success_ci_low = ?, success_ci_high = ?, train_steps = ?, train_wall_s = ?, "
                "algo = ?, seed = ?, embedding = ?, embedding_model = ?, description_embedding = ? "
                "WHERE id = ?",
                (
                    new.task_id,
                    new.description,
                    _actions_json(new.actions),
                    new.success_rate,
                    ci_low,
                    ci_high,
                    new.train_steps,
                    new.train_wall_s,
                    new.algo,
                    new.seed,
                    _blob(new.embedding),
                    new.embedding_model,
                    _blob(new.description_embedding),
                    skill.id,
                ),
            )
        return new

    # -- reads
    @_reporting_sqlite_errors
    def get(self, key: int | str) -> Skill:
        """A skill by id (an int, or a string of digits) or by name."""
        return self._get(self._conn, key)

    def _get(self, conn: sqlite3.Connection, key: int | str) -> Skill:
        return _row_to_skill(self._get_row(conn, key))

    @staticmethod
    def _get_row(conn: sqlite3.Connection, key: int | str) -> sqlite3.Row:
        value: int | str | None
        if isinstance(key, int) or is_serial_number(key):
            column, value = "id", _sqlite_integer(key)
        else:
            column, value = "name", key
        found = None
        if value is not None:  # None: a number past SQLite's integers, which no skill has
            query = f"SELECT {_COLUMNS} FROM skills WHERE {column} = ?"
            found = conn.execute(query, (value,)).fetchone()
        if found is None:
            names = [r[0] for r in conn.execute("SELECT name FROM skills ORDER BY id")]
            raise UnknownSkillError(key, names)
        return found

    @_reporting_sqlite_errors
    def list(self, task_id: str | None = None) -> list[Skill]:
        """Every skill (or every skill for ``task_id``), by serial number."""
        if task_id is None:
            rows = self._conn.execute(f"SELECT {_COLUMNS} FROM skills ORDER BY id")
        else:
            rows = self._conn.execute(
                f"SELECT {_COLUMNS} FROM skills WHERE task_id = ? ORDER BY id", (task_id,)
            )
        return [_row_to_skill(r) for r in rows]

    @_reporting_sqlite_errors
    def __len__(self) -> int:
        return int(self._conn.execute("SELECT COUNT(*) FROM skills").fetchone()[0])
