"""The TOML data files a user reads and edits (tasks, hyper-parameters, budgets, experiments...).

Every loader reports a problem the same way: the file, where in it, and what was expected, so a
user can fix the file without reading our code. Each loader has its own subclass of
:class:`DataFileError` so callers can tell which kind of file was wrong. The value tests
(:func:`is_number`, :func:`is_count`) serve the JSON records too (checkpoints, the skill
manifest), which their readers check field by field the same way.
"""

from __future__ import annotations

import math
import string
import sys
from pathlib import Path
from typing import Any

from itskill.errors import PicklableError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class DataFileError(PicklableError, ValueError):
    """A data file that does not validate: names the file, the field and the problem."""

    def __init__(self, path: str | Path, where: str, problem: str) -> None:
        super().__init__(f"{path}: {where}: {problem}")
        self.path, self.where, self.problem = str(path), where, problem


def is_number(value: Any) -> bool:
    """Whether ``value`` is a finite int or float, not a bool: TOML and JSON readers also give
    booleans (an int to Python), ``nan`` and ``inf`` (TOML's ``1e999`` too), which no length, rate
    or time can be, and integers of any length, which one past a float's range is not either."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int too large for a float: every use of the number would fail
        return False


def is_count(value: Any) -> bool:
    """Whether ``value`` is a whole number of 0 or more, not a bool."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def placeholders(text: str) -> list[str]:
    """The ``{field}`` names of a :meth:`str.format` text (a prompt template, a phrase or code
    template of a data file), in order; ``ValueError`` saying how to write literal braces where
    the braces do not parse."""
    try:
        return [f for _, f, _, _ in string.Formatter().parse(text) if f is not None]
    except ValueError as err:
        raise ValueError(f"{err} (write literal braces as {{{{ and }}}})") from err


def read_toml(path: str | Path, error: type[DataFileError] = DataFileError) -> dict[str, Any]:
    """The parsed TOML file at ``path``; a file that is missing, unreadable (a directory, no
    permission), not UTF-8 text or not valid TOML raises ``error``."""
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as err:
        raise error(path, "file", "no such file") from err
    except OSError as err:
        raise error(path, "file", (err.strerror or str(err)).lower()) from err
    except UnicodeDecodeError as err:
        raise error(path, "file", f"not UTF-8 text (byte {err.start})") from err
    except tomllib.TOMLDecodeError as err:
        raise error(path, "TOML syntax", str(err)) from err
    except ValueError as err:
        # tomllib reads an integer of any length through int(), which refuses more digits than
        # Python's limit with a ValueError (its advice, sys.set_int_max_str_digits, is for code).
        raise error(
            path, "file", f"a number of more than {sys.get_int_max_str_digits()} digits"
        ) from err


def check_like(
    path: str | Path, where: str, value: Any, default: Any, error: type[DataFileError]
) -> Any:
    """``value`` converted to the type of the field's ``default`` (bool, int, float, str or a
    tuple of ints, read from a TOML list), or ``error`` naming the type expected.

    A float field takes finite numbers only: TOML writes ``nan``, ``inf`` and ``1e999``, which no
    rate, coefficient or width means, and which otherwise reach training as a traceback there
    ("Invalid learning rate: nan") or, worse, as losses that are NaN from the first update.
    """
    if isinstance(default, bool):
        ok, want = isinstance(value, bool), "a boolean"
    elif isinstance(default, int):
        ok, want = isinstance(value, int) and not isinstance(value, bool), "an integer"
    elif isinstance(default, float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if ok and not is_number(value):
            raise error(path, where, f"expected a finite number, got {value!r}")
        want, value = "a number", float(value) if ok else value
    elif isinstance(default, str):
        ok, want = isinstance(value, str), "a string"
    else:
        ok = isinstance(value, list) and all(
            isinstance(v, int) and not isinstance(v, bool) for v in value
        )
        want, value = "a list of integers", tuple(value) if ok else value
    if not ok:
        raise error(path, where, f"expected {want}, got {type(value).__name__} {value!r}")
    return value
