"""Settings of the transfer methods: one dataclass, defaults in ``data/transfer.toml``.

The packaged file holds the defaults; :func:`load_transfer_config` reads it (or a user's file of the
same shape; :func:`parse_transfer_config` such tables from elsewhere, an experiment file's
``[transfer]``) and checks every field, reporting the file, the field and what was expected
(:class:`TransferConfigError`).
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from itskill.datafile import DataFileError, check_like, check_table, read_toml
from itskill.limits import RETRIES_MAX, SOURCES_MAX, WIDTH_MAX


class TransferConfigError(DataFileError):
    """A transfer settings file that does not validate: names the file, field and problem."""


_Rule = tuple[Callable[[Any], bool], str]
_AT_LEAST_1: _Rule = (lambda v: v >= 1, "at least 1")
_SOURCES: _Rule = (lambda v: v <= SOURCES_MAX, f"at most {SOURCES_MAX:,}")
_RULES: dict[str, tuple[_Rule, ...]] = {
    "k": (_AT_LEAST_1, _SOURCES),
    "attention_hidden": (_AT_LEAST_1, (lambda v: v <= WIDTH_MAX, f"at most {WIDTH_MAX:,}")),
    "pst_keep": (_AT_LEAST_1, _SOURCES),
    "min_success": ((lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),),
    "prior_weight": ((lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),),
    "analyzer_retries": (
        (lambda v: v >= 0, "0 or more"),
        (lambda v: v <= RETRIES_MAX, f"at most {RETRIES_MAX:,}"),
    ),
    "fusion_hidden": (
        (lambda v: all(w >= 1 for w in v), "positive widths"),
        (lambda v: all(w <= WIDTH_MAX for w in v), f"widths of at most {WIDTH_MAX:,}"),
    ),
}
"""The range of each :class:`TransferConfig` field, by its name there; a rule holds the tests and
what each wants (``"at least 1"``), which the dataclass and the file's loader word each their way.
A NaN is outside every range. The upper bounds (:mod:`itskill.limits`) stop a mistyped huge
width or count before it allocates a network of terabytes, retrieves and runs thousands of
sources, or pays for thousands of model calls."""


def _out_of_range(name: str, value: Any) -> str | None:
    """What field ``name`` wants, if ``value`` is outside its range (:data:`_RULES`)."""
    return next((want for test, want in _RULES.get(name, ()) if not test(value)), None)


def _of_kind(value: Any, default: Any) -> bool:
    """Whether ``value`` is of the kind of a field whose default is ``default``: a bool only
    where a bool is, an integer (no bool; NumPy's too) where an int is, a float taking an
    integer too, a tuple of widths as a tuple or list of integers."""
    if isinstance(default, tuple):
        return isinstance(value, tuple | list) and all(_of_kind(w, 0) for w in value)
    if isinstance(default, bool) or isinstance(value, bool | np.bool_):
        return isinstance(value, bool | np.bool_) and isinstance(default, bool)
    return isinstance(value, numbers.Real if isinstance(default, float) else numbers.Integral)


def check_setting(name: str, value: Any) -> None:
    """``TypeError`` if ``value`` is not of the kind of :class:`TransferConfig` field ``name``
    (``k=2.5``, ``residual=1``), ``ValueError`` if it is outside the field's range: for the
    settings a transfer network is also built with from Python."""
    default = next(f.default for f in fields(TransferConfig) if f.name == name)
    if not _of_kind(value, default):
        kind = _kind_name(default)
        raise TypeError(f"{name} must be {kind}, got {type(value).__name__} {value!r}")
    want = _out_of_range(name, value)
    if want is not None:
        raise ValueError(f"{name} must be {want}, got {value}")


def _kind_name(default: Any) -> str:
    if isinstance(default, tuple):
        return "a list of integers"
    return {bool: "a boolean", int: "an integer", float: "a number"}[type(default)]


@dataclass(frozen=True)
class TransferConfig:
    """How sources are chosen and how the transfer network is shaped (see transfer.toml)."""

    k: int = 3
    distinct_actions: bool = True
    min_success: float = 0.5
    attention_hidden: int = 32
    prior_weight: float = 0.5
    fusion_hidden: tuple[int, ...] = ()
    pst_keep: int = 1
    analyzer_retries: int = 2
    residual: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):
            check_setting(f.name, getattr(self, f.name))
            if type(f.default) in (bool, int, float):  # NumPy's as Python's, for JSON
                object.__setattr__(self, f.name, type(f.default)(getattr(self, f.name)))
        object.__setattr__(self, "fusion_hidden", tuple(int(w) for w in self.fusion_hidden))

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "fusion_hidden": list(self.fusion_hidden)}

    def policy_kwargs(self) -> dict[str, Any]:
        """The network settings a transfer policy takes (the rest is about choosing sources)."""
        return {
            "attention_hidden": self.attention_hidden,
            "prior_weight": self.prior_weight,
            "fusion_hidden": list(self.fusion_hidden),
        }


# TOML table -> {key: dataclass field}.
_LAYOUT: dict[str, dict[str, str]] = {
    "sources": {"k": "k", "distinct_actions": "distinct_actions", "min_success": "min_success"},
    "attention": {"hidden": "attention_hidden", "prior_weight": "prior_weight"},
    "fusion": {"hidden": "fusion_hidden"},
    "pst": {"keep": "pst_keep"},
    "analyzer": {"retries": "analyzer_retries"},
    "head": {"residual": "residual"},
}


def setting_key(name: str) -> tuple[str, str]:
    """The table and key of :class:`TransferConfig` field ``name`` in ``transfer.toml``'s
    shape (``pst_keep``: ``("pst", "keep")``), to name a setting as the files do."""
    return next((t, k) for t, entries in _LAYOUT.items() for k, n in entries.items() if n == name)


def default_path() -> Path:
    """The packaged ``transfer.toml``: the settings a run takes where nothing names others."""
    return Path(str(resources.files("itskill.transfer") / "data" / "transfer.toml"))


def load_transfer_config(path: str | Path | None = None) -> TransferConfig:
    """The settings in ``path`` (default: the packaged ``transfer.toml``), every field checked."""
    path = Path(path) if path is not None else default_path()
    return parse_transfer_config(read_toml(path, TransferConfigError), path)


def parse_transfer_config(
    data: dict[str, Any], path: str | Path, base: TransferConfig | None = None
) -> TransferConfig:
    """``data``, tables in ``transfer.toml``'s shape, on top of ``base`` (default: the
    dataclass's defaults): every field checked, a :class:`TransferConfigError` naming ``path``,
    the field as ``data`` has it (``pst.keep``) and what was expected."""
    defaults = {f.name: f.default for f in fields(TransferConfig)}
    values: dict[str, Any] = {}
    check_table(path, "", data, TransferConfigError, _LAYOUT, "table")
    for table, entries in data.items():
        check_table(path, table, entries, TransferConfigError, _LAYOUT[table])
        for key, value in entries.items():
            name = _LAYOUT[table][key]
            values[name] = check_like(
                path, f"{table}.{key}", value, defaults[name], TransferConfigError
            )
            # Named as the file has it (pst.keep), not as the dataclass (pst_keep).
            want = _out_of_range(name, values[name])
            if want is not None:
                raise TransferConfigError(
                    path, f"{table}.{key}", f"expected {want}, got {values[name]!r}"
                )
    return replace(base or TransferConfig(), **values)
