"""Experiment files: a TOML file naming tasks × methods × seeds and the training budget.

``experiments/validation.toml`` (the paper's validation experiment) is the worked example. Every
problem is reported with the file, the field and what was expected, before any training starts:
a reward file is checked when the experiment file is loaded as a reward search checks a sample
(compiled in the reward sandbox and run on a probe batch of its task's contexts): cells train
on it only in the sandbox (:mod:`itskill.experiments.sandboxed`), since it is usually generated
code, a search's ``best_reward.py``.

Fields (``[eval]``, ``[report]`` and ``[execution]`` are tables; everything but ``tasks``,
``methods``, ``steps`` and ``eval.every`` has a default)::

    name (default: the file's stem; a plain directory name), description
    tasks = [task ids]           methods = [itn, nia, dfs, pst, no_transfer]
    seeds = 5 (at most 1000) | [0, 1, ...]   algo = "a2c" | "ppo"   steps = env-steps per cell
    num_envs = N (at most 1024)  (default: the family's, from the hyper-parameter table)
    reward = "expert" | {task = "file.py", ...}   (paths relative to the experiment file)
    sources = "auto" | {task = [skill names or ids], ...}
    k = sources retrieved by "auto" (at most 32)
    llm = "offline" | "openai:MODEL"              (the analyzer's client)
    [hyperparams.<task>] hyper-parameters of the task's cells, on top of the packaged ones:
                 the algorithm's fields by name (learning_rate = 1e-5), policy = {...},
                 demos = {...}, init = {...}, checkpoint_every, normalize_reward
                 (docs/experiments.md)
    [transfer] settings of the transfer methods, on top of the packaged transfer.toml, in its
                 tables: [transfer.pst] keep = 2, [transfer.attention] prior_weight = 0.3, ...
    [eval] every, episodes (at most 1,000,000)
    [report] threshold, fractions (strictly increasing), baseline, grid_points, paper_gain
    [execution] executor, workers (at most 1024), ray_address
"""

from __future__ import annotations

import itertools
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from itskill.datafile import DataFileError, check_positive, check_table, check_type, read_toml
from itskill.executors import EXECUTORS
from itskill.limits import (
    EPISODES_MAX,
    NUM_ENVS_MAX,
    SEED_COUNT_MAX,
    SOURCES_MAX,
    STEPS_MAX,
    WORKERS_MAX,
)
from itskill.llm.client import UnknownModelError, model_spec
from itskill.reward.config import check_seeds
from itskill.reward_contract import EXPERT
from itskill.rl.config import ALGOS, HyperparamError, load_hyperparams
from itskill.rl.train import RESUMABLE_CHANGES
from itskill.tasks import UnknownTaskError, get_task

if TYPE_CHECKING:
    from itskill.transfer.config import TransferConfig

AUTO = "auto"
MAX_NAME_BYTES = 100
"""Well inside the file systems' 255 bytes per directory name, and a path one can still read."""
MAX_GRID_POINTS = 100_000
"""A figure's curves have no use for more points; each method's band is seeds × points floats."""


class ExperimentConfigError(DataFileError):
    """An experiment file that does not validate: names the file, the field and the problem."""


@dataclass(frozen=True)
class EvalSettings:
    """Deterministic evaluation during training: every ``every`` env-steps, ``episodes`` each."""

    every: int
    episodes: int = 50


@dataclass(frozen=True)
class ReportSettings:
    """What the report measures; the defaults are the paper's (80% success, Table II's fifths)."""

    threshold: float = 0.8
    fractions: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8, 1.0)
    baseline: str = "no_transfer"
    grid_points: int = 101
    paper_gain: dict[str, float] = field(default_factory=dict)
    """The paper's reported gain per task, printed next to the measured one."""


@dataclass(frozen=True)
class ExecutionSettings:
    """Where the cells run (:func:`itskill.executors.run_jobs`); command-line options override."""

    executor: str = "local"
    workers: int | None = None
    ray_address: str | None = None


@dataclass(frozen=True)
class ExperimentConfig:
    """A validated experiment file."""

    name: str
    tasks: tuple[str, ...]
    methods: tuple[str, ...]
    seeds: tuple[int, ...]
    steps: int
    eval: EvalSettings
    algo: str = "a2c"
    num_envs: int | None = None
    reward: dict[str, str] = field(default_factory=dict)
    """Task -> ``"expert"`` or an absolute path to a reward file."""
    sources: dict[str, str | tuple[str, ...]] = field(default_factory=dict)
    """Task -> ``"auto"`` or the source skills' names/ids."""
    k: int = 3
    llm: str = "offline"
    hyperparams: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Task -> the hyper-parameters its cells change (``overrides`` of
    :func:`itskill.rl.config.load_hyperparams`): a file that names them trains the same way
    after the packaged defaults change."""
    transfer: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The ``[transfer]`` tables, as ``transfer.toml`` has them (``{"pst": {"keep": 2}}``):
    the settings of the transfer methods the cells change (:meth:`transfer_config`)."""
    description: str = ""
    report: ReportSettings = field(default_factory=ReportSettings)
    execution: ExecutionSettings = field(default_factory=ExecutionSettings)

    def training_settings(self) -> dict[str, Any]:
        """What decides a cell's training: a resumed run must have the same."""
        return {
            "algo": self.algo,
            "steps": self.steps,
            "num_envs": self.num_envs,
            "reward": self.reward,
            "sources": {t: list(s) if isinstance(s, tuple) else s for t, s in self.sources.items()},
            "k": self.k,
            "llm": self.llm,
            "eval": asdict(self.eval),
            # What a resumed run may change does not count (how often it checkpoints).
            "hyperparams": {t: _trained_with(self.hyperparams.get(t, {})) for t in self.tasks},
            "transfer": self.network_settings(),
        }

    def transfer_config(self) -> TransferConfig:
        """The settings the cells' transfer methods train with: the packaged ``transfer.toml``
        with the file's ``[transfer]`` tables on top (checked when the file was loaded), and the
        file's ``k``."""
        from itskill.transfer.config import load_transfer_config, parse_transfer_config

        config = parse_transfer_config(self.transfer, "[transfer]", base=load_transfer_config())
        return replace(config, k=self.k)

    def transfer_key(self, name: str) -> str | None:
        """Where the file sets :class:`TransferConfig` field ``name`` (``transfer.pst.keep``),
        or None where it leaves it to the packaged ``transfer.toml``."""
        from itskill.transfer.config import setting_key

        table, key = setting_key(name)
        return f"transfer.{table}.{key}" if key in self.transfer.get(table, {}) else None

    def network_settings(self) -> dict[str, Any]:
        """The transfer settings the experiment's methods build their networks and choose among
        their sources with (:attr:`itskill.transfer.methods.Method.settings`), by field: what
        decides how a cell trains once its sources are stored, written out or packaged alike."""
        from itskill.transfer.methods import used_settings

        return used_settings(self.methods, self.transfer_config().to_dict())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (written to the run directory as ``config.json``)."""
        return json.loads(json.dumps(asdict(self)))


def _trained_with(table: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in table.items() if k not in RESUMABLE_CHANGES}


# ---------------------------------------------------------------------- loading
_TOP = {
    "name", "description", "tasks", "methods", "seeds", "algo", "steps", "num_envs", "reward",
    "sources", "k", "llm", "hyperparams", "transfer", "eval", "report", "execution",
}  # fmt: skip


def _typed(path: Path, where: str, value: Any, kind: type | tuple[type, ...]) -> Any:
    return check_type(path, where, value, kind, ExperimentConfigError)


def _table(path: Path, where: str, value: Any, allowed: set[str]) -> dict[str, Any]:
    return check_table(path, where, value, ExperimentConfigError, allowed)


def _positive(path: Path, where: str, value: Any, most: int | None = None) -> int:
    return check_positive(path, where, value, ExperimentConfigError, most)


def _strings(path: Path, where: str, value: Any) -> tuple[str, ...]:
    items = _typed(path, where, value, list)
    if not items:
        raise ExperimentConfigError(path, where, "must not be empty")
    for i, item in enumerate(items):
        _typed(path, f"{where}[{i}]", item, str)
    if len(set(items)) != len(items):
        raise ExperimentConfigError(path, where, f"duplicate entries in {items}")
    return tuple(items)


def _name(path: Path, value: Any) -> str:
    """The experiment's name, which names its run directory (``runs/experiments/<name>``): one
    plain directory name, so that no name puts the run outside that folder or over the cwd."""
    name = _typed(path, "name", value, str)
    if (
        not name.strip()
        or name == "."
        or not name.isprintable()  # NUL makes no directory name, a control character a bad one
        or any(bad in name for bad in ("/", "\\", ".."))
    ):
        raise ExperimentConfigError(
            path,
            "name",
            f"expected a plain, non-empty name (it names the run directory) of printable "
            f"characters without '/', '\\' or '..', got {name!r}",
        )
    size = len(name.encode("utf-8"))
    if size > MAX_NAME_BYTES:
        raise ExperimentConfigError(
            path, "name", f"too long for a directory name: {size} bytes (UTF-8), at most "
            f"{MAX_NAME_BYTES}"
        )  # fmt: skip
    return name


def _per_task(
    path: Path, where: str, value: Any, tasks: tuple[str, ...], default: Any
) -> dict[str, Any]:
    """A value for every task: one for all, or a table ``{task = value}`` (missing -> default)."""
    if not isinstance(value, dict):
        return dict.fromkeys(tasks, value)
    unknown = sorted(set(value) - set(tasks))
    if unknown:
        raise ExperimentConfigError(
            path, f"{where}.{unknown[0]}", f"not one of the experiment's tasks {list(tasks)}"
        )
    return {t: value.get(t, default) for t in tasks}


def _parse_hyperparams(
    path: Path,
    value: Any,
    tasks: tuple[str, ...],
    algo: str,
    num_envs: int | None,
    recorded: bool,
) -> dict[str, dict[str, Any]]:
    """Each task's ``[hyperparams.<task>]``, checked with the file's ``num_envs`` as the
    hyper-parameter loader checks them for training (a recorded run's only for its form: its
    tasks may not exist here)."""
    tables = _typed(path, "hyperparams", value, dict)
    found: dict[str, dict[str, Any]] = {}
    for task, table in tables.items():
        where = f"hyperparams.{task}"
        if task not in tasks:
            raise ExperimentConfigError(
                path, where, f"not one of the experiment's tasks {list(tasks)}"
            )
        table = _typed(path, where, table, dict)
        if "num_envs" in table:
            # The cells' num_envs is the file's top-level one, which would win unseen.
            raise ExperimentConfigError(
                path, f"{where}.num_envs", "set num_envs at the top of the file, for every task"
            )
        if not recorded:
            spec = get_task(task)
            try:
                load_hyperparams(
                    spec.family, algo, overrides=table, task=spec.id, num_envs=num_envs
                )
            except HyperparamError as err:
                # Named as this file has it: algorithm fields by name, no "overrides" table.
                if err.where.startswith("overrides."):
                    where += "." + err.where.removeprefix("overrides.").removeprefix(f"{algo}.")
                raise ExperimentConfigError(path, where, err.problem) from err
        found[task] = table
    return found


def _parse_transfer(path: Path, value: Any) -> dict[str, dict[str, Any]]:
    """The ``[transfer]`` tables, checked as ``transfer.toml``'s are, but for how many sources
    ``auto`` retrieves, which is the file's ``k``."""
    from itskill.transfer.config import TransferConfigError, parse_transfer_config

    tables = _typed(path, "transfer", value, dict)
    try:
        parse_transfer_config(tables, path)
    except TransferConfigError as err:
        raise ExperimentConfigError(path, f"transfer.{err.where}", err.problem) from err
    if "k" in tables.get("sources", {}):
        raise ExperimentConfigError(
            path, "transfer.sources.k", "set k at the top of the file (how many auto retrieves)"
        )
    return tables


def _check_reward_file(path: Path, where: str, file: Path, task: str) -> None:
    """Check ``file`` for ``task`` as training will run it (in the reward sandbox, on a probe
    batch), so a broken reward file is refused here instead of failing every cell of the task."""
    from itskill.experiments.sandboxed import check_reward_file

    problem = check_reward_file(file, task)
    if problem is not None:
        raise ExperimentConfigError(path, where, f"{file}: {problem}")


def parse_experiment(data: dict[str, Any], path: Path, recorded: bool = False) -> ExperimentConfig:
    """Validate a parsed experiment file; relative reward paths are resolved against ``path``.

    ``recorded``: ``data`` is a run's ``config.json`` (:meth:`ExperimentConfig.to_dict`). Its
    values are checked as a file's are, but not that its tasks and reward files exist here: a
    report may read a run made on another machine, or with a tasks folder that is not set now.
    """
    from itskill.transfer import METHODS

    raw = _table(path, "", data, _TOP)
    # A record always names its run: without one it would take the file's name, "config".
    for key in ("tasks", "methods", "steps", "eval", *(("name",) if recorded else ())):
        if key not in raw:
            raise ExperimentConfigError(path, key, "missing (required)")
    tasks = _strings(path, "tasks", raw["tasks"])
    for i, task in enumerate(() if recorded else tasks):
        try:
            get_task(task)
        except UnknownTaskError as err:
            raise ExperimentConfigError(path, f"tasks[{i}]", str(err)) from err
    methods = _strings(path, "methods", raw["methods"])
    for i, method in enumerate(methods):
        if method not in METHODS:
            raise ExperimentConfigError(
                path, f"methods[{i}]", f"unknown method {method!r}; expected one of {list(METHODS)}"
            )
    seeds_raw = raw.get("seeds", 5)
    if isinstance(seeds_raw, list):
        seeds = tuple(_typed(path, f"seeds[{i}]", s, int) for i, s in enumerate(seeds_raw))
        check_seeds(path, "seeds", seeds, ExperimentConfigError)
    else:
        count = _positive(path, "seeds", seeds_raw)
        if count > SEED_COUNT_MAX:
            # A mistyped count (50000 for 5) would queue that many runs per task and method, and
            # a huge one hang building them; more than this is listed on purpose.
            raise ExperimentConfigError(
                path, "seeds", f"at most {SEED_COUNT_MAX} as a count, got {count}; list the "
                "seeds to run more"
            )  # fmt: skip
        seeds = tuple(range(count))
    algo = _typed(path, "algo", raw.get("algo", "a2c"), str)
    if algo not in ALGOS:
        raise ExperimentConfigError(path, "algo", f"expected one of {list(ALGOS)}, got {algo!r}")
    steps = _positive(path, "steps", raw["steps"], STEPS_MAX)
    num_envs = raw.get("num_envs")
    if num_envs is not None:
        # More crashed every cell at allocation, after the run was made (itskill.limits).
        _positive(path, "num_envs", num_envs, NUM_ENVS_MAX)

    reward = {}
    for task, value in _per_task(path, "reward", raw.get("reward", EXPERT), tasks, EXPERT).items():
        where = f"reward.{task}" if isinstance(raw.get("reward"), dict) else "reward"
        _typed(path, where, value, str)
        if value == EXPERT or recorded:
            reward[task] = value
            continue
        file = (path.parent / value).resolve()
        if file.suffix != ".py" or not file.is_file():
            raise ExperimentConfigError(
                path, where, f"expected {EXPERT!r} or an existing .py reward file, got {value!r}"
            )
        _check_reward_file(path, where, file, task)
        reward[task] = str(file)

    sources: dict[str, str | tuple[str, ...]] = {}
    for task, value in _per_task(path, "sources", raw.get("sources", AUTO), tasks, AUTO).items():
        where = f"sources.{task}" if isinstance(raw.get("sources"), dict) else "sources"
        if value == AUTO:
            sources[task] = AUTO
        elif isinstance(value, list) and value:
            sources[task] = tuple(str(_typed(path, where, v, (str, int))) for v in value)
        else:
            raise ExperimentConfigError(
                path, where, f"expected {AUTO!r} or a list of skill names/ids, got {value!r}"
            )

    ev = _table(path, "eval", raw["eval"], {"every", "episodes"})
    if "every" not in ev:
        raise ExperimentConfigError(path, "eval.every", "missing (required)")
    evaluation = EvalSettings(
        _positive(path, "eval.every", ev["every"]),
        # More made every cell fail with MemoryError after its training (itskill.limits).
        _positive(path, "eval.episodes", ev.get("episodes", 50), EPISODES_MAX),
    )
    if evaluation.every > steps:
        raise ExperimentConfigError(
            path, "eval.every", f"{evaluation.every} is more than steps ({steps}): no curve"
        )
    llm = _typed(path, "llm", raw.get("llm", "offline"), str)
    try:
        model_spec(llm)  # parses the spec only: loading a file never contacts a model
    except UnknownModelError as err:
        raise ExperimentConfigError(path, "llm", str(err)) from err
    report = _parse_report(path, raw.get("report", {}), tasks, recorded)
    execution = _parse_execution(path, raw.get("execution", {}))
    return ExperimentConfig(
        name=_name(path, raw.get("name", path.stem)),
        description=_typed(path, "description", raw.get("description", ""), str),
        tasks=tasks,
        methods=methods,
        seeds=seeds,
        steps=steps,
        eval=evaluation,
        algo=algo,
        num_envs=num_envs,
        reward=reward,
        sources=sources,
        # More retrieved and ran thousands of frozen sources in every cell (itskill.limits).
        k=_positive(path, "k", raw.get("k", 3), SOURCES_MAX),
        llm=llm,
        hyperparams=_parse_hyperparams(
            path, raw.get("hyperparams", {}), tasks, algo, num_envs, recorded
        ),
        transfer=_parse_transfer(path, raw.get("transfer", {})),
        report=report,
        execution=execution,
    )


def _parse_report(path: Path, value: Any, tasks: tuple[str, ...], recorded: bool) -> ReportSettings:
    allowed = {"threshold", "fractions", "baseline", "grid_points", "paper_gain"}
    rep = _table(path, "report", value, allowed)
    default = ReportSettings()
    threshold = _typed(path, "report.threshold", rep.get("threshold", default.threshold), float)
    if not 0 < threshold <= 1:
        raise ExperimentConfigError(path, "report.threshold", f"expected (0, 1], got {threshold}")
    fractions_raw = _typed(
        path, "report.fractions", rep.get("fractions", [0.2, 0.4, 0.6, 0.8, 1]), list
    )
    fractions = tuple(
        _typed(path, f"report.fractions[{i}]", f, float) for i, f in enumerate(fractions_raw)
    )
    # Strictly increasing: a repeated fraction is a repeated column of the report's table.
    if (
        not fractions
        or any(not 0 < f <= 1 for f in fractions)
        or any(a >= b for a, b in itertools.pairwise(fractions))
    ):
        raise ExperimentConfigError(
            path,
            "report.fractions",
            f"expected strictly increasing values in (0, 1], got {fractions_raw}",
        )
    baseline = _typed(path, "report.baseline", rep.get("baseline", default.baseline), str)
    # A baseline need not be among the methods: its runs may come from another experiment run
    # (`itskill report --baseline-run`), and without them the report has no gain column. A
    # name no method has is a typo (a run's record always names its baseline).
    from itskill.transfer import METHODS

    if "baseline" in rep and not recorded and baseline not in METHODS:
        raise ExperimentConfigError(
            path, "report.baseline", f"unknown method {baseline!r}; expected one of {list(METHODS)}"
        )
    points = _typed(path, "report.grid_points", rep.get("grid_points", default.grid_points), int)
    if not 2 <= points <= MAX_GRID_POINTS:
        raise ExperimentConfigError(
            path, "report.grid_points", f"expected 2 to {MAX_GRID_POINTS:,} points, got {points:,}"
        )
    paper = _table(path, "report.paper_gain", rep.get("paper_gain", {}), set(tasks))
    paper_gain = {t: _gain(path, f"report.paper_gain.{t}", g) for t, g in paper.items()}
    return ReportSettings(threshold, fractions, baseline, points, paper_gain)


def _gain(path: Path, where: str, value: Any) -> float:
    """A time-efficiency gain, 1 − method/baseline: a fraction below 1 (negative when slower)."""
    gain = _typed(path, where, value, float)
    if gain >= 1:
        raise ExperimentConfigError(
            path, where, f"expected a fraction below 1 (0.7222 for 72.22%), got {value}"
        )
    return gain


def _parse_execution(path: Path, value: Any) -> ExecutionSettings:
    ex = _table(path, "execution", value, {"executor", "workers", "ray_address"})
    executor = _typed(path, "execution.executor", ex.get("executor", "local"), str)
    if executor not in EXECUTORS:
        raise ExperimentConfigError(
            path, "execution.executor", f"expected one of {list(EXECUTORS)}, got {executor!r}"
        )
    workers = ex.get("workers")
    if workers is not None:
        # More started processes until the machine gave out (itskill.limits).
        _positive(path, "execution.workers", workers, WORKERS_MAX)
    address = ex.get("ray_address")
    if address is not None:
        _typed(path, "execution.ray_address", address, str)
        if not address.strip():
            raise ExperimentConfigError(
                path, "execution.ray_address", "empty: leave it out for a local Ray instance"
            )
    return ExecutionSettings(executor, workers, address)


def load_experiment(path: str | Path) -> ExperimentConfig:
    """Read and validate an experiment file (:class:`ExperimentConfigError` says what is wrong)."""
    path = Path(path)
    if not path.is_file():
        why = "a directory, not a file" if path.is_dir() else "no such experiment file"
        raise ExperimentConfigError(path, "file", why)
    data = read_toml(path, ExperimentConfigError)
    return parse_experiment(data, path)
