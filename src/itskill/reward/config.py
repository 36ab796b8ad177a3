"""Settings of the reward optimisation loop, with defaults from ``itskill/reward/data/search.toml``.

:func:`load_search_config` reads that file (or a user's of the same shape) and applies overrides;
every problem names the file, the field and what was expected (:class:`SearchConfigError`).
"""

from __future__ import annotations

import typing
from dataclasses import asdict, dataclass, field, fields, replace
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from itskill.datafile import (
    DataFileError,
    check_like,
    check_table,
    check_type,
    read_toml,
)
from itskill.executors import EXECUTORS
from itskill.limits import (
    EPISODES_MAX,
    NUM_ENVS_MAX,
    RETRIES_MAX,
    SEED_COUNT_MAX,
    SEED_MAX,
    STEPS_MAX,
    WORKERS_MAX,
)
from itskill.reward.sandbox import SandboxConfig
from itskill.rl.config import ALGOS


class SearchConfigError(DataFileError):
    """A search setting that does not validate: names the source, the field and the problem."""

    @property
    def setting(self) -> str:
        """The setting at fault, without an index or sub-field (``seeds`` for ``seeds[0]``)."""
        return self.where.split(".")[0].split("[")[0]


_KINDS: dict[str, type] = {
    "iterations": int, "samples": int, "steps": int, "num_envs": int, "algo": str,
    "seeds": tuple, "select_top": int, "select_seeds": int, "final_seeds": int,
    "evaluations": int, "eval_episodes": int,
    "correlation_envs": int, "executor": str, "workers": int, "ray_address": str,
    "max_regenerations": int, "probe_envs": int, "probe_steps": int,
    "candidate_timeout_s": float, "temperature": float,
}  # fmt: skip
"""Type of every ``[search]`` field."""
_OPTIONAL = {"workers", "ray_address"}
_POSITIVE = {
    "iterations", "samples", "steps", "num_envs", "select_seeds", "final_seeds", "evaluations",
    "eval_episodes",
    "correlation_envs", "probe_envs", "probe_steps", "candidate_timeout_s",
}  # fmt: skip
DAY_S = 24 * 3600
CALL_TIMEOUT_MAX_S = 3600
"""One reward call (one env-step of a batch) for at most an hour: a candidate calls it thousands
of times, so more could never finish; and ``signal.setitimer`` overflows on an infinite one."""
TIME_LIMIT_MAX_S = 3 * DAY_S
"""A candidate's wall-clock (``candidate_timeout_s``) and CPU-time (``sandbox.cpu_limit_s``)
limits: the packaged ones are half an hour and an hour, so days are no limit to a reward search;
an infinite or vast one overflows the C types that the timers and ``RLIMIT_CPU`` take."""
MEMORY_LIMIT_MAX_MB = 1024 * 1024
"""1 TiB: more than any machine a search runs on has, so no limit at all; a larger number of
bytes overflows the C long ``RLIMIT_AS`` takes (an OverflowError in the candidate's process)."""
ITERATIONS_MAX = 100
"""The most iterations of the loop (the paper's: 5): each waits for its samples' trainings."""
SAMPLES_MAX = 100
"""The most reward samples per iteration, and rewards retrained before the choice
(``select_top``): the paper samples 10; each sample is a paid model call and a training per seed."""
EVALUATIONS_MAX = 1000
"""The most evaluations through one training (packaged: 4): each runs ``eval_episodes`` episodes,
so a mistyped huge count evaluates after every few env-steps instead of training."""
PROBE_STEPS_MAX = 1000
"""The most random steps of the probe (packaged: 6): the tasks' episodes end within a few hundred
steps, and the probe keeps every step's context of every environment."""
_MAXIMA: dict[str, int] = {
    "num_envs": NUM_ENVS_MAX, "correlation_envs": NUM_ENVS_MAX, "probe_envs": NUM_ENVS_MAX,
    "eval_episodes": EPISODES_MAX, "candidate_timeout_s": TIME_LIMIT_MAX_S,
    "iterations": ITERATIONS_MAX, "samples": SAMPLES_MAX, "select_top": SAMPLES_MAX,
    "steps": STEPS_MAX, "evaluations": EVALUATIONS_MAX, "probe_steps": PROBE_STEPS_MAX,
    "select_seeds": SEED_COUNT_MAX, "final_seeds": SEED_COUNT_MAX, "workers": WORKERS_MAX,
    "max_regenerations": RETRIES_MAX,
    "sandbox.call_timeout_s": CALL_TIMEOUT_MAX_S, "sandbox.cpu_limit_s": TIME_LIMIT_MAX_S,
    "sandbox.memory_limit_mb": MEMORY_LIMIT_MAX_MB,
}  # fmt: skip
"""The largest value of a field (by its name in the file): environments stepped together in one
process (:data:`~itskill.limits.NUM_ENVS_MAX`), episodes of an evaluation
(:data:`~itskill.limits.EPISODES_MAX`), worker processes, retries of a paid model call, seeds
given as a count (:mod:`itskill.limits`), and the limits above. A mistyped huge count ran a whole
training first and failed after it (MemoryError), crashed every candidate at allocation, paid for
thousands of model calls, or ran for days."""


def default_path() -> Path:
    """The packaged defaults file."""
    return Path(str(resources.files("itskill.reward") / "data" / "search.toml"))


def _coerce(source: str | Path, where: str, value: Any, kind: type, optional: bool) -> Any:
    if value is None and optional:
        return None
    if kind is tuple:
        # A file's list of seeds, or the tuple a command line gives.
        listed = list(value) if isinstance(value, tuple) else value
        return check_like(source, where, listed, (), SearchConfigError)
    return check_type(source, where, value, kind, SearchConfigError)


def check_seeds(
    source: str | Path, where: str, seeds: tuple[int, ...], error: type[DataFileError]
) -> None:
    """Raise ``error`` naming ``source`` and the field unless ``seeds`` are distinct, at least
    one, and each a seed training takes (0 to :data:`~itskill.limits.SEED_MAX`): a seed
    training refuses would otherwise fail every run only once the runs start."""
    if not seeds or len(set(seeds)) != len(seeds):
        raise error(source, where, f"expected distinct seeds, at least one, got {list(seeds)}")
    for i, seed in enumerate(seeds):
        if not 0 <= seed <= SEED_MAX:
            raise error(
                source, f"{where}[{i}]", f"expected a seed between 0 and {SEED_MAX}, got {seed}"
            )


def _sandbox(source: str | Path, table: Any, base: SandboxConfig | None = None) -> SandboxConfig:
    """A :class:`SandboxConfig` from a table of its fields (over ``base``)."""
    hints = typing.get_type_hints(SandboxConfig)
    check_table(source, "sandbox", table, SearchConfigError, hints)
    values = {}
    for key, value in table.items():
        kind = next(a for a in (*typing.get_args(hints[key]), hints[key]) if a is not type(None))
        optional = type(None) in typing.get_args(hints[key])
        values[key] = _coerce(source, f"sandbox.{key}", value, kind, optional)
    return replace(base or SandboxConfig(), **values)


def _read(path: Path, sandbox: SandboxConfig | None = None) -> dict[str, Any]:
    """The fields a search file sets, type-checked (values are range-checked by the dataclass);
    its ``[sandbox]`` table over ``sandbox`` (a user's file: the packaged limits, so that a file
    which leaves them out does not run generated code without them)."""
    data = read_toml(path, SearchConfigError)
    check_table(path, "", data, SearchConfigError, {"search", "sandbox"}, "table")
    table = check_table(path, "search", data.get("search", {}), SearchConfigError, _KINDS)
    values: dict[str, Any] = {}
    for key, value in table.items():
        values[key] = _coerce(path, f"search.{key}", value, _KINDS[key], key in _OPTIONAL)
    values["sandbox"] = _sandbox(path, data.get("sandbox", {}), sandbox)
    return values


@cache
def _defaults() -> dict[str, Any]:
    """The packaged file's values: the dataclass defaults below come from here."""
    values = _read(default_path())
    missing = sorted(set(_KINDS) - _OPTIONAL - set(values))
    if missing:
        raise SearchConfigError(default_path(), f"search.{missing[0]}", "missing (required)")
    return values


@dataclass(frozen=True)
class RewardSearchConfig:
    """Budget and settings of one reward search (the paper's: 5 iterations x 10 samples)."""

    iterations: int = _defaults()["iterations"]
    samples: int = _defaults()["samples"]
    steps: int = _defaults()["steps"]
    """Env-steps per candidate and seed (and per final run)."""
    num_envs: int = _defaults()["num_envs"]
    algo: str = _defaults()["algo"]
    seeds: tuple[int, ...] = _defaults()["seeds"]
    """Training seeds of every candidate; its success is the mean over them."""
    select_top: int = _defaults()["select_top"]
    """How many of the best distinct rewards are retrained on ``select_seeds`` more seeds before
    the choice (0: choose on ``seeds`` alone)."""
    select_seeds: int = _defaults()["select_seeds"]
    final_seeds: int = _defaults()["final_seeds"]
    evaluations: int = _defaults()["evaluations"]
    """Deterministic evaluations spread evenly through each training run."""
    eval_episodes: int = _defaults()["eval_episodes"]
    correlation_envs: int = _defaults()["correlation_envs"]
    executor: str = _defaults()["executor"]
    workers: int | None = _defaults().get("workers")
    ray_address: str | None = _defaults().get("ray_address")
    max_regenerations: int = _defaults()["max_regenerations"]
    probe_envs: int = _defaults()["probe_envs"]
    probe_steps: int = _defaults()["probe_steps"]
    candidate_timeout_s: float = _defaults()["candidate_timeout_s"]
    temperature: float = _defaults()["temperature"]
    sandbox: SandboxConfig = field(default_factory=lambda: _defaults()["sandbox"])

    def __post_init__(self) -> None:
        where = "RewardSearchConfig"
        for name in _POSITIVE:
            value = getattr(self, name)
            if not value > 0:
                raise SearchConfigError(where, name, f"expected a positive number, got {value!r}")
        if self.algo not in ALGOS:
            raise SearchConfigError(where, "algo", f"expected one of {ALGOS}, got {self.algo!r}")
        if self.executor not in EXECUTORS:
            raise SearchConfigError(
                where, "executor", f"expected one of {EXECUTORS}, got {self.executor!r}"
            )
        if self.ray_address is not None and not self.ray_address.strip():
            raise SearchConfigError(
                where, "ray_address", "empty: leave it out for a local Ray instance"
            )
        # Before the seeds' check, which lists the retraining's seeds: a huge count hung there.
        for name, most in _MAXIMA.items():
            table, _, key = name.rpartition(".")
            value = getattr(self.sandbox if table else self, key)
            if value is not None and value > most:
                unit = " s" if key.endswith("_s") else " MB" if key.endswith("_mb") else ""
                raise SearchConfigError(
                    where, name, f"expected at most {most:,}{unit}, got {value:,}"
                )
        check_seeds(where, "seeds", self.seeds, SearchConfigError)
        # The final (and selection) retraining train on the seeds after the largest one.
        last = self.last_seed
        if last > SEED_MAX:
            raise SearchConfigError(
                where,
                "seeds",
                f"the retraining after the search takes the seeds after the largest one, up to "
                f"{last}, more than {SEED_MAX}: use smaller seeds",
            )
        if self.workers is not None and self.workers < 1:
            raise SearchConfigError(where, "workers", f"expected at least 1, got {self.workers}")
        if self.select_top < 0:
            raise SearchConfigError(where, "select_top", "expected 0 or more")
        if self.max_regenerations < 0:
            raise SearchConfigError(where, "max_regenerations", "expected 0 or more")
        if not 0.0 <= self.temperature <= 2.0:
            raise SearchConfigError(where, "temperature", "expected a value in [0, 2]")
        for limit in fields(SandboxConfig):
            # A limit of 0 or less does not mean "none" (leaving it out does): the limit would be
            # silently off (a negative timeout or memory limit) or refuse every reward.
            value = getattr(self.sandbox, limit.name)
            if value is not None and not value > 0:
                raise SearchConfigError(
                    where, f"sandbox.{limit.name}", f"expected a positive number, got {value!r}"
                )

    @property
    def select_seed_list(self) -> list[int]:
        """Seeds of the selection retraining: after the search's and the final retraining's,
        so neither the choice nor the final comparison reuses a seed the other saw."""
        first = max(self.seeds) + 1 + self.final_seeds
        return [first + s for s in range(self.select_seeds)]

    @property
    def last_seed(self) -> int:
        """The largest seed the search trains on (its final or selection retraining)."""
        return (self.select_seed_list if self.select_top else self.final_seed_list)[-1]

    @property
    def final_seed_list(self) -> list[int]:
        """Seeds of the final retraining of the chosen and the expert reward."""
        return [max(self.seeds) + 1 + s for s in range(self.final_seeds)]

    @property
    def eval_every(self) -> int:
        """Env-steps between evaluations (there is always one at the end of training)."""
        return max(1, -(-self.steps // self.evaluations))

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["seeds"] = list(self.seeds)
        return data

    def result_settings(self) -> dict[str, Any]:
        """The settings that change results: a resumed run must keep them (where and on how many
        workers the jobs run does not matter)."""
        data = self.to_dict()
        for key in ("executor", "workers", "ray_address"):
            data.pop(key)
        return data


def _in_file(where: str) -> str:
    """A field as a search file names it: its ``[search]`` fields under ``search.``, as the
    ``sandbox.`` ones are under theirs (the dataclass's checks name the field alone)."""
    return where if where.startswith("sandbox.") else f"search.{where}"


def load_search_config(
    path: str | Path | None = None, overrides: dict[str, Any] | None = None
) -> RewardSearchConfig:
    """The search settings from ``path`` (default: the packaged file) with ``overrides`` on top.

    ``overrides`` may set any field; ``sandbox`` may be a :class:`SandboxConfig` or a dict of some
    of its fields. ``None`` values are ignored (a command-line option that was not given).
    """
    values = _read(Path(path), _defaults()["sandbox"]) if path is not None else {}
    try:
        base = RewardSearchConfig(**values)
    except SearchConfigError as err:
        raise SearchConfigError(path or default_path(), _in_file(err.where), err.problem) from err
    over: dict[str, Any] = {}
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        if key == "sandbox":
            sandbox = value if isinstance(value, SandboxConfig) else None
            over[key] = sandbox or _sandbox("overrides", value, base.sandbox)
        elif key in _KINDS:
            over[key] = _coerce("overrides", key, value, _KINDS[key], key in _OPTIONAL)
        else:
            raise SearchConfigError(
                "overrides", key, f"unknown field; expected one of {', '.join(_KINDS)}, sandbox"
            )
    try:
        return replace(base, **over)
    except SearchConfigError as err:
        raise SearchConfigError("overrides", err.where, err.problem) from err
