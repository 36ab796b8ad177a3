"""Training hyper-parameters: one dataclass per algorithm, values per task family from TOML.

The packaged file is ``itskill/rl/data/hyperparams.toml``; ``load_hyperparams(..., path=...)``
reads a user's file of the same shape instead. Every problem is reported with the file, the field
(the table, for a problem of two fields together, such as ``rms_prop_tf_like`` without
``use_rms_prop``) and what was expected (:class:`HyperparamError`).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike
from stable_baselines3.common.utils import LinearSchedule

from itskill.datafile import DataFileError, check_like, check_table, read_toml
from itskill.limits import DEPTH_MAX, EPISODES_MAX, NUM_ENVS_MAX, WIDTH_MAX
from itskill.rl.demos import DemoConfig
from itskill.rl.init_policy import InitConfig
from itskill.rl.policy import PolicyConfig
from itskill.tasks.spec import UnknownTaskError, all_tasks, get_task

Algo = Literal["a2c", "ppo"]
ALGOS: tuple[str, ...] = ("a2c", "ppo")


class HyperparamError(DataFileError):
    """A hyper-parameter file or override that does not validate."""


LR_SCHEDULES: tuple[str, ...] = ("constant", "linear")
"""``constant``: the same learning rate throughout; ``linear``: from ``learning_rate`` down to 0
at the end of the run's env-step budget (PPO's usual annealing: late updates stop undoing a
policy that already succeeds)."""


class _AlgoConfig:
    """What every algorithm's config shares: the ``lr_schedule`` field's check and SB3 form."""

    lr_schedule: str

    def __post_init__(self) -> None:
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(
                f"lr_schedule must be one of {list(LR_SCHEDULES)}, got {self.lr_schedule!r}"
            )

    def sb3_kwargs(self) -> dict[str, Any]:
        """The algorithm's SB3 keyword arguments, the learning-rate schedule resolved."""
        kw = asdict(self)  # type: ignore[call-overload]
        if kw.pop("lr_schedule") == "linear":
            # SB3 calls it with the fraction of the budget left: 1 at the start, 0 at the end.
            kw["learning_rate"] = LinearSchedule(kw["learning_rate"], 0.0, 1.0)
        return kw

    def optimizer_kwargs(self) -> dict[str, Any]:
        """``policy_kwargs`` that choose the policy's optimiser; empty: the algorithm's own."""
        return {}


@dataclass(frozen=True)
class A2CConfig(_AlgoConfig):
    """A2C (synchronous advantage actor-critic); defaults follow Mnih et al. (2016) / SB3."""

    learning_rate: float = 7e-4
    n_steps: int = 8
    gamma: float = 0.99
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    use_rms_prop: bool = True
    rms_prop_eps: float = 1e-5
    rms_prop_tf_like: bool = False
    """RMSprop as TensorFlow computes it (Stable-Baselines3's ``RMSpropTFLike``), the optimiser of
    the A2C results of OpenAI Baselines and Stable-Baselines 2: the running average of squared
    gradients starts at 1 instead of 0, so the first updates are small rather than a full
    ``learning_rate`` per weight, and the epsilon sits inside the square root. Needs
    ``use_rms_prop``. On Pick (nut M12) it learned far slower than torch's (docs/training.md, "A2C
    settings screened"), so the packaged file leaves it off."""
    normalize_advantage: bool = False
    lr_schedule: str = "constant"
    """One of :data:`LR_SCHEDULES`."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.rms_prop_tf_like and not self.use_rms_prop:
            raise ValueError("rms_prop_tf_like needs use_rms_prop = true")

    def sb3_kwargs(self) -> dict[str, Any]:
        kw = super().sb3_kwargs()
        del kw["rms_prop_tf_like"]  # an optimiser class, passed with the policy's arguments
        return kw

    def optimizer_kwargs(self) -> dict[str, Any]:
        if not self.rms_prop_tf_like:
            return {}
        # SB3's A2C builds torch's RMSprop with these same alpha and weight decay.
        return {
            "optimizer_class": RMSpropTFLike,
            "optimizer_kwargs": {"alpha": 0.99, "eps": self.rms_prop_eps, "weight_decay": 0.0},
        }


@dataclass(frozen=True)
class PPOConfig(_AlgoConfig):
    """PPO with clipped surrogate; defaults are the usual continuous-control values."""

    learning_rate: float = 3e-4
    n_steps: int = 128
    batch_size: int = 512
    n_epochs: int = 5
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.0
    """0 disables early stopping on KL."""
    lr_schedule: str = "constant"
    """One of :data:`LR_SCHEDULES`."""

    def sb3_kwargs(self) -> dict[str, Any]:
        kw = super().sb3_kwargs()
        kw["target_kl"] = kw["target_kl"] or None
        return kw


@dataclass(frozen=True)
class Hyperparams:
    """Everything the trainer needs for one (family, algorithm) pair."""

    family: str
    algo: Algo
    num_envs: int = 16
    checkpoint_every: int = 50_000
    normalize_reward: bool = True
    """Divide rewards by a running estimate of the discounted return's standard deviation before
    the algorithm sees them (logged rewards stay raw). Staged rewards pay a bonus every step, so
    returns reach the hundreds; unscaled, the critic's gradients dominate the shared gradient-norm
    clip and shrink every actor update with them."""
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo_config: A2CConfig | PPOConfig = field(default_factory=PPOConfig)
    demos: DemoConfig = field(default_factory=DemoConfig)
    """Warm start from the task's scripted controller before RL (off by default;
    :mod:`itskill.rl.demos`)."""
    init: InitConfig = field(default_factory=InitConfig)
    """How a run started from a trained policy explores and learns
    (:mod:`itskill.rl.init_policy`)."""

    def starting_from_policy(self) -> Hyperparams:
        """These settings for a run that starts from a trained policy: the ``init`` table's action
        noise and learning rate in place of the policy's and the algorithm's."""
        return replace(
            self,
            policy=replace(self.policy, log_std_init=self.init.log_std_init),
            algo_config=replace(self.algo_config, learning_rate=self.init.learning_rate),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": self.family,
            "algo": self.algo,
            "num_envs": self.num_envs,
            "checkpoint_every": self.checkpoint_every,
            "normalize_reward": self.normalize_reward,
            "policy": self.policy.to_dict(),
            self.algo: asdict(self.algo_config),
            "demos": asdict(self.demos),
            "init": asdict(self.init),
        }


ALGO_CONFIGS: dict[str, type] = {"a2c": A2CConfig, "ppo": PPOConfig}
_FAMILY_KEYS = {"num_envs": int, "checkpoint_every": int, "normalize_reward": bool}
_SUB_TABLES = ("policy", "demos", "init")
"""Sub-tables besides the algorithms': :class:`PolicyConfig`, :class:`DemoConfig`,
:class:`InitConfig`."""
_FIELDS = {*_FAMILY_KEYS, *_SUB_TABLES, *ALGOS}
"""What a family's or task's table may hold (a family's also ``tasks``)."""
_POSITIVE = (lambda v: v > 0, "a positive value")
_NON_NEGATIVE = (lambda v: v >= 0, "a value of 0 or more")
LOG_STD_RANGE = (-5.0, 2.0)
"""The range of ``log_std_init`` (the policy's and the ``init`` table's): the log of the action
noise's standard deviation, actions being in [-1, 1]. At 2 the noise (7.4) is over three times
the whole action range, nearly every action clipped to a bound; at -5 (0.007) the policy hardly
explores. The packaged values are -3 to -0.5. A NaN or infinite one trained into a traceback
mid-run."""
N_STEPS_MAX = 100_000
"""The longest rollout per environment (``n_steps``): the packaged are 8 (A2C) and 64 (PPO), and
the rollout buffer holds ``n_steps`` rows of every environment, so a mistyped huge one fails at
allocation after the environments are made."""
BATCH_SIZE_MAX = 1_000_000
"""The largest minibatch (PPO's, the warm start's): the packaged are 256; a million transitions
is already a whole rollout of many environments, and no minibatch at all."""
EPOCHS_MAX = 1000
"""The most passes over one rollout (PPO's ``n_epochs``, packaged 5) or over the demonstrations
(the warm start's ``epochs``, 100): a mistyped 50000 trains on for days before the first
evaluation."""
_RANGES: dict[str, tuple[Callable[[Any], bool], str]] = {
    **dict.fromkeys(("checkpoint_every", "max_grad_norm", "rms_prop_eps"), _POSITIVE),
    # A mistyped exponent (3e4 for 3e-4) loaded, then training failed on NaN actions after a
    # rollout; a clip range past 1 makes PPO's lower ratio bound negative.
    **dict.fromkeys(("learning_rate", "clip_range"), (lambda v: 0 < v <= 1, "a value in (0, 1]")),
    # Normalised observations span a few units: clipped to under one, they carry little.
    "obs_clip": (lambda v: v >= 1, "a value of 1 or more"),
    **dict.fromkeys(("ent_coef", "vf_coef", "target_kl"), _NON_NEGATIVE),
    "gamma": (lambda v: 0 < v <= 1, "a value in (0, 1]"),
    "gae_lambda": (lambda v: 0 <= v <= 1, "a value in [0, 1]"),
    "log_std_init": (
        lambda v: LOG_STD_RANGE[0] <= v <= LOG_STD_RANGE[1],
        f"a value in [{LOG_STD_RANGE[0]:g}, {LOG_STD_RANGE[1]:g}]",
    ),
    # Counts a mistyped huge value turns into an allocation that fails mid-run: see the limits.
    "num_envs": (lambda v: 1 <= v <= NUM_ENVS_MAX, f"a positive value, at most {NUM_ENVS_MAX:,}"),
    "episodes": (
        lambda v: 0 <= v <= EPISODES_MAX,
        f"a value of 0 or more (0: no warm start), at most {EPISODES_MAX:,}",
    ),
    "critic_episodes": (
        lambda v: 1 <= v <= EPISODES_MAX, f"a positive value, at most {EPISODES_MAX:,}"
    ),
    "n_steps": (lambda v: 1 <= v <= N_STEPS_MAX, f"a positive value, at most {N_STEPS_MAX:,}"),
    "batch_size": (
        lambda v: 1 <= v <= BATCH_SIZE_MAX, f"a positive value, at most {BATCH_SIZE_MAX:,}"
    ),
    **dict.fromkeys(
        ("n_epochs", "epochs"),
        (lambda v: 1 <= v <= EPOCHS_MAX, f"a positive value, at most {EPOCHS_MAX:,}"),
    ),
    "stages": (
        lambda v: 1 <= len(v) <= DEPTH_MAX and all(1 <= w <= WIDTH_MAX for w in v),
        f"1 to {DEPTH_MAX} positive widths, at most {WIDTH_MAX:,} each",
    ),
}  # fmt: skip
"""The range of every numeric field, by name in any table. Outside it training does not fail at
once: a discount of 90 or a negative clip range turns the losses into NaN after the first
rollout, and a gradient-norm clip of 0 silently stops all learning. NaN and infinity (valid TOML)
are refused for every float field: by its range where that refuses them, else by
:func:`~itskill.datafile.check_like`."""


def default_path() -> Path:
    return Path(str(resources.files("itskill.rl") / "data" / "hyperparams.toml"))


def _check_value(path: Path, where: str, value: Any, default: Any) -> Any:
    """``value`` as the type of ``default`` and within its field's range (:data:`_RANGES`), or a
    HyperparamError naming the expected type or range."""
    rule = _RANGES.get(where.rsplit(".", 1)[-1])
    # A NaN or an infinity the field's range refuses is named with that range ("gamma: expected
    # a value in (0, 1], got nan"), which says more than check_like's "a finite number".
    nonfinite = isinstance(value, float) and not math.isfinite(value)
    if rule is not None and nonfinite and not rule[0](value):
        raise HyperparamError(path, where, f"expected {rule[1]}, got {value!r}")
    value = check_like(path, where, value, default, HyperparamError)
    if rule is not None and not rule[0](value):
        raise HyperparamError(path, where, f"expected {rule[1]}, got {value!r}")
    return value


def _build(path: Path, where: str, cls: type, table: Any, base: Any = None) -> Any:
    """An instance of dataclass ``cls`` from a TOML table, every field checked."""
    check_table(path, where, table, HyperparamError, {f.name for f in fields(cls)})
    base = base if base is not None else cls()
    values = {
        key: _check_value(path, f"{where}.{key}", value, getattr(base, key))
        for key, value in table.items()
    }
    try:
        return replace(base, **values)
    except (TypeError, ValueError) as err:
        raise HyperparamError(path, where, str(err)) from err


def _layer(
    path: Path | str, where: str, table: Any, algo: str, allowed: set[str], base: Hyperparams
) -> Hyperparams:
    """``base`` with the fields of one family or task table applied, every one checked."""
    check_table(path, where, table, HyperparamError, allowed)
    ppo = table.get("ppo") if algo == "ppo" else None
    batch = ppo.get("batch_size") if isinstance(ppo, dict) else None  # else _build names it
    if isinstance(batch, int) and not isinstance(batch, bool) and batch == 1:
        # PPO normalises the advantages over a minibatch, which one sample cannot be (SB3
        # asserted so once the environments were built); the warm start's batches may be 1.
        raise HyperparamError(path, f"{where}.ppo.batch_size", "must be 2 or more for PPO, got 1")
    top = {
        k: _check_value(path, f"{where}.{k}", table[k], getattr(base, k))
        for k in _FAMILY_KEYS
        if k in table
    }
    return replace(
        base,
        policy=_build(path, f"{where}.policy", PolicyConfig, table.get("policy", {}), base.policy),
        demos=_build(path, f"{where}.demos", DemoConfig, table.get("demos", {}), base.demos),
        init=_build(path, f"{where}.init", InitConfig, table.get("init", {}), base.init),
        algo_config=_build(
            path, f"{where}.{algo}", ALGO_CONFIGS[algo], table.get(algo, {}), base.algo_config
        ),
        **top,
    )


def _check_families(path: Path, data: dict[str, Any]) -> None:
    """Every top-level entry of the file is the table of a known task family.

    A key above the first table (``num_envs = 4`` before ``[nutbolt]``) belongs to no family, and
    a table under a mistyped family (``[peghol]``) is never read: either way runs would train with
    other values than the file shows, and nothing would say so.
    """
    families = sorted({spec.family for spec in all_tasks().values()})
    known = ", ".join(families)
    for name, table in data.items():
        if not isinstance(table, dict):
            raise HyperparamError(
                path,
                name,
                f"a key above the first table, in no family's; put it under a family's table "
                f"(known families: {known})",
            )
        if name not in families:
            close = difflib.get_close_matches(name, families, n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise HyperparamError(
                path, name, f"unknown task family {name!r}; {hint}known families: {known}"
            )


def _check_task_ids(path: Path, data: dict[str, Any]) -> None:
    """Every ``[<family>.tasks.<id>]`` table in the file names a known task of that family.

    A table under a mistyped id, or under another family than its task's, is never read: its
    task would train with the family's values and nothing would say so. The tables of every
    family are checked, since a task's table misplaced under another family is not in its own.
    """
    tasks = all_tasks()
    for family, table in data.items():
        own = table.get("tasks") if isinstance(table, dict) else None
        # A family's table of another shape is reported when that family is loaded.
        for name in own if isinstance(own, dict) else ():
            where = f"{family}.tasks.{name}"
            spec = tasks.get(name)
            if spec is None:
                ids = [t.id for t in tasks.values() if t.family == family] or list(tasks)
                raise HyperparamError(path, where, str(UnknownTaskError(name, ids)))
            if spec.family != family:
                raise HyperparamError(
                    path,
                    where,
                    f"task {name!r} is of family {spec.family!r} ({spec.source}), not "
                    f"{family!r}: its table goes under [{spec.family}.tasks.{name}]",
                )


def _file_layers(
    path: Path, table: dict[str, Any], family: str, algo: str
) -> tuple[Hyperparams, dict[str, Hyperparams]]:
    """The family's hyper-parameters for ``algo`` from its table, and each task table's."""
    base = Hyperparams(family=family, algo=algo, algo_config=ALGO_CONFIGS[algo]())  # type: ignore[arg-type]
    hp = _layer(path, family, table, algo, _FIELDS | {"tasks"}, base)
    tasks = table.get("tasks", {})
    if not isinstance(tasks, dict):
        raise HyperparamError(path, f"{family}.tasks", "expected a table of task tables")
    per_task = {
        name: _layer(path, f"{family}.tasks.{name}", task_table, algo, _FIELDS, hp)
        for name, task_table in tasks.items()
    }
    return hp, per_task


def check_hyperparams_file(path: str | Path, cells: Iterable[tuple[str, str]]) -> None:
    """Load the hyper-parameter file ``path`` for each ``(task, algo)`` of ``cells``, so that a
    caller about to start runs with it learns of a bad file (:class:`HyperparamError`) or task
    (:class:`UnknownTaskError`) before any run starts, not from every run failing."""
    for task, algo in cells:
        load_hyperparams(get_task(task).family, algo, path, task=task)


def load_hyperparams(
    family: str,
    algo: str,
    path: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    task: str | None = None,
    num_envs: int | None = None,
) -> Hyperparams:
    """Hyper-parameters for ``family`` and ``algo`` from ``path`` (default: the packaged file).

    A ``[<family>.tasks.<task>]`` table, with the fields of the family's table, changes them for
    one task. ``overrides`` are applied on top, with the same checks: algorithm fields by name,
    plus ``num_envs``, ``checkpoint_every``, ``normalize_reward``, and ``policy``, ``demos`` and
    ``init`` (each a dict of the fields of its table). ``num_envs``, where given, wins over every
    table and the overrides' own.
    """
    if num_envs is not None:
        overrides = {**(overrides or {}), "num_envs": num_envs}
    path = Path(path) if path is not None else default_path()
    if algo not in ALGO_CONFIGS:
        raise HyperparamError(path, "algo", f"expected one of {list(ALGOS)}, got {algo!r}")
    data = read_toml(path, HyperparamError)
    _check_families(path, data)
    if family not in data:
        # Mostly the task file's family is mistyped, not this file short of a table.
        spec = all_tasks().get(task) if task is not None else None
        of = "" if spec is None else f" (of task {spec.id!r}, from {spec.source})"
        raise HyperparamError(
            path,
            family,
            f"no table for task family {family!r}{of}; this file has tables for "
            f"{', '.join(sorted(data)) or 'no family'}",
        )
    _check_task_ids(path, data)
    # Every task table and the other algorithm's are checked, not only what this run uses: a
    # typo fails on first use of the file.
    for other in ALGOS:
        if other != algo:
            _file_layers(path, data[family], family, other)
    hp, per_task = _file_layers(path, data[family], family, algo)
    hp = per_task.get(task, hp)
    if overrides:
        # The same layer as a file's table, with the algorithm's fields given by name.
        table = {k: v for k, v in overrides.items() if k in _FAMILY_KEYS or k in _SUB_TABLES}
        table[algo] = {k: v for k, v in overrides.items() if k not in table}
        hp = _layer("overrides", "overrides", table, algo, _FIELDS, hp)
    rollout = hp.algo_config.n_steps * hp.num_envs
    # PPO always normalises a minibatch's advantages, A2C when asked: one sample's standard
    # deviation is NaN, and the first update turns the policy into NaN too. The two values
    # may come from different tables (the family's, the task's) or the overrides.
    normalises = isinstance(hp.algo_config, PPOConfig) or hp.algo_config.normalize_advantage
    if rollout < 2 and normalises:
        raise HyperparamError(
            path,
            "n_steps x num_envs",
            f"{algo.upper()} needs 2 or more samples a rollout to normalise advantages; "
            f"{family}'s settings for {task or algo} give n_steps {hp.algo_config.n_steps} x "
            f"num_envs {hp.num_envs}" + (" (the overrides included)" if overrides else ""),
        )
    if isinstance(hp.algo_config, PPOConfig):
        # Fewer environments than the family's (a small machine, a reward-search candidate)
        # shrink the rollout below a minibatch: train on the whole rollout at once instead.
        batch = min(hp.algo_config.batch_size, rollout)
        hp = replace(hp, algo_config=replace(hp.algo_config, batch_size=batch))
    return hp
