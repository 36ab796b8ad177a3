"""Settings of the transfer methods: one dataclass, defaults in ``data/transfer.toml``.

The packaged file holds the defaults; :func:`load_transfer_config` reads it (or a user's file of the
same shape) and checks every field, reporting the file, the field and what was expected
(:class:`TransferConfigError`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from itskill.datafile import DataFileError, check_like, read_toml


class TransferConfigError(DataFileError):
    """A transfer settings file that does not validate: names the file, field and problem."""


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
        for name in ("k", "attention_hidden", "pst_keep"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if not 0.0 <= self.min_success <= 1.0:
            raise ValueError(f"min_success must be in [0, 1], got {self.min_success}")
        if not 0.0 <= self.prior_weight <= 1.0:
            raise ValueError(f"prior_weight must be in [0, 1], got {self.prior_weight}")
        if self.analyzer_retries < 0:
            raise ValueError(f"analyzer_retries must be >= 0, got {self.analyzer_retries}")
        if any(w < 1 for w in self.fusion_hidden):
            raise ValueError(f"fusion_hidden must be positive widths, got {self.fusion_hidden}")
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


def default_path() -> Path:
    return Path(str(resources.files("itskill.transfer") / "data" / "transfer.toml"))


def load_transfer_config(path: str | Path | None = None) -> TransferConfig:
    """The settings in ``path`` (default: the packaged ``transfer.toml``), every field checked."""
    path = Path(path) if path is not None else default_path()
    data = read_toml(path, TransferConfigError)
    defaults = {f.name: f.default for f in fields(TransferConfig)}
    values: dict[str, Any] = {}
    for table, entries in data.items():
        if table not in _LAYOUT:
            raise TransferConfigError(
                path, table, f"unknown table; expected one of {', '.join(sorted(_LAYOUT))}"
            )
        if not isinstance(entries, dict):
            raise TransferConfigError(
                path, table, f"expected a table, got {type(entries).__name__}"
            )
        for key, value in entries.items():
            if key not in _LAYOUT[table]:
                known = ", ".join(sorted(_LAYOUT[table]))
                raise TransferConfigError(
                    path, f"{table}.{key}", f"unknown field; expected one of {known}"
                )
            name = _LAYOUT[table][key]
            values[name] = check_like(
                path, f"{table}.{key}", value, defaults[name], TransferConfigError
            )
    try:
        return TransferConfig(**values)
    except ValueError as err:
        raise TransferConfigError(path, "values", str(err)) from err
