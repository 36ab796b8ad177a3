"""Atomic writes for run directories, caches and libraries: a file is either absent or complete.

A run killed at any moment (kill -9 included) leaves no half-written file behind, so a resumed run
can trust every file it finds: a ``result.json`` that exists is a finished candidate, a
``checkpoint.json`` a finished checkpoint.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from filelock import FileLock, Timeout

from itskill.datafile import NotUTF8Error, is_count, is_number, utf8_text
from itskill.errors import PicklableError


@contextmanager
def replaced_whole(path: Path, keep_suffix: bool = False) -> Iterator[Path]:
    """A temporary path beside ``path`` to write the new file to: when the block ends it replaces
    ``path`` in one ``os.replace``; if the block fails (a full disk, Ctrl-C) it is removed and
    ``path`` is left as it was. ``keep_suffix`` ends the temporary name with ``path``'s suffix,
    for writers that choose the format by it (a video's encoder)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if keep_suffix else ""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp{suffix}")  # see is_partial_write
    try:
        yield tmp
        try:
            os.replace(tmp, path)
        except OSError as err:
            # The error names the temporary file first; the path the caller asked for is the
            # one to tell the user about (a folder standing where the file goes, say).
            raise type(err)(err.errno, err.strerror, str(path)) from err
    finally:
        tmp.unlink(missing_ok=True)


def copy_whole(source: Path, path: Path) -> None:
    """Copy the file ``source`` to ``path`` whole (:func:`replaced_whole`): a copy cut short
    leaves ``path`` as it was, never truncated."""
    with replaced_whole(path) as tmp:
        shutil.copyfile(source, tmp)


def write_text(path: Path, text: str, errors: str = "strict") -> None:
    """Write ``text`` to ``path`` whole (:func:`replaced_whole`), synced to disk first, in UTF-8
    (``errors`` as :func:`open` takes it: ``surrogateescape`` writes back bytes read with it)."""
    with replaced_whole(path) as tmp, open(tmp, "w", encoding="utf-8", errors=errors) as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON, atomically; non-finite floats become ``null``."""
    write_text(path, json.dumps(json_safe(data), indent=2) + "\n")


class CorruptFileError(PicklableError, ValueError):
    """A run's or library's file that exists but cannot be read back (edited or damaged): names
    the file and the problem."""

    def __init__(self, path: str | Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem


UNUSABLE_PATH_ERRORS: tuple[type[OSError], ...] = (
    FileExistsError,
    FileNotFoundError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)
"""What a user-given path that cannot be written or read raises (a file where a directory should
be, a directory that cannot be created, no permission, ...). With :data:`UNUSABLE_PATH_ERRNOS`,
what :func:`is_unusable_path` takes for the path's fault."""

UNUSABLE_PATH_ERRNOS = frozenset({errno.ENAMETOOLONG, errno.ELOOP, errno.EROFS})
"""The path's faults that Python raises as a plain OSError, told apart only by ``errno``: a name
too long, a loop of symbolic links, a read-only file system."""


def is_unusable_path(err: OSError) -> bool:
    """Whether ``err`` is the fault of the path it names, which the commands report as one line
    (:func:`path_error_message`) rather than as a traceback."""
    return isinstance(err, UNUSABLE_PATH_ERRORS) or err.errno in UNUSABLE_PATH_ERRNOS


def decode_utf8(data: bytes, path: str | Path) -> str:
    """``data``, read from ``path``, as text; :class:`CorruptFileError` naming the file and the
    first bad byte if it is not UTF-8 (an editor's byte-order mark is not text)."""
    try:
        return utf8_text(data)
    except NotUTF8Error as err:
        raise CorruptFileError(path, str(err)) from err


def read_utf8(path: str | Path) -> str:
    """The text in ``path``: :func:`decode_utf8` of its bytes."""
    return decode_utf8(Path(path).read_bytes(), path)


def read_json(path: Path) -> Any:
    """The JSON in ``path``; :class:`CorruptFileError` naming the file if it is not valid JSON."""
    try:
        return json.loads(read_utf8(path))
    except json.JSONDecodeError as err:
        raise CorruptFileError(path, f"not valid JSON ({err})") from err


def read_json_or_none(path: Path) -> Any:
    """The JSON in ``path``, or None if there is no such file or it cannot be read back: for
    records a caller redoes or leaves out when they are missing or damaged."""
    if not Path(path).is_file():
        return None
    try:
        return read_json(path)
    except CorruptFileError:
        return None


@dataclass(frozen=True)
class Check:
    """A value a JSON field must hold: ``what`` it is, in words for the error, and the
    ``test`` of it (a shape of :func:`check_shape` that a type cannot say)."""

    what: str
    test: Callable[[Any], bool]


_KINDS: dict[type, Check] = {
    str: Check("a string", lambda v: isinstance(v, str)),
    bool: Check("true or false", lambda v: isinstance(v, bool)),
    int: Check("a whole number", is_count),
    float: Check("a number", is_number),
    dict: Check("a JSON object", lambda v: isinstance(v, dict)),
    list: Check("a list", lambda v: isinstance(v, list)),
}


def check_shape(path: Path, value: Any, shape: Any, field: str = "") -> None:
    """Raise :class:`CorruptFileError` naming ``path`` and the first ``field`` of ``value`` (the
    file's JSON) that is missing or not of ``shape``.

    A shape is a type (``str``, ``bool``, ``dict``, ``list``; ``float`` is any finite number,
    ``int`` a whole number of 0 or more), a :class:`Check`, a dict of an object's fields (a "?"
    ends one that may be absent), a one-item list (a list of items of that shape) or a
    ``(shape, None)`` pair (that, or null)."""
    nullable = isinstance(shape, tuple)
    if nullable:
        if value is None:
            return
        shape = shape[0]
    kind = dict if isinstance(shape, dict) else list if isinstance(shape, list) else shape
    check = shape if isinstance(shape, Check) else _KINDS[kind]
    if not check.test(value):
        null = " or null" if nullable else ""
        problem = f"expected {check.what}{null}, got {_shown(value)}"
        raise CorruptFileError(path, f"{field}: {problem}" if field else problem)
    if isinstance(shape, dict):
        for key, inner in shape.items():
            name = key.rstrip("?")
            named = f"{field}.{name}" if field else name
            if name in value:
                check_shape(path, value[name], inner, named)
            elif not key.endswith("?"):
                raise CorruptFileError(path, f"{named}: missing")
    elif isinstance(shape, list):
        for k, item in enumerate(value):
            check_shape(path, item, shape[0], f"{field}[{k}]")


def _shown(value: Any) -> str:
    """``value`` as the file spells it, cut short if long."""
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


PATH_SHOWN_MAX = 120
"""The most characters of a path an error message shows: a path too long to use (thousands of
characters) would otherwise fill the terminal."""


def path_error_message(err: OSError) -> str:
    """``err`` (one that :func:`is_unusable_path` takes) as a line naming the path, cut short
    in the middle if long (its start and its last name tell where it is), and the problem."""
    where = "a path" if err.filename is None else str(err.filename)
    if len(where) > PATH_SHOWN_MAX:
        half = (PATH_SHOWN_MAX - 3) // 2
        where = f"{where[:half]}...{where[-half:]} ({len(where):,} characters)"
    problem = err.strerror or str(err)
    if isinstance(err, FileExistsError) and err.filename and Path(err.filename).is_file():
        # What mkdir's "File exists" means to a user who named a directory.
        problem = "it is a file, and a directory is needed there"
    return f"cannot use {where}: {problem}"


def json_safe(data: Any) -> Any:
    """``data`` with its non-finite floats as None: ``json.dumps`` writes them as ``NaN`` and
    ``Infinity``, which no JSON reader but Python's takes."""
    if isinstance(data, float) and not math.isfinite(data):
        return None
    if isinstance(data, dict):
        return {str(k): json_safe(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_safe(v) for v in data]
    return data


def some_of(names: Sequence[str], most: int = 3) -> str:
    """``names`` for a message: the first ``most`` of them, and how many more there are."""
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


BROWSER_FILES = frozenset({".DS_Store", "Thumbs.db", "desktop.ini"})
"""What a file browser leaves in a folder it showed: not the user's files."""


def is_partial_write(name: str) -> bool:
    """Whether ``name`` is the temporary file of a :func:`replaced_whole` write that a kill cut
    short (``.NAME.PID.tmp``, or ``.NAME.PID.tmp.SUFFIX`` keeping NAME's suffix): itskill's,
    never the user's."""
    match = _PARTIAL_WRITE.fullmatch(name)
    if match is None:
        return False
    return match["suffix"] is None or match["name"].endswith(match["suffix"])


_PARTIAL_WRITE = re.compile(r"\.(?P<name>.+)\.\d+\.tmp(?P<suffix>\.[^.]+)?")


def foreign_entries(directory: Path, ours: Callable[[str], bool] = lambda name: False) -> list[str]:
    """The names, sorted, of the entries of ``directory`` that ``ours`` does not claim, no file
    browser left (:data:`BROWSER_FILES`) and no cut-short write of itskill's left
    (:func:`is_partial_write`); none where it is not a directory. A new run asks this of its
    ``--out``: a run there would read another's files, or overwrite the user's."""
    if not directory.is_dir():
        return []
    return sorted(
        e.name
        for e in directory.iterdir()
        if e.name not in BROWSER_FILES and not is_partial_write(e.name) and not ours(e.name)
    )


def run_path(run_dir: Path, recorded: str, default: str) -> Path:
    """A path a run's record names, found in the run as it is now: against ``run_dir`` if it is
    there; else at ``default``, its usual place in ``run_dir`` (records from before paths were
    relative to the run hold absolute paths, or paths relative to the directory the command ran
    in, and the run may have been moved or copied to ``results/`` since); else as written, where
    an older run's file still is."""
    path = Path(recorded)
    ours = [run_dir / default] if path.is_absolute() else [run_dir / path, run_dir / default]
    return next((c for c in [*ours, path] if c.exists()), run_dir / default)


LOCK_DIR_ENV = "ITSKILL_LOCK_DIR"
"""Names the folder lock files go in, instead of ``/tmp/itskill-locks-UID``."""


def lock_folder() -> Path:
    """The folder :func:`directory_lock` keeps its files in: ``$ITSKILL_LOCK_DIR`` if set (an
    absolute path, ``~`` expanded; a relative one is refused), else ``itskill-locks-UID`` in
    ``/tmp``, not in ``$TMPDIR``: every session must find the same lock for a directory, and two
    sessions with different ``TMPDIR`` trained into one run at once (without ``/tmp``, the
    system's temporary directory)."""
    named = os.environ.get(LOCK_DIR_ENV)
    if named:
        try:
            path = Path(named).expanduser()
        except RuntimeError as err:  # ~user of no such user
            raise PermissionError(
                errno.EACCES, f"{LOCK_DIR_ENV}: cannot expand ~ ({err})", named
            ) from err
        if not path.is_absolute():
            # Each session would read it against its own working directory: other locks.
            raise PermissionError(
                errno.EACCES,
                f"{LOCK_DIR_ENV} must name an absolute path, the same in every session",
                named,
            )
        return path
    uid = os.getuid() if hasattr(os, "getuid") else None
    root = Path("/tmp") if Path("/tmp").is_dir() else Path(tempfile.gettempdir())
    return root / f"itskill-locks-{'user' if uid is None else uid}"


def directory_lock(directory: Path, kind: str) -> FileLock:
    """A lock that one process at a time holds on ``directory`` (``kind`` names what for).

    Its file is in a folder of the user's own (:func:`lock_folder`), keyed by the directory's
    resolved path, not in the directory itself: it would show up in a checkout, a package or a
    run's results. A lock file stays after its release (removing it would race with a process
    opening it), one per directory ever locked, so they are kept together rather than among
    the temporary directory's other files. Processes on one machine see it; a cluster's nodes
    do not.
    """
    key = hashlib.sha256(str(Path(directory).resolve()).encode()).hexdigest()[:16]
    locks = lock_folder()
    remedy = (
        f"set {LOCK_DIR_ENV} to a folder of your own, the same in every session on this machine"
    )
    try:
        locks.mkdir(mode=0o700, parents=True, exist_ok=True)
    except FileExistsError as err:
        raise PermissionError(
            errno.EACCES, f"a file, where the folder of itskill's locks goes; {remedy}", str(locks)
        ) from err
    if hasattr(os, "getuid"):
        # The name is predictable: a folder another user made first, or can write in, could
        # hold or delete the locks, so that two sessions work on one run.
        st = locks.lstat()
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
            raise PermissionError(
                errno.EACCES, f"not a folder of this user's alone; {remedy}", str(locks)
            )
    return FileLock(str(locks / f"{kind}-{key}.lock"))


_HELD: set[str] = set()
"""The lock files this process holds through :func:`held_alone`."""


@contextmanager
def held_alone(directory: Path, kind: str, refusal: Exception) -> Iterator[None]:
    """Run the block holding ``directory``'s lock of ``kind`` (:func:`directory_lock`); raise
    ``refusal`` at once, before anything is read or written, if another session holds it.

    A run's directory is worked on by one session at a time: two would train the same jobs into
    the same files and damage the run for good. A block inside one that holds the same lock
    (a command that calls a function taking it too) runs as part of that session.
    """
    lock = directory_lock(directory, kind)
    if lock.lock_file in _HELD:
        yield
        return
    try:
        lock.acquire(timeout=0)
    except Timeout:
        raise refusal from None
    _HELD.add(lock.lock_file)
    try:
        yield
    finally:
        _HELD.discard(lock.lock_file)
        lock.release()
