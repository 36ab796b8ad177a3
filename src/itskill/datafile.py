"""The TOML data files a user reads and edits (tasks, hyper-parameters, budgets, experiments...).

Every loader reports a problem the same way: the file, where in it, and what was expected, so a
user can fix the file without reading our code. Each loader has its own subclass of
:class:`DataFileError` so callers can tell which kind of file was wrong. The value tests
(:func:`is_number`, :func:`is_count`) serve the JSON records too (checkpoints, the skill
manifest), which their readers check field by field the same way.
"""

from __future__ import annotations

import codecs
import math
import string
import sys
from collections.abc import Collection, Mapping
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
        super().__init__(f"{path}: {where}: {problem}" if where else f"{path}: {problem}")
        self.path, self.where, self.problem = str(path), where, problem


class NotUTF8Error(ValueError):
    """Bytes that are not UTF-8 text: says at which byte of the file."""


def utf8_text(data: bytes) -> str:
    """A file's bytes as text; :class:`NotUTF8Error` at the first byte that is not UTF-8. An
    editor's byte-order mark is dropped (it is not text), and the byte counted is the file's."""
    bom = len(codecs.BOM_UTF8) if data.startswith(codecs.BOM_UTF8) else 0
    try:
        return data[bom:].decode("utf-8")
    except UnicodeDecodeError as err:
        raise NotUTF8Error(f"not UTF-8 text (byte {bom + err.start})") from err


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


def check_format_text(
    path: str | Path,
    where: str,
    value: Any,
    sample: Mapping[str, Any],
    error: type[DataFileError],
    exact: bool = False,
) -> str:
    """``value`` if it is a non-blank :meth:`str.format` text whose placeholders are names of
    ``sample`` (every one of them when ``exact``) and which ``sample`` fills, or ``error``
    saying what is wrong: a phrase or code template of a data file would otherwise fail with a
    ``KeyError`` (or a format spec it does not take, ``{object:d}``) only once it is used."""
    if not isinstance(value, str) or not value.strip():
        raise error(path, where, f"expected a non-empty string, got {value!r}")
    try:
        names = placeholders(value)
    except ValueError as err:
        raise error(path, where, str(err)) from err
    known = ", ".join("{" + name + "}" for name in sorted(sample))
    for name in names:
        if name not in sample:
            raise error(path, where, f"unknown placeholder {{{name}}}; known: {known}")
    missing = sorted(set(sample) - set(names)) if exact else []
    if missing:
        raise error(path, where, f"missing placeholder {{{missing[0]}}}")
    try:
        value.format(**sample)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as err:
        raise error(path, where, f"cannot be filled: {err}") from err
    return value


def read_toml(path: str | Path, error: type[DataFileError] = DataFileError) -> dict[str, Any]:
    """The parsed TOML file at ``path``; a file that is missing, unreadable (a directory, no
    permission), not UTF-8 text or not valid TOML raises ``error``."""
    try:
        return tomllib.loads(utf8_text(Path(path).read_bytes()))
    except FileNotFoundError as err:
        raise error(path, "file", "no such file") from err
    except OSError as err:
        raise error(path, "file", (err.strerror or str(err)).lower()) from err
    except NotUTF8Error as err:
        raise error(path, "file", str(err)) from err
    except tomllib.TOMLDecodeError as err:
        raise error(path, "TOML syntax", str(err)) from err
    except ValueError as err:
        # tomllib reads an integer of any length through int(), which refuses more digits than
        # Python's limit with a ValueError (its advice, sys.set_int_max_str_digits, is for code).
        raise error(
            path, "file", f"a number of more than {sys.get_int_max_str_digits()} digits"
        ) from err


_KIND_NAMES = {
    bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "a list",
    dict: "a table",
}  # fmt: skip


def check_type(
    path: str | Path,
    where: str,
    value: Any,
    kind: type | tuple[type, ...],
    error: type[DataFileError],
) -> Any:
    """``value`` if it is a ``kind`` (one type or a tuple of them), or ``error`` naming the types
    expected and what the file has.

    TOML and JSON give booleans, which Python counts as integers: a bool is taken only where
    ``bool`` is asked for. A float field takes an integer too, as a float, and takes finite
    numbers only: TOML writes ``nan``, ``inf`` and ``1e999``, which no rate, coefficient or width
    means, and which otherwise reach training as a traceback there ("Invalid learning rate: nan")
    or, worse, as losses that are NaN from the first update.
    """
    kinds = kind if isinstance(kind, tuple) else (kind,)
    is_bool = isinstance(value, bool)
    if float in kinds and int not in kinds and isinstance(value, int) and not is_bool:
        if not is_number(value):  # an integer of any length, which float() would overflow
            raise error(path, where, f"expected a finite number, got {value!r}")
        value = float(value)
    if not isinstance(value, kinds) or (is_bool and bool not in kinds):
        want = " or ".join(_KIND_NAMES.get(k, k.__name__) for k in kinds)
        raise error(path, where, f"expected {want}, got {type(value).__name__} {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise error(path, where, f"expected a finite number, got {value!r}")
    return value


def check_positive(
    path: str | Path, where: str, value: Any, error: type[DataFileError], most: int | None = None
) -> int:
    """``value`` if it is an integer of 1 or more and, given ``most``, at most that (the caps of
    :mod:`itskill.limits`), or ``error`` saying which bound it breaks."""
    if check_type(path, where, value, int, error) < 1:
        raise error(path, where, f"must be positive, got {value}")
    if most is not None and value > most:
        raise error(path, where, f"must be at most {most:,}, got {value:,}")
    return value


def check_nonnegative(
    path: str | Path,
    where: str,
    value: Any,
    error: type[DataFileError],
    positive: bool = False,
    unit: str = "",
) -> float:
    """``value`` as a float if it is a finite number >= 0 (> 0 when ``positive``: a divisor's),
    or ``error`` saying so, with ``unit`` (such as "USD per 1M tokens") in the message."""
    if not is_number(value) or value < 0 or (positive and value == 0):
        want = "a finite number > 0" if positive else "a finite number >= 0"
        if unit:
            want += f" ({unit})"
        raise error(path, where, f"expected {want}, got {value!r}")
    return float(value)


def check_table(
    path: str | Path,
    where: str,
    value: Any,
    error: type[DataFileError],
    allowed: Collection[str] | None = None,
    what: str = "field",
) -> dict[str, Any]:
    """``value`` if it is a table whose keys are all in ``allowed`` (any keys when it is None),
    or ``error`` naming the first other key (``what`` it is: a field, a table) and the known
    ones. A misspelt key would otherwise be read as left out, and its setting silently lost."""
    table = check_type(path, where, value, dict, error)
    if allowed is not None:
        for key in table:
            if key not in allowed:
                raise error(
                    path,
                    f"{where}.{key}" if where else key,
                    f"unknown {what}; expected one of {', '.join(sorted(allowed))}",
                )
    return table


def check_like(
    path: str | Path, where: str, value: Any, default: Any, error: type[DataFileError]
) -> Any:
    """``value`` as the type of the field's ``default``: bool, int, float or str as
    :func:`check_type` takes them, or a tuple of ints, read from a TOML list."""
    if not isinstance(default, tuple):
        return check_type(path, where, value, type(default), error)
    if not isinstance(value, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in value
    ):
        raise error(
            path, where, f"expected a list of integers, got {type(value).__name__} {value!r}"
        )
    return tuple(value)
