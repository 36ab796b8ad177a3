"""Run an experiment: every task × method × seed cell as a job, locally or on Ray, resumably.

Run directory layout::

    <run>/experiment.toml        the experiment file as given
    <run>/config.json            the validated configuration (a resume must match its training part)
    <run>/sources.json           the source skills of each task, resolved once for every cell
    <run>/provenance.json        one entry per session: command, machine, start, end, wall time
    <run>/llm_cache/             the analyzer's cached replies (an LLM is asked once per question)
    <run>/cells/<task>/<method>/seed_<s>/   the transfer run (checkpoints, metrics.csv, eval.csv,
                                           transfer.json) and, once finished, result.json

A cell with ``result.json`` is done and skipped; a cell with only a checkpoint resumes from it
(the trainer continues the step count); the others start. Each ``result.json`` is written by the
worker that trained the cell, atomically, so a killed run loses only the cells in flight.
``config.json`` is what makes a directory a run: it is written before anything else of the run.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from itskill.curves import read_curve
from itskill.datafile import is_count, is_number
from itskill.executors import check_executor, run_jobs
from itskill.experiments.analysis import time_to_threshold
from itskill.experiments.config import (
    AUTO,
    ExperimentConfig,
    ExperimentConfigError,
    parse_experiment,
)
from itskill.experiments.provenance import Sessions
from itskill.files import (
    Check,
    CorruptFileError,
    check_shape,
    copy_whole,
    foreign_entries,
    held_alone,
    read_json,
    read_json_or_none,
    some_of,
    write_json,
    write_text,
)
from itskill.reward_contract import EXPERT

if TYPE_CHECKING:
    from itskill.transfer.config import TransferConfig

CELLS_DIR = "cells"
RESULT_FILE = "result.json"
CONFIG_FILE = "config.json"
SOURCES_FILE = "sources.json"
PROVENANCE_FILE = "provenance.json"
EXPERIMENT_FILE = "experiment.toml"
ERROR_FILE = "error.txt"
REWARDS_DIR = "rewards"
"""The run's copy of each task's reward file (``<task>.py``), which its cells train with."""


class ExperimentRunError(ValueError):
    """A run directory that cannot be used for this experiment: says why and what to do."""


@dataclass(frozen=True)
class Cell:
    """One training run of the experiment."""

    task: str
    method: str
    seed: int

    @property
    def name(self) -> str:
        return f"{self.task}/{self.method}/seed_{self.seed}"

    def dir(self, run_dir: Path) -> Path:
        return Path(run_dir) / CELLS_DIR / self.task / self.method / f"seed_{self.seed}"


def cells(config: ExperimentConfig) -> list[Cell]:
    """Every cell, seed by seed: a run stopped half-way has whole seeds of every method."""
    return [
        Cell(task, method, seed)
        for seed in config.seeds
        for task in config.tasks
        for method in config.methods
    ]


@dataclass(frozen=True)
class CellSettings:
    """What a worker needs to train one cell (picklable, for local processes and Ray)."""

    algo: str
    steps: int
    num_envs: int | None
    reward: str
    sources: tuple[str, ...]
    llm: str
    eval_every: int
    eval_episodes: int
    threshold: float
    llm_cache: str
    hyperparams: dict[str, Any] = field(default_factory=dict)
    """The experiment file's ``[hyperparams.<task>]`` for the cell's task."""
    transfer: TransferConfig | None = None
    """The transfer methods' settings (None: the packaged ``transfer.toml``)."""


def run_cell(cell: Cell, settings: CellSettings, out: Path) -> dict[str, Any]:
    """Train one cell into ``out`` (resuming a partial run) and write its ``result.json``."""
    from itskill.experiments.sandboxed import train_transfer_on
    from itskill.llm.client import LazyClient

    # A reward file is usually a search's best_reward.py: generated code, run only in the sandbox.
    res = train_transfer_on(
        settings.reward,
        "file",
        "the cell's process",
        target=cell.task,
        method=cell.method,
        sources=list(settings.sources),
        seed=cell.seed,
        steps=settings.steps,
        algo=settings.algo,
        out=out,
        num_envs=settings.num_envs,
        eval_every=settings.eval_every,
        eval_episodes=settings.eval_episodes,
        n_threads=1,
        # Made only if the analyzer is asked: a cell that asks no model needs no API key.
        client=LazyClient(settings.llm, cache_dir=Path(settings.llm_cache)),
        progress=False,
        overrides=settings.hyperparams,
        config=settings.transfer,
    )
    curve = read_curve(out, settings.steps)
    hit = time_to_threshold([curve], settings.threshold)
    result = {
        "task": cell.task,
        "method": cell.method,
        "seed": cell.seed,
        "num_timesteps": res.num_timesteps,
        "resumed_from": res.resumed_from,
        "session_wall_s": round(res.session_wall_s, 2),
        "train_wall_s": round(float(curve.wall_s[-1]), 2),
        "final_success": float(curve.success[-1]),
        "threshold": settings.threshold,
        "steps_to_threshold": float(hit.steps[0]) if hit.reached[0] else None,
        "wall_s_to_threshold": float(hit.wall_s[0]) if hit.reached[0] else None,
        # The evaluation that chose the cell's best/ policy.
        "best": res.best,
    }
    write_json(out / RESULT_FILE, result)
    (out / ERROR_FILE).unlink(missing_ok=True)  # a failure of an earlier session is fixed
    return result


@dataclass
class RunSummary:
    """What a call of :func:`run_experiment` did."""

    run_dir: Path
    finished: list[Cell] = field(default_factory=list)
    skipped: list[Cell] = field(default_factory=list)
    resumed: list[Cell] = field(default_factory=list)
    failed: dict[Cell, str] = field(default_factory=dict)


def _recorded_run(
    config: ExperimentConfig, run_dir: Path, resume: bool, source_file: Path | None
) -> ExperimentConfig | None:
    """The configuration ``run_dir`` records, once this call may use it; None for a new run.

    It only reads, so a refused call leaves ``run_dir`` as it was. A new run is refused a
    directory that holds anything but ``source_file`` itself (the experiment file may live in
    the folder of its run): the run would overwrite the user's files or mix with them.
    """
    if (run_dir / CONFIG_FILE).is_file():
        old = read_run_config(run_dir)  # another kind of run is named as such, first
        if not resume:
            raise ExperimentRunError(
                f"{run_dir} already holds an experiment run; pass --resume to continue it, "
                "or choose another --out"
            )
        _check_same_training(old, config, run_dir)
        _not_a_copy(run_dir)
        return old
    if resume:
        what = "is not an experiment run directory" if run_dir.exists() else "does not exist"
        raise ExperimentRunError(
            f"nothing to resume: {run_dir} {what} (no {CONFIG_FILE}); give the run's --out, "
            "or leave out --resume to start a new run"
        )
    if run_dir.exists() and not run_dir.is_dir():
        raise ExperimentRunError(
            f"{run_dir}: not a directory; give --out a new or empty directory for the run"
        )
    foreign = foreign_entries(
        run_dir, lambda name: source_file is not None and _same_file(run_dir / name, source_file)
    )
    if foreign:
        raise ExperimentRunError(
            f"{run_dir}: holds {some_of(foreign)} and is not an experiment run "
            f"(no {CONFIG_FILE}); a new run would overwrite or mix with them: give --out a "
            "new or empty directory"
        )
    return None


def reward_copy(run_dir: Path, task: str) -> Path:
    """Where the run keeps the reward file it trains ``task`` with."""
    return run_dir / REWARDS_DIR / f"{task}.py"


def _reward_files(config: ExperimentConfig) -> dict[str, Path]:
    """Task -> the reward file the experiment names for it (the expert reward's tasks left out)."""
    return {task: Path(reward) for task, reward in config.reward.items() if reward != EXPERT}


def _check_rewards_unchanged(rewards: dict[str, Path], run_dir: Path) -> None:
    """Refuse a resume whose reward file was edited since the run copied it: the cells still to
    train would learn another reward than the finished ones, and the report mix the two. A run
    from before the copies were kept is checked against what its cells' checkpoints record."""
    for task, reward in rewards.items():
        trained, copy = reward_hashes(run_dir, task), reward_copy(run_dir, task)
        changed = bool(trained) and hashlib.sha256(reward.read_bytes()).hexdigest() not in trained
        if changed:
            version = (
                f"that version is in {copy}"
                if copy.is_file()
                else "its cells' checkpoints record another sha256"
            )
            raise ExperimentRunError(
                f"{reward}: changed since {run_dir} started training {task} with it ({version}); "
                "put it back to resume, or use another --out"
            )


def reward_hashes(run_dir: Path, task: str) -> set[str]:
    """The sha256 of the reward file ``run_dir`` trained ``task`` with: of its copy, else those
    its cells' checkpoints record (a run from before copies were kept; empty if neither)."""
    copy = reward_copy(run_dir, task)
    if copy.is_file():
        return {hashlib.sha256(copy.read_bytes()).hexdigest()}
    return trained_reward_hashes(run_dir, task)


def trained_reward_hashes(run_dir: Path, task: str) -> set[str]:
    """The sha256 of the reward file every cell of ``task`` with a checkpoint trained with."""
    return _recorded(run_dir, task, lambda meta: meta["reward"]["sha256"])


def trained_task_hashes(run_dir: Path, task: str) -> set[str]:
    """The fingerprints of ``task`` (:attr:`TaskSpec.fingerprint`) its cells with a checkpoint
    trained on; a checkpoint from before they were recorded adds none."""
    return _recorded(run_dir, task, lambda meta: meta["task_sha256"])


def _recorded(run_dir: Path, task: str, read: Callable[[dict[str, Any]], Any]) -> set[str]:
    """What ``read`` gives of each checkpoint record of ``task``'s cells, where it gives one."""
    found = set()
    for meta in (run_dir / CELLS_DIR / task).glob("*/*/checkpoint.json"):
        try:
            found.add(str(read(read_json(meta))))
        except (CorruptFileError, KeyError, TypeError):
            continue  # a damaged checkpoint is the cell's own error when it resumes
    return found


def _first_record(
    candidates: Iterable[Cell], run_dir: Path, read: Callable[[Path], dict[str, Any]]
) -> dict[str, Any] | None:
    """What ``read`` gives of the first finished cell of ``candidates`` in ``run_dir`` whose
    record it can read (a damaged one is that cell's own error); None where there is none."""
    from itskill.rl.checkpoint import CheckpointError

    for cell in candidates:
        if finished_result(cell.dir(run_dir)) is not None:
            try:
                return read(cell.dir(run_dir))
            except CheckpointError:
                continue
    return None


def recorded_training(config: ExperimentConfig, run_dir: Path, task: str) -> dict | None:
    """The settings of the algorithm, the network and the reward's normalisation that the first
    finished cell of ``task`` in ``run_dir`` recorded in its checkpoint (every method's cells
    share them); None where no finished cell has a readable one."""
    from itskill.rl.checkpoint import read_meta

    saved = _first_record((c for c in cells(config) if c.task == task), run_dir, read_meta)
    return None if saved is None else _training_part(saved["hyperparams"], saved["algo"])


def _training_part(hyperparams: dict[str, Any], algo: str) -> dict[str, Any]:
    """What :func:`recorded_training` compares of a run's hyper-parameters."""
    return {
        key: hyperparams[key] for key in (algo, "policy", "normalize_reward") if key in hyperparams
    }


def _check_as_recorded(
    config: ExperimentConfig, record: ExperimentConfig, run_dir: Path, new: list[Cell]
) -> None:
    """Refuse a session whose new cells would train, by the file ``config``, otherwise than the
    finished cells of the run (``record``: every session's grid) of their task (and, for the
    transfer settings, their method) recorded: another version of the task, other
    hyper-parameters or network settings, or another version of the expert reward. The file's
    settings were compared already; the packaged ones under them, the task's file and the
    expert reward's code may have changed since the run began (another itskill release), and
    the new seeds would learn beside the old ones under them. Cells resumed from a checkpoint
    are checked against their own records."""
    from itskill.rl.checkpoint import TASK_CHANGED
    from itskill.rl.config import load_hyperparams
    from itskill.rl.train import changed_settings
    from itskill.tasks import get_task
    from itskill.tasks.rewards import expert_fingerprint
    from itskill.transfer import get_method
    from itskill.transfer.methods import used_settings
    from itskill.transfer.train import network_settings, read_transfer

    def refuse(what: str, differ: list[str]) -> ExperimentRunError:
        return ExperimentRunError(
            f"{run_dir}: its finished {what} trained with other settings than new ones would "
            f"now ({'; '.join(differ)}: recorded -> now), packaged defaults having changed "
            "since; name the recorded values in the experiment file, or use another --out"
        )

    for task in dict.fromkeys(cell.task for cell in new):
        trained_on = trained_task_hashes(run_dir, task)
        if trained_on and get_task(task).fingerprint not in trained_on:
            raise ExperimentRunError(
                f"{run_dir}: its cells of {task} trained on the task as it was then "
                f"({TASK_CHANGED}): new seeds would learn another task beside them; use another "
                "--out"
            )
        if config.reward.get(task, EXPERT) == EXPERT:
            trained = trained_reward_hashes(run_dir, task)
            if trained and expert_fingerprint(get_task(task)) not in trained:
                raise ExperimentRunError(
                    f"{run_dir}: its cells of {task} trained with another version of the expert "
                    "reward (its code or the task's stages changed since the run began): new "
                    "seeds would learn another reward beside them; use another --out"
                )
        have = recorded_training(record, run_dir, task)
        if have is None:
            continue
        hp = load_hyperparams(
            get_task(task).family,
            config.algo,
            overrides=config.hyperparams.get(task),
            task=task,
            num_envs=config.num_envs,
        )
        differ = changed_settings(have, _training_part(hp.to_dict(), config.algo))
        if differ:
            raise refuse(f"cells of {task}", differ)
    now = config.transfer_config().to_dict()
    for method in dict.fromkeys(cell.method for cell in new if get_method(cell.method).settings):
        of_method = (c for c in cells(record) if c.method == method)
        have = _first_record(of_method, run_dir, lambda d: network_settings(read_transfer(d)))
        differ = [] if have is None else changed_settings(have, used_settings([method], now))
        if differ:
            raise refuse(f"{method} cells", differ)


def _same_file(a: Path, b: Path) -> bool:
    return a.exists() and b.exists() and os.path.samefile(a, b)


def _not_a_copy(run_dir: Path) -> None:
    """Refuse to resume ``run_dir`` if a cell holds a checkpoint's record without its weights:
    what ``itskill report RUN --out DIR`` copies, whose cells cannot train on, and whose results
    folder the new cells would fill."""
    for record in sorted((run_dir / CELLS_DIR).glob("*/*/seed_*/checkpoint.json")):
        if not (record.parent / "model.zip").is_file():
            raise ExperimentRunError(
                f"{run_dir}: its cell {record.parent.relative_to(run_dir)} has a checkpoint "
                "record but no weights: a report's copy of a run (or a run whose weights were "
                "deleted) cannot be resumed; resume the run itself"
            )


def read_run_config(run_dir: Path) -> ExperimentConfig:
    """The configuration recorded in an experiment run directory; :class:`ExperimentRunError`
    if ``run_dir/config.json`` is another kind of run's (a reward search's), damaged, or holds a
    value an experiment file could not have (every field is checked as the file's were: the
    report formats them, and ``report.threshold = "x"`` failed deep in it), or missing."""
    path = run_dir / CONFIG_FILE
    if not path.is_file():
        raise ExperimentRunError(
            f"{run_dir}: not an experiment run directory (no {CONFIG_FILE}); "
            "run `itskill experiment run FILE.toml` first"
        )
    data = read_json(path)
    kind = data.get("kind") if isinstance(data, dict) else None
    if kind is not None:
        raise ExperimentRunError(
            f"{run_dir} holds another kind of run ({kind!r}), not an experiment run"
        )
    try:
        return parse_experiment(data, path, recorded=True)
    except ExperimentConfigError as err:
        raise ExperimentRunError(f"{err}; was it edited?") from err


def _check_same_training(old: ExperimentConfig, new: ExperimentConfig, run_dir: Path) -> None:
    """Refuse a resume whose file changes a setting the run's cells were trained with. The
    sources and ``k`` matter only to a run of methods that use sources (``k`` only where a task
    retrieved them), and the analyzer's ``llm`` only to one of methods that use its matrix: a
    No_Transfer run resumed to add ITN may name them anew. A run recorded before experiment
    files named hyper-parameters or transfer settings may be resumed with a file that names
    them."""
    from itskill.transfer import get_method

    have, want = old.training_settings(), new.training_settings()
    methods = [get_method(m) for m in old.methods]
    retrieved = any(old.sources.get(task, AUTO) == AUTO for task in old.tasks)
    unused = {
        *(() if any(m.uses_sources for m in methods) else ("sources", "k")),
        *(() if any(m.uses_prior for m in methods) else ("llm",)),
        # How many to retrieve matters only where sources were retrieved, not named.
        *(() if retrieved else ("k",)),
    }
    recorded = read_json(run_dir / CONFIG_FILE)
    # Recorded before files could name them: the cells trained with the packaged ones of their
    # day, which the file may now name; a cell resumed is checked against what its checkpoint
    # and transfer record hold, and the report shows the settings every cell trained with.
    unused.update(key for key in ("hyperparams", "transfer") if key not in recorded)
    for key in (k for k in want if k not in unused):
        mismatch = have.get(key) != want[key]
        if key in ("reward", "sources", "hyperparams"):  # per task: a task added brings its own
            mismatch = any(have[key].get(t, want[key][t]) != want[key][t] for t in want[key])
        if key == "transfer":
            # Those both the trained and the named methods use: a method added brings its own,
            # a method left out takes its settings along (its cells are checked against their
            # own records when they resume).
            mismatch = any(want[key].get(name, v) != v for name, v in have[key].items())
        if mismatch:
            raise ExperimentRunError(
                f"{run_dir}: was run with {key}={have.get(key)!r}, the experiment file now "
                f"says {key}={want[key]!r}; resume with the same training settings or use "
                "another --out (tasks, methods and seeds may change)"
            )


def _union(old: ExperimentConfig, new: ExperimentConfig, trains: bool) -> ExperimentConfig:
    """What a run resumed with ``new`` records: see :func:`run_experiment`."""

    from itskill.transfer.config import setting_key
    from itskill.transfer.methods import used_settings

    def merged(a: tuple, b: tuple) -> tuple:
        return tuple(dict.fromkeys((*a, *b)))

    settings = new.transfer_config().to_dict()

    def keys(methods: tuple[str, ...]) -> set[tuple[str, str]]:
        return {setting_key(n) for n in used_settings(methods, settings)}

    # What the old methods alone use stays as their cells trained with it: a file without them
    # may name it, but nothing of this session trains with it.
    theirs = keys(old.methods) - keys(new.methods)

    return replace(
        new,
        name=old.name,
        description=old.description,
        tasks=merged(old.tasks, new.tasks),
        methods=merged(old.methods, new.methods),
        seeds=merged(old.seeds, new.seeds),
        reward={**old.reward, **new.reward},
        sources={**old.sources, **new.sources},
        hyperparams={**old.hyperparams, **new.hyperparams},
        # By setting (one both sessions' methods use was checked equal).
        transfer={
            table: {
                **old.transfer.get(table, {}),
                **{
                    key: value
                    for key, value in new.transfer.get(table, {}).items()
                    if (table, key) not in theirs
                },
            }
            for table in dict.fromkeys((*old.transfer, *new.transfer))
        },
        execution=new.execution if trains else old.execution,
    )


_STORED_SOURCES = Check(
    "an object of task -> list of source skill names",
    lambda v: (
        isinstance(v, dict)
        and all(
            isinstance(names, list) and all(isinstance(n, str) for n in names)
            for names in v.values()
        )
    ),
)


def read_stored_sources(run_dir: Path) -> dict[str, list[str]]:
    """The sources each task's cells share, as a run stored them in ``sources.json`` (task ->
    skill names; none yet: empty); :class:`CorruptFileError` if the file was edited out of shape."""
    path = run_dir / SOURCES_FILE
    if not path.is_file():
        return {}
    found = read_json(path)
    check_shape(path, found, _STORED_SOURCES)
    return found


def resolve_all_sources(
    config: ExperimentConfig, run_dir: Path, source_file: Path | None = None
) -> dict[str, list[str]]:
    """Each task's source skills (names): those ``run_dir`` stores, the others resolved now. They
    are resolved once and stored (by :func:`run_experiment`) so that every cell uses the same.

    A resumed run keeps the stored ones: the skill space may have grown since. Nothing is
    resolved while no method uses sources (No_Transfer alone needs no skill space). Skills the
    experiment file names that cannot be used (unknown, empty, no checkpoint) are an
    :class:`ExperimentConfigError` naming ``sources.<task>`` and the file (``source_file``, else
    the run's copy of it or its ``config.json``). A method that cannot train on a task's
    sources (PST keeping all of them) is refused here too, before any cell: an
    :class:`ExperimentConfigError` for sources resolved now, an :class:`ExperimentRunError` for
    those the run stored.
    """
    from itskill.transfer import get_method, resolve_sources
    from itskill.transfer.sources import SourceError

    found = read_stored_sources(run_dir)
    if not any(get_method(m).uses_sources for m in config.methods):
        return found
    transfer_config = config.transfer_config()
    for task in config.tasks:
        wanted = config.sources.get(task, AUTO)
        stored = task in found
        if not stored:
            try:
                chosen = resolve_sources(
                    task, wanted if wanted == AUTO else list(wanted), transfer_config
                )
            except SourceError as err:
                if wanted == AUTO:
                    raise  # about the skill space, not about anything the file says
                raise ExperimentConfigError(
                    _experiment_file(run_dir, source_file), f"sources.{task}", str(err)
                ) from err
            found[task] = [s.name for s in chosen]
        for method in config.methods:
            # As its cells will choose (PST keeps a subset, refusing to keep them all): said
            # now, not by every such cell failing after hours of the others; for the sources a
            # resumed run stored too (a session adding PST to a run of one source each).
            try:
                get_method(method).select(found[task], transfer_config)
            except SourceError as err:
                if stored:
                    raise ExperimentRunError(
                        f"{run_dir / SOURCES_FILE}: {method} on {task}: {err}; this run keeps the "
                        f"sources it stored for {task}: run {method} in another run directory"
                    ) from err
                # The setting to blame where the file chose it, else the sources it gave.
                where = (err.setting and config.transfer_key(err.setting)) or (
                    "k" if wanted == AUTO else f"sources.{task}"
                )
                raise ExperimentConfigError(
                    _experiment_file(run_dir, source_file), where, f"{method} on {task}: {err}"
                ) from err
    return found


def _experiment_file(run_dir: Path, source_file: Path | None) -> Path | str:
    """What an error about the experiment's settings names: the file given, else the run's copy
    of it or the configuration it recorded, else (a caller with neither) the run it is for."""
    if source_file is not None:
        return source_file
    for name in (EXPERIMENT_FILE, CONFIG_FILE):
        if (run_dir / name).is_file():
            return run_dir / name
    return f"the experiment file of {run_dir}"


def run_experiment(
    config: ExperimentConfig,
    run_dir: Path,
    executor: str | None = None,
    workers: int | None = None,
    ray_address: str | None = None,
    resume: bool = False,
    source_file: Path | None = None,
    console: Console | None = None,
) -> RunSummary:
    """Run every unfinished cell of ``config`` in ``run_dir``; returns what was done.

    ``executor``, ``workers`` and ``ray_address`` default to the file's ``[execution]`` table.
    A cell that fails is reported (and its error saved in ``error.txt``); the others go on.

    A run resumed with another experiment file (``resume``) keeps its name and description (its
    identity, what its report is titled with) and the training settings, which must match. It
    records the union of every session's tasks, methods and seeds (and their rewards, sources,
    hyper-parameters and transfer settings), so the report covers every cell in the directory,
    and the file's report settings. The union is one grid: a cell of it no session asked for
    (ITN on seed 0, then No_Transfer on seed 1) is listed as not started, and trains when the run
    is resumed with a file that names it;
    its ``[execution]`` only when cells train (nothing ran with it otherwise). Whenever the run's
    files are written, ``source_file`` is copied to ``experiment.toml``: the file of the latest
    session that trained or changed what is recorded. A call refused (``run_dir`` in use by
    another session on this machine included), or with nothing to train and nothing new to
    record, writes nothing.
    """
    console = console or Console(stderr=True, emoji=False)
    run_dir = Path(run_dir)
    ex = executor or config.execution.executor
    workers = workers or config.execution.workers
    if ray_address is None and ex == "ray":
        # The file's address goes with the file's cluster: `--executor local` leaves it behind
        # (to finish a run on this machine once the cluster is gone); an address given with
        # `--executor local` is refused below.
        ray_address = config.execution.ray_address
    # Before the run is recorded: settings that cannot run leave no run to --resume.
    check_executor(ex, workers, ray_address)
    if ex == "ray":
        # Ray runs a cell on any node, from a working directory of its own: a relative run
        # directory would have it write there (every node must see the run at the same path).
        run_dir = run_dir.absolute()
    # Before the directory is checked or written.
    busy = ExperimentRunError(
        f"{run_dir} is in use by another itskill experiment run on this machine; wait for it "
        "to end, or stop it and --resume"
    )
    with held_alone(run_dir, "experiment", busy):
        return _run(config, run_dir, ex, workers, ray_address, resume, source_file, console)


def _run(
    config: ExperimentConfig,
    run_dir: Path,
    ex: str,
    workers: int | None,
    ray_address: str | None,
    resume: bool,
    source_file: Path | None,
    console: Console,
) -> RunSummary:
    """:func:`run_experiment`'s run, once ``run_dir`` is this session's alone."""
    old = _recorded_run(config, run_dir, resume, source_file)
    rewards = _reward_files(config)
    _check_rewards_unchanged(rewards, run_dir)
    # Before the run is recorded: a source that cannot be found leaves no run to --resume.
    sources = resolve_all_sources(config, run_dir, source_file)
    summary = RunSummary(run_dir)
    todo: list[Cell] = []
    for cell in cells(config):
        out = cell.dir(run_dir)
        if finished_result(out) is not None:
            summary.skipped.append(cell)
            continue
        if (out / "checkpoint.json").is_file():
            summary.resumed.append(cell)
        todo.append(cell)
    record = config if old is None else _union(old, config, trains=bool(todo))
    if old is not None:
        new = [c for c in todo if c not in summary.resumed]
        _check_as_recorded(config, record, run_dir, new)
    if old is not None and config.name != old.name:
        console.print(
            f"note: the run in {escape(str(run_dir))} keeps its name "
            f"{escape(repr(old.name))} (the experiment file says {escape(repr(config.name))})"
        )
    if todo or record != old:
        # config.json first: from then on the directory is a run, which --resume completes.
        write_json(run_dir / CONFIG_FILE, record.to_dict())
        write_json(run_dir / SOURCES_FILE, sources)
        for task, reward in rewards.items():
            if not reward_copy(run_dir, task).is_file():
                copy_whole(reward, reward_copy(run_dir, task))
        if source_file is not None and not _same_file(source_file, run_dir / EXPERIMENT_FILE):
            copy_whole(source_file, run_dir / EXPERIMENT_FILE)
    for cell in todo:
        # A failure of an earlier session is retried now: the report must not call it failed.
        (cell.dir(run_dir) / ERROR_FILE).unlink(missing_ok=True)
    transfer = config.transfer_config()
    jobs = [
        (
            cell,
            CellSettings(
                algo=config.algo,
                steps=config.steps,
                num_envs=config.num_envs,
                reward=str(reward_copy(run_dir, cell.task)) if cell.task in rewards else EXPERT,
                sources=tuple(sources.get(cell.task, ())),
                llm=config.llm,
                eval_every=config.eval.every,
                eval_episodes=config.eval.episodes,
                threshold=config.report.threshold,
                llm_cache=str(run_dir / "llm_cache"),
                hyperparams=config.hyperparams.get(cell.task, {}),
                transfer=transfer,
            ),
            cell.dir(run_dir),
        )
        for cell in todo
    ]
    console.print(
        f"experiment [bold]{escape(record.name)}[/bold]: {len(summary.skipped) + len(todo)} cells, "
        f"{len(summary.skipped)} done, {len(summary.resumed)} to resume, "
        f"{len(todo) - len(summary.resumed)} to start → {escape(str(run_dir))}"
    )
    if not todo:
        # Nothing ran: a session recorded now would add a command, a machine and a wall time
        # that produced none of the results.
        return summary
    sessions = Sessions(run_dir / PROVENANCE_FILE)
    sessions.start(executor=ex, workers=workers, cells=len(todo))
    status = "interrupted"
    try:
        with Progress(
            TextColumn("[bold]cells"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
        ) as progress:
            bar = progress.add_task("cells", total=len(jobs))
            results = run_jobs(run_cell, jobs, ex, workers, ray_address)
            for res in results:
                cell = todo[res.index]
                progress.advance(bar)
                if res.ok:
                    summary.finished.append(cell)
                    progress.console.print(_describe(cell, res.value))
                else:
                    message = f"{type(res.error).__name__}: {res.error}"
                    summary.failed[cell] = message
                    write_text(cell.dir(run_dir) / ERROR_FILE, message + "\n")
                    progress.console.print(
                        f"[red]failed[/red] {cell.name}: {escape(message)}", highlight=False
                    )
        status = "failed cells" if summary.failed else "complete"
    finally:
        sessions.finish(status=status)
    return summary


def _describe(cell: Cell, result: dict[str, Any]) -> str:
    t = result.get("steps_to_threshold")
    reached = (
        f"{t:,.0f} steps to {result['threshold']:.0%}" if t is not None else "threshold not reached"
    )
    return (
        f"[green]done[/green] {cell.name}: success {result['final_success']:.0%}, {reached}, "
        f"{result['train_wall_s'] / 60:.1f} min"
    )


_RESULT_KEYS = frozenset({"task", "method", "seed", "num_timesteps", "final_success"})


def finished_result(out: Path) -> dict[str, Any] | None:
    """The ``result.json`` of the cell in ``out``, or None while the cell is unfinished.

    A ``result.json`` that cannot be read (emptied or edited outside itskill: the runner writes it
    whole) counts as unfinished too, so ``--resume`` finishes the cell again from its checkpoint
    and the report does not count a run it cannot vouch for; so does one naming another cell
    than the directory it lies in.
    """
    out = Path(out)
    data = read_json_or_none(out / RESULT_FILE)
    if not (isinstance(data, dict) and data.keys() >= _RESULT_KEYS):
        return None
    # The cell a result names is the directory's it lies in: an edited seed or task sent the
    # held-out measurement to another cell's directory, or stopped it with a traceback.
    own = (out.parent.parent.name, out.parent.name, out.name)
    named = (data["task"], data["method"], f"seed_{data['seed']}")
    if named != own or not is_count(data["seed"]) or not is_count(data["num_timesteps"]):
        return None
    return data if is_number(data["final_success"]) else None


def load_cell_results(run_dir: Path) -> dict[Cell, dict[str, Any]]:
    """Every finished cell's ``result.json`` in ``run_dir``."""
    found = {}
    for path in sorted((Path(run_dir) / CELLS_DIR).glob(f"*/*/seed_*/{RESULT_FILE}")):
        data = finished_result(path.parent)
        if data is not None:
            found[Cell(data["task"], data["method"], data["seed"])] = data
    return found
