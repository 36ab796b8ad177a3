"""Atomic writes for run directories, caches and libraries: a file is either absent or complete.

A run killed at any moment (kill -9 included) leaves no half-written file behind, so a resumed run
can trust every file it finds: a ``result.json`` that exists is a finished candidate, a
``checkpoint.json`` a finished checkpoint.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def replaced_whole(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write the new file to: when the block ends it replaces
    ``path`` in one ``os.replace``; if the block fails (a full disk, Ctrl-C) it is removed and
    ``path`` is left as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole (:func:`replaced_whole`), synced to disk first."""
    with replaced_whole(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON, atomically; non-finite floats become ``null``."""
    write_text(path, json.dumps(_finite(data), indent=2) + "\n")


class CorruptFileError(ValueError):
    """A run's or library's file that exists but cannot be read back (edited or damaged)."""


UNUSABLE_PATH_ERRORS: tuple[type[OSError], ...] = (
    FileExistsError,
    FileNotFoundError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)
"""What a user-given path that cannot be written or read raises (a file where a directory should
be, a read-only place, a directory that cannot be created, ...): the commands report it as one
line naming the path."""


def read_json(path: Path) -> Any:
    """The JSON in ``path``; :class:`CorruptFileError` naming the file if it is not valid JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise CorruptFileError(f"{path}: not valid JSON ({err})") from err


def path_error_message(err: OSError) -> str:
    """``err`` (one of :data:`UNUSABLE_PATH_ERRORS`) as a line naming the path and the problem."""
    where = err.filename if err.filename is not None else "a path"
    return f"cannot use {where}: {err.strerror or err}"


def _finite(data: Any) -> Any:
    if isinstance(data, float) and not math.isfinite(data):
        return None
    if isinstance(data, dict):
        return {str(k): _finite(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_finite(v) for v in data]
    return data
