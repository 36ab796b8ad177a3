"""Reports: Markdown + self-contained HTML from an experiment run or an ``itskill learn`` run.

An experiment report has, per task: learning curves with 95% bands (the paper's Fig. 7), success
at fixed fractions of the budget (Table II), env-steps and wall time to the success threshold with
the time-efficiency gain over the baseline (next to the paper's figures), the ITN's attention
weights over one episode (Fig. 8), a rollout video of the best method's final policy and the
training settings the runs recorded in their checkpoints. Its header records the configuration,
the commands that produced the run, the machine and the time. Only finished cells (with
``result.json``) enter the statistics; cells still running are listed.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from itskill.curves import EVAL_FILE, Curve, CurveError, eval_seed, read_curve
from itskill.datafile import is_count, is_number
from itskill.experiments.analysis import (
    Band,
    Gain,
    Threshold,
    best_evaluation,
    common_grid,
    estimate,
    mean_band,
    success_at_fractions,
    threshold_gain,
    time_to_threshold,
)
from itskill.experiments.config import ExperimentConfig, ReportSettings
from itskill.experiments.document import (
    Bullets,
    Code,
    Document,
    Figure,
    Heading,
    Paragraph,
    Video,
    write_document,
)
from itskill.experiments.held_out import HELD_OUT_FILE, POLICY_DIRS, read_held_out
from itskill.experiments.learn_layout import (
    best_reward_file,
    kept_policy_words,
    policy_dir,
    transfer_dir,
)
from itskill.experiments.plots import method_label, plot_attention, plot_learning_curves
from itskill.experiments.provenance import Sessions, machine_facts, now
from itskill.experiments.runner import (
    CELLS_DIR,
    CONFIG_FILE,
    ERROR_FILE,
    EXPERIMENT_FILE,
    PROVENANCE_FILE,
    RESULT_FILE,
    REWARDS_DIR,
    SOURCES_FILE,
    Cell,
    ExperimentRunError,
    cells,
    finished_result,
    read_run_config,
    read_stored_sources,
    recorded_training,
    reward_hashes,
    trained_reward_hashes,
)
from itskill.files import CorruptFileError, copy_whole, read_json, read_json_or_none, read_utf8
from itskill.reward_contract import EXPERT
from itskill.rl.checkpoint import META_FILE
from itskill.rl.eval_callback import read_selection
from itskill.stats import mean_interval
from itskill.transfer.trace import TRACE_FILE
from itskill.transfer.train import TRANSFER_FILE

REPORT_MD = "report.md"
REPORT_HTML = "report.html"
FIGURES_DIR = "figures"
VIDEOS_DIR = "videos"
RUN_FILES = (CONFIG_FILE, EXPERIMENT_FILE, SOURCES_FILE, PROVENANCE_FILE)
CELL_FILES = (
    RESULT_FILE,
    ERROR_FILE,
    EVAL_FILE,
    "metrics.csv",
    META_FILE,
    TRANSFER_FILE,
    TRACE_FILE,
    HELD_OUT_FILE,
    # The best policy's record and its held-out measurement (its weights stay in the run).
    f"{POLICY_DIRS['best']}/{META_FILE}",
    f"{POLICY_DIRS['best']}/{HELD_OUT_FILE}",
)
"""What a report reads from a run and its cells, weights aside: a report written elsewhere copies
these beside itself, so it can be written again from its own directory (without the video)."""
OUT_NAMES = (
    REPORT_MD, REPORT_HTML, FIGURES_DIR, VIDEOS_DIR, *RUN_FILES, REWARDS_DIR, CELLS_DIR
)  # fmt: skip
"""What a report written outside its run puts in its directory."""


class ReportError(ValueError):
    """A directory that is not a run this module can report on."""


@dataclass(frozen=True)
class ReportFiles:
    """The written report."""

    markdown: Path
    html: Path
    notes: tuple[str, ...]
    """Parts that could not be produced (no finished ITN run, no OpenGL...), and why."""


# ---------------------------------------------------------------------- shared sections
def header_section(doc: Document, sessions: Sessions, extra: dict[str, str]) -> None:
    """Date, commands, total wall time and the machine."""
    runs = sessions.data.get("sessions", [])
    items = [f"{k}: {v}" for k, v in extra.items()]
    items.append(f"report written: {now()}")
    for i, s in enumerate(runs, 1):
        wall = f"{s['wall_s'] / 60:.1f} min" if s.get("wall_s") is not None else "did not finish"
        status = f", {s['status']}" if s.get("status") else ""
        items.append(f"session {i}: `{s['command']}` started {s['started']} ({wall}{status})")
    items.append(f"total wall time of the sessions: {sessions.wall_s / 60:.1f} min")
    # Each machine the sessions ran on, not the last one's alone: wall times from two machines
    # add up in the figures.
    machines: dict[str, list[int]] = {}
    for i, s in enumerate(runs, 1):
        machines.setdefault(_machine_text(s["machine"]), []).append(i)
    if len(machines) > 1:
        for text, numbers in machines.items():
            which = "session" if len(numbers) == 1 else "sessions"
            items.append(f"{which} {', '.join(map(str, numbers))} ran on {text}")
    else:
        # This machine's facts only for a record with no session (they import torch, ask git).
        items.append(next(iter(machines)) if machines else _machine_text(machine_facts()))
    commits = list(dict.fromkeys(s["machine"].get("commit") for s in runs))
    if any(commits):
        items.append(
            "code: " + ", ".join(f"commit {c}" if c else "no commit recorded" for c in commits)
        )
    doc.add(Heading("Provenance"), Bullets(tuple(items)))


def _machine_text(machine: dict[str, Any]) -> str:
    """The machine and library versions a session recorded, as the report lists them."""
    versions = ", ".join(
        f"{k} {machine[k]}"
        for k in ("python", "itskill", "torch", "mujoco", "stable_baselines3", "numpy")
        if k in machine
    )
    return (
        f"machine: {machine['cpu_count']} × {machine['cpu_model']}, {machine['os']}, "
        f"GPU {machine.get('gpu') or 'none'}; versions: {versions}"
    )


def attention_section(
    doc: Document, run_dir: Path, task: str, figures: Path, notes: list[str]
) -> None:
    """Fig. 8: the trained policy's source weights over one deterministic episode, stages marked."""
    from itskill.transfer import recorded_attention_trace

    try:
        trace = recorded_attention_trace(run_dir)
    except Exception as err:  # a failed trace must not cost the rest of the report
        notes.append(f"attention trace of {run_dir} failed: {type(err).__name__}: {err}")
        doc.add(Paragraph(f"No attention figure: {type(err).__name__}: {err}"))
        return
    episode = trace["episodes"][0]
    weights = np.asarray(episode["weights"], dtype=float)
    raw = None if episode["raw"] is None else np.asarray(episode["raw"], dtype=float)
    stages, segments = np.asarray(episode["stage"]), trace["segments"]
    path = plot_attention(
        weights,
        stages,
        trace["sources"],
        f"{task}: source weights over one episode",
        figures / f"attention_{task}.png",
        stage_names=segments,
        raw=raw,
    )
    outcome = "succeeded" if episode["success"] else "failed"
    doc.add(
        Figure(
            path,
            f"Fig. 8 ({task}): corrected weights W of each source (solid; the attention's raw "
            f"weights dashed) at every step of one deterministic episode ({outcome}, "
            f"{episode['length']} steps); dotted lines are stage changes.",
        )
    )
    doc.table(
        ["stage", "steps", *trace["sources"]],
        [
            [segments[s] if s < len(segments) else str(s), str(int(np.sum(stages == s)))]
            + [f"{w:.2f}" for w in weights[stages == s].mean(axis=0)]
            for s in np.unique(stages)
        ],
        "Mean corrected weight W per stage of the episode",
    )


def video_section(
    doc: Document, task: str, run_dir: Path, label: str, videos: Path, notes: list[str]
) -> None:
    """A rollout video of the policy in ``run_dir``; says why when it cannot render."""
    from itskill.rl.checkpoint import CheckpointError, as_policy
    from itskill.tasks import UnknownTaskError, get_task
    from itskill.tasks.render import RenderError, record

    out = videos / f"{task}_{label}.mp4"
    try:
        # as_policy reads only checkpoint.json; missing weights are found once record loads them.
        res = record(get_task(task), as_policy(run_dir), out, episodes=1, seed=0)
    except UnknownTaskError as err:
        # A run made on another machine, with a task file that is not here.
        notes.append(f"no video: {err}")
        doc.add(Paragraph(f"No video: the task is not defined here ({err})."))
        return
    except CheckpointError as err:
        # Committed results keep curves and results, not policies: the report still gets written.
        notes.append(f"no video: {err}")
        doc.add(Paragraph(f"No video: the policy is not in the run directory ({err})."))
        return
    except RenderError as err:
        notes.append(f"no video: {err}")
        doc.add(Paragraph(f"No video: offscreen rendering is not available here ({err})."))
        return
    outcome = "success" if res.successes[0] else "failure"
    doc.add(Video(res.path, f"{task}, {label}: one deterministic episode ({outcome})"))


# ---------------------------------------------------------------------- experiment report
@dataclass(frozen=True)
class _Runs:
    """The methods a report shows, where it reads each one's cells and the budget they trained
    for: the run's own, or for the baseline method those of a baseline run given to the report
    (trained with a longer budget, so that its time to the threshold is measured rather than
    cut off; the run itself need not have trained the baseline then)."""

    run_dir: Path
    steps: int
    methods: tuple[str, ...]
    baseline: str | None = None
    baseline_dir: Path | None = None
    baseline_steps: int = 0
    about_baseline: str = ""
    """The sentence saying where the baseline's cells come from (with a baseline run)."""

    def _theirs(self, method: str) -> Path | None:
        """The baseline run's directory if ``method``'s cells are read from it."""
        return self.baseline_dir if method == self.baseline else None

    def cell_dir(self, task: str, method: str, seed: int) -> Path:
        return Cell(task, method, seed).dir(self._theirs(method) or self.run_dir)

    def budget(self, method: str) -> int:
        return self.steps if self._theirs(method) is None else self.baseline_steps


@dataclass(frozen=True)
class _Baseline:
    """A baseline run's cells as the report reads them (:func:`_baseline_runs`)."""

    where: _Runs
    curves: dict
    pending: list[str]
    """Its baseline cells not finished, as the report lists them."""
    broken: list[str]


def _baseline_runs(config: ExperimentConfig, run_dir: Path, baseline_dir: Path) -> _Baseline:
    """Where the report reads each method's cells with ``baseline_dir``'s baseline cells in place
    of the run's, and those cells as it reads them.

    :class:`ReportError` unless ``baseline_dir`` is an experiment run of the baseline method on
    every task of the run, trained as the run's cells were (algorithm, environments, reward,
    evaluation, and the algorithm's settings its checkpoints record) for at least as many
    env-steps: anything else would compare two things at once.
    """
    baseline = config.report.baseline

    def refuse(problem: str) -> ReportError:
        return ReportError(f"baseline run {baseline_dir}: {problem}")

    if not (baseline_dir / CONFIG_FILE).is_file():
        raise refuse(f"not an experiment run directory (no {CONFIG_FILE})")
    try:
        other = read_run_config(baseline_dir)
    except (ExperimentRunError, CorruptFileError) as err:
        raise refuse(str(err)) from err
    if baseline not in other.methods or not set(config.tasks) <= set(other.tasks):
        raise refuse(
            f"it has no {baseline} runs of every task of this run ({', '.join(config.tasks)}): "
            f"it ran {', '.join(other.methods)} on {', '.join(other.tasks)}"
        )
    mine, theirs = config.training_settings(), other.training_settings()
    for key in ("algo", "num_envs", "eval"):
        if mine[key] != theirs[key]:
            raise refuse(
                f"trained with {key} {theirs[key]}, this run with {mine[key]}: its runs are no "
                "baseline for these"
            )
    for task in config.tasks:
        problem = _reward_difference(task, (run_dir, mine["reward"][task]),
                                     (baseline_dir, theirs["reward"][task]))  # fmt: skip
        if problem:
            raise refuse(problem)
    if other.steps < config.steps:
        raise refuse(
            f"a budget of {other.steps:,} env-steps, less than this run's {config.steps:,}: its "
            "curves would end before theirs"
        )
    # Only its baseline cells on this run's tasks: notes on its other cells would read as this
    # run's.
    own = replace(other, tasks=config.tasks, methods=(baseline,))
    curves, pending, broken = _curves(own, baseline_dir)
    schedule = _compare_recorded(config, run_dir, own, baseline_dir, refuse)
    seeds = "" if other.seeds == config.seeds else f" (seeds {', '.join(map(str, other.seeds))})"
    text = (
        f" The {method_label(baseline)} runs are those of the experiment run {other.name} "
        f"({baseline_dir}){seeds}, {sum(map(len, curves.values()))} finished, trained the same "
        f"way for {other.steps:,} env-steps: one that never reaches "
        f"{config.report.threshold:.0%} counts as that budget. Table II reads them at the "
        "fractions of this run's budget, their best evaluation over all of theirs; their wall "
        "times are those measured in that run."
    )
    if schedule == "linear" and other.steps > config.steps:
        text += (
            " Their learning rate decays linearly over their own budget, as this run's does over "
            f"its: at {config.steps:,} env-steps it is still at "
            f"{1 - config.steps / other.steps:.0%} of its start, where this run's has reached zero."
        )
    methods = config.methods if baseline in config.methods else (*config.methods, baseline)
    where = _Runs(run_dir, config.steps, methods, baseline, baseline_dir, other.steps, text)
    return _Baseline(where, curves, [f"baseline run: {_pending_line(c, baseline_dir)}"
                                     for c in pending], broken)  # fmt: skip


def _compare_recorded(
    config: ExperimentConfig,
    run_dir: Path,
    other: ExperimentConfig,
    other_dir: Path,
    refuse: Callable[[str], ReportError],
) -> str | None:
    """Refuse (``refuse``) a baseline run whose cells recorded other settings of the algorithm,
    the network or the reward's normalisation in their checkpoints (a task's own learning rate
    or action noise, changed between the runs) than this run's did, as a resume compares them
    (:func:`itskill.rl.train.changed_settings`: a setting a later release added counts with the
    value runs before it trained with); the learning-rate schedule the baseline's cells recorded
    (None where none of them records it, as in a copy from before checkpoints were kept). The
    demonstrations are not compared: methods with sources train without the task's."""
    from itskill.rl.train import changed_settings

    schedule = None
    for task in config.tasks:
        mine = recorded_training(config, run_dir, task)
        theirs = recorded_training(other, other_dir, task)
        if theirs is not None:
            schedule = theirs.get(config.algo, {}).get("lr_schedule", schedule)
        if mine is None or theirs is None:
            continue
        # Both ways: a setting a later release added is filled in only on the side that lacks
        # it, and either run may be the older.
        for have, want, way in ((mine, theirs, "this run's -> the baseline run's"),
                                (theirs, mine, "the baseline run's -> this run's")):  # fmt: skip
            differ = changed_settings(have, want)
            if differ:
                raise refuse(
                    f"its runs of {task} trained with other settings ({'; '.join(differ)}: {way})"
                )
    return schedule


def _reward_difference(task: str, a: tuple[Path, str], b: tuple[Path, str]) -> str | None:
    """Why two runs, each (directory, reward as recorded), cannot be compared on ``task`` for
    their rewards, or None if they trained it with one reward: the expert's in both, or files
    of the same code (by the runs' copies, or for a run from before copies were kept, by the
    sha256 its cells' checkpoints record)."""
    (dir_a, reward_a), (dir_b, reward_b) = a, b
    if EXPERT in (reward_a, reward_b):
        if reward_a != reward_b:
            return f"{task} trained with another reward than here"
        # The expert reward's version, where both runs' cells record it (since 2026-12-07).
        versions = [trained_reward_hashes(d, task) for d in (dir_a, dir_b)]
        if all(versions) and versions[0].isdisjoint(versions[1]):
            return (
                f"{task} trained with another version of the expert reward than here (its code "
                "or the task's stages changed between the runs)"
            )
        return None
    hashes = [reward_hashes(d, task) for d in (dir_a, dir_b)]
    unknown = [str(d) for d, h in zip((dir_a, dir_b), hashes, strict=True) if not h]
    if unknown:
        return (
            f"{task}'s rewards cannot be compared: {' and '.join(unknown)} keep(s) no copy of "
            "the reward file, and no cell's checkpoint.json records its sha256"
        )
    if hashes[0] != hashes[1]:
        return f"{task} trained with another reward than here (the reward files' code differs)"
    return None


def _curves(config: ExperimentConfig, run_dir: Path) -> tuple[dict, list[Cell], list[str]]:
    """Finished cells' curves by (task, method), the cells not finished, and unreadable ones."""
    curves: dict[tuple[str, str], list[tuple[int, Curve]]] = {}
    pending, broken = [], []
    for cell in cells(config):
        out = cell.dir(run_dir)
        if finished_result(out) is None:
            pending.append(cell)
            continue
        try:
            curve = read_curve(out, config.steps)
        except CurveError as err:
            # Left out of every figure below: the reader must learn which seed is missing.
            broken.append(f"{cell.name}: finished, but not counted in any figure: {err}")
            continue
        curves.setdefault((cell.task, cell.method), []).append((cell.seed, curve))
    return curves, pending, broken


def experiment_report(
    run_dir: str | Path,
    out: str | Path | None = None,
    video: bool = True,
    baseline_run: str | Path | None = None,
) -> ReportFiles:
    """Write ``report.md`` and ``report.html`` (and ``figures/``, ``videos/``) for a run.

    With ``out`` outside the run, the run's small files (:data:`RUN_FILES`, its reward copies,
    :data:`CELL_FILES`, no weights) are copied there as well: the directory to commit to
    ``results/``. Such an ``out`` must hold none of :data:`OUT_NAMES`, or be an earlier report
    copy of the same run, written again: its ``provenance.json`` starts with the same session
    (command and start time, which stay as the run is resumed, moved or copied; two runs of one
    file differ) and its cells hold only :data:`CELL_FILES` (a run directory also holds weights
    and logs there).
    Anything else (another run, a run directory, the user's own ``report.md``) is refused with
    :class:`ReportError` before anything is written.

    ``baseline_run``, another experiment run of the baseline method on the same tasks with the
    same algorithm, environments, reward and evaluation and a budget at least this run's, stands
    in for this run's baseline cells: a baseline that never reaches the threshold within the
    budget makes every gain over it only a lower bound, set by the budget; run on for longer, it
    is measured (:func:`_baseline_runs` says what must match).
    """
    run_dir = Path(run_dir)
    try:
        config = read_run_config(run_dir)
    except ExperimentRunError as err:
        raise ReportError(str(err)) from err
    out = Path(out) if out else run_dir
    outside = out.resolve() != run_dir.resolve()
    if outside:
        _check_out(run_dir, out)
    figures, videos = out / FIGURES_DIR, out / VIDEOS_DIR
    # Read before anything is written: a copy that cannot be shown must leave no half report.
    toml_path = run_dir / EXPERIMENT_FILE
    toml_text = _experiment_text(toml_path) if toml_path.is_file() else None
    sessions, sources = Sessions(run_dir / PROVENANCE_FILE), read_stored_sources(run_dir)
    base = None if baseline_run is None else _baseline_runs(config, run_dir, Path(baseline_run))
    if outside:
        # Before the figures: a report cut short then leaves an out that the next one knows
        # as this run's by its provenance.json, instead of figures it would refuse to replace.
        _copy_results(config, run_dir, out)
    curves, pending, broken = _curves(config, run_dir)
    where = _Runs(run_dir, config.steps, config.methods)
    if base is not None:
        where = base.where
        curves = {key: v for key, v in curves.items() if key[1] != where.baseline}
        curves.update(base.curves)
        pending = [c for c in pending if c.method != where.baseline]
        broken += base.broken
    pending_lines = [_pending_line(c, run_dir) for c in pending]
    if base is not None:
        pending_lines += base.pending
    notes: list[str] = list(broken)
    if base is None and config.report.baseline not in config.methods:
        notes.append(
            f"no gains: the baseline, {method_label(config.report.baseline)}, has no runs in this "
            "experiment; `itskill report RUN --baseline-run OTHER` reads them from a run of it"
        )

    doc = Document(f"Experiment report: {config.name}")
    if config.description:
        doc.add(Paragraph(config.description))
    # This run's own cells: a baseline run's are counted where the report says where they are from.
    own = [c for c in cells(config) if where.baseline_dir is None or c.method != where.baseline]
    own_methods = {c.method for c in own}
    finished = sum(len(v) for (_, m), v in curves.items() if m in own_methods)
    seeds = len(config.seeds)
    doc.add(
        Paragraph(
            f"{len(config.tasks)} task(s) × {len(own_methods)} method(s) × {seeds} seed(s); "
            f"{config.algo.upper()}, {config.steps:,} env-steps per run, deterministic evaluation "
            f"over {config.eval.episodes} episodes every {config.eval.every:,} env-steps"
            f"{_episodes_of_seeds(curves, where)}. "
            f"{finished} of {len(own)} runs finished"
            f"{f' and counted ({len(broken)} more not counted: see Notes)' if broken else ''}."
            f"{where.about_baseline}"
        )
    )
    header_section(doc, sessions, {"run directory": str(run_dir.resolve())})
    doc.add(Heading("Configuration", 3))
    if toml_text is not None:
        doc.add(Code(toml_text, "toml"))
    doc.add(Code(json.dumps(config.to_dict(), indent=2), "json"))

    for task in config.tasks:
        _task_section(doc, config, task, curves, sources.get(task), where, figures, notes)
        if video:
            # Of this run's own cells: a baseline run's final policy had a longer budget.
            best = _best_run(
                config, task, curves, tuple(m for m in config.methods if m in own_methods)
            )
            if best is not None:
                method, seed = best
                doc.add(Heading("Rollout of the best method's final policy", 3))
                cell_dir = where.cell_dir(task, method, seed)
                video_section(doc, task, cell_dir, f"{method}_seed{seed}", videos, notes)

    if pending_lines:
        doc.add(Heading("Runs not finished"))
        doc.add(Bullets(tuple(pending_lines)))
    if notes:
        doc.add(Heading("Notes"), Bullets(tuple(notes)))
    if outside:
        # The attention traces this report made go with the copy, which has no weights to trace
        # them from when its own report is written.
        for cell in cells(config):
            if (cell.dir(run_dir) / TRACE_FILE).is_file():
                copy_whole(cell.dir(run_dir) / TRACE_FILE, cell.dir(out) / TRACE_FILE)
    md, html_path = out / REPORT_MD, out / REPORT_HTML
    write_document(doc, md, html_path)
    return ReportFiles(md, html_path, tuple(notes))


def _experiment_text(path: Path) -> str:
    """The run's copy of its experiment file, as the report shows it; :class:`ReportError` if it
    is not UTF-8 text (the runner copies the user's file as is, and TOML must be UTF-8)."""
    try:
        return read_utf8(path)
    except CorruptFileError as err:
        raise ReportError(
            f"{err}; was it edited? Restore it from the "
            "experiment file, or delete it to report without it"
        ) from err


def _check_out(run_dir: Path, out: Path) -> None:
    """Refuse an ``out`` outside the run whose files the report would overwrite, unless it is
    an earlier report copy of this run (see :func:`experiment_report`)."""
    found = [name for name in OUT_NAMES if (out / name).exists()]
    if not found:
        return
    origin = _first_session(out)
    if origin is None:
        what = f"files the report writes ({', '.join(found)})"
    elif origin != _first_session(run_dir):
        what = f"another experiment run (its {PROVENANCE_FILE} starts with another session)"
    elif any(
        p.is_file() and p.relative_to(seed).as_posix() not in CELL_FILES
        for seed in (out / CELLS_DIR).glob("*/*/*")
        for p in seed.rglob("*")
    ):
        what = "an experiment run directory (its cells hold weights or logs)"
    else:
        return
    raise ReportError(
        f"{out}: holds {what}, which the report would overwrite; give --out a new or empty "
        f"directory, or an earlier report of {run_dir}"
    )


def _first_session(run_dir: Path) -> tuple[str, str] | None:
    """The command and start time of the run's first session, what tells one run from another;
    None without a readable record."""
    try:
        first = read_json(run_dir / PROVENANCE_FILE)["sessions"][0]
        return first["command"], first["started"]
    except (OSError, CorruptFileError, LookupError, TypeError):
        return None


def _copy_results(config: ExperimentConfig, run_dir: Path, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name in RUN_FILES:
        if (run_dir / name).is_file():
            copy_whole(run_dir / name, out / name)
    for reward in sorted((run_dir / REWARDS_DIR).glob("*.py")):  # what the cells trained with
        copy_whole(reward, out / REWARDS_DIR / reward.name)
    for cell in cells(config):
        src, dst = cell.dir(run_dir), cell.dir(out)
        for name in CELL_FILES:
            if (src / name).is_file():
                copy_whole(src / name, dst / name)
            else:  # gone from the run since the last copy (an error file once the cell finished)
                (dst / name).unlink(missing_ok=True)


def _pending_line(cell: Cell, run_dir: Path) -> str:
    out = cell.dir(run_dir)
    if (out / ERROR_FILE).is_file():
        error = (out / ERROR_FILE).read_text(encoding="utf-8", errors="replace").strip()
        return f"{cell.name}: failed: {error}"
    if (out / RESULT_FILE).is_file():
        return (
            f"{cell.name}: its {RESULT_FILE} cannot be read (damaged or edited), so the run is not "
            "counted; `itskill experiment run ... --resume` finishes it again from its checkpoint"
        )
    if (out / META_FILE).is_file():
        meta = read_json_or_none(out / META_FILE)
        steps = meta.get("num_timesteps") if isinstance(meta, dict) else None
        if not is_count(steps):  # damaged, or edited into another shape
            return f"{cell.name}: in progress (its checkpoint.json cannot be read)"
        return f"{cell.name}: in progress ({steps:,} env-steps checkpointed)"
    return f"{cell.name}: not started"


def _best_run(
    config: ExperimentConfig, task: str, curves: dict, methods: tuple[str, ...]
) -> tuple[str, int] | None:
    """The method with the highest mean final success (then the fewest steps to threshold) and
    its best seed."""
    scored = []
    for method in methods:
        runs = curves.get((task, method), [])
        if not runs:
            continue
        final = float(np.mean([c.success[-1] for _, c in runs]))
        steps = time_to_threshold([c for _, c in runs], config.report.threshold).steps.mean()
        scored.append((-final, steps, method, _best_seed(runs)))
    if not scored:
        return None
    _, _, method, seed = min(scored)
    return method, seed


def _best_seed(runs: list[tuple[int, Curve]]) -> int:
    """The seed of ``(seed, curve)`` runs with the highest final success (the lowest of ties)."""
    return max(runs, key=lambda sc: (sc[1].success[-1], -sc[0]))[0]


def _task_section(
    doc: Document,
    config: ExperimentConfig,
    task: str,
    curves: dict,
    sources: list[str] | None,
    where: _Runs,
    figures: Path,
    notes: list[str],
) -> None:
    rep = config.report
    doc.add(Heading(f"Task {task}"))
    if sources:
        doc.add(
            Paragraph(
                f"Source skills: {', '.join(sources)} (retrieved once for every method and "
                "seed; PST keeps a subset, No_Transfer none)."
            )
        )
    by_method = {
        m: [c for _, c in curves.get((task, m), [])] for m in where.methods if curves.get((task, m))
    }
    if not by_method:
        doc.add(Paragraph("No finished run yet."))
        return
    _settings_section(doc, task, curves, where, notes)
    fig = plot_learning_curves(
        _mean_bands(by_method, rep.grid_points),
        f"{task} ({config.algo.upper()})",
        figures / f"curves_{task}.png",
        rep.threshold,
    )
    doc.add(
        Heading("Learning curves (Fig. 7)", 3),
        Figure(
            fig,
            f"Deterministic success against env-steps, mean over seeds with the 95% t-interval; "
            f"dotted line: {rep.threshold:.0%}.",
        ),
    )
    doc.add(Heading("Success at fractions of the budget (Table II)", 3))
    _fractions_table(
        doc,
        config,
        by_method,
        "mean [95% t-interval over seeds, cut to 0–100%]; each seed's success at a fraction is "
        "read between the evaluations either side of it (the one past it weighs in where the "
        "fraction falls between evaluations)",
    )
    _held_out_section(doc, task, curves, where)
    _progress_section(doc, config, task, curves, where, figures, notes)
    thresholds = {m: time_to_threshold(cs, rep.threshold) for m, cs in by_method.items()}
    base = thresholds.get(rep.baseline)
    paper = rep.paper_gain.get(task)
    header = [
        "method",
        f"env-steps to {rep.threshold:.0%}",
        "wall-minutes",
        f"gain over {method_label(rep.baseline)} (env-steps)",
        "gain (wall time)",
    ]
    rows = []
    for m, th in thresholds.items():
        gain_steps = gain_wall = "—"
        if base is not None and m != rep.baseline:
            gain_steps = threshold_gain(th, base, "steps").format()
            gain_wall = threshold_gain(th, base, "wall_s").format()
        rows.append(
            [method_label(m), th.format_steps(), th.format_minutes(), gain_steps, gain_wall]
        )
    doc.add(Heading(f"Time to {rep.threshold:.0%} success and time efficiency", 3))
    doc.table(
        header,
        rows,
        "mean [95% t-interval, cut to zero and the budget]; gain: 1 − method/baseline, "
        "95% interval",
    )
    doc.add(Paragraph(_gain_explanation(rep.threshold, thresholds, paper)))
    if "itn" in by_method:
        doc.add(Heading("Attention over one episode (Fig. 8)", 3))
        seed = _best_seed(curves[(task, "itn")])
        doc.add(
            Paragraph(f"The ITN policy of seed {seed}, the one with the highest final success.")
        )
        attention_section(doc, where.cell_dir(task, "itn", seed), task, figures, notes)


def _episodes_of_seeds(curves: dict, where: _Runs) -> str:
    """Whether each seed was evaluated on episodes of its own (what the finished cells'
    checkpoints record, a baseline run's included), said because a mean over seeds that shared
    one sample carries its luck unseen."""
    own = shared = 0
    for (task, method), runs in curves.items():
        for seed, _ in runs:
            meta = read_json_or_none(where.cell_dir(task, method, seed) / META_FILE)
            evaluation = meta.get("evaluation") if isinstance(meta, dict) else None
            if isinstance(evaluation, dict):
                # A run from before that was resumed records the seed it kept: seed 0's.
                mine = evaluation.get("seed") == eval_seed(seed)
                own, shared = own + mine, shared + (not mine)
    if not shared:
        return ", each seed on episodes of its own" if own else ""
    which = "every seed" if not own else f"{shared} of the runs"
    return (
        f", the same episodes for {which} (runs from before each seed had its own, 2026-12-06 "
        "15:25 UTC: the interval over seeds does not cover the luck of that sample; `itskill "
        "experiment held-out` measures the final policies on others)"
    )


def _held_out_section(doc: Document, task: str, curves: dict, where: _Runs) -> None:
    """The final and best policies on held-out episodes (:mod:`itskill.experiments.held_out`)
    beside the evaluation each was drawn or chosen at, for the seeds measured; nothing where no
    seed was."""
    rows, counts = [], set()
    for method in where.methods:
        for policy in POLICY_DIRS:
            held, evaluated = [], []
            for seed, curve in curves.get((task, method), []):
                cell_dir = where.cell_dir(task, method, seed)
                record = read_held_out(cell_dir, policy)
                score = curve.success[-1] if policy == "final" else _selection_score(cell_dir)
                if record is not None and score is not None:
                    held.append(float(record["success"]))
                    evaluated.append(float(score))
                    counts.add(int(record["episodes"]))
            if not held:
                continue
            mean, low, high = (100 * v for v in mean_interval(np.subtract(evaluated, held)))
            spread = f" (all {len(held)} seeds)" if low == high else f" [{low:+.1f}, {high:+.1f}]"
            label = method_label(method)
            if where.budget(method) != where.steps:
                # A baseline run's policies trained for its own budget, not this run's.
                label += f" (trained {where.budget(method):,} env-steps)"
            rows.append(
                [
                    label,
                    policy,
                    str(len(held)),
                    estimate(held).format(),
                    estimate(evaluated).format(),
                    f"{mean:+.1f}{spread if len(held) > 1 else ''}",
                ]
            )
    if not rows:
        return
    doc.add(Heading("Policies on held-out episodes", 3))
    doc.table(
        [
            "method",
            "policy",
            "seeds",
            "held-out success",
            "its evaluation",
            "evaluation − held out (points)",
        ],
        rows,
        f"each seed's final policy, and its best/ one where measured, on "
        f"{' or '.join(map(str, sorted(counts)))} episodes no run trains or evaluates on "
        "(seed 10,000; `itskill experiment held-out RUN [--policy best]`), against the "
        "evaluation on the run's own episodes it was drawn at (final) or chosen by (best: the "
        "run's highest, so flattered by that choice as well as by the luck of those episodes); "
        "mean over the seeds measured with the 95% t-interval",
    )


def _selection_score(cell_dir: Path) -> float | None:
    """The success of the evaluation that chose the cell's best policy, as its record keeps it
    (the row of ``eval.csv`` may be gone: a resumed run evaluates again where it crashed, and
    keeps the best policy); None without a readable one."""
    selection = read_selection(cell_dir)
    success = selection.get("success") if selection is not None else None
    return float(success) if is_number(success) else None


_TRANSFER_SETTING_LABELS = {
    "pst_keep": "PST: sources kept",
    "attention_hidden": "attention: width of each source's MLP",
    "prior_weight": "attention: weight of the analyzer's prior",
    "fusion_hidden": "fusion: hidden widths",
    "residual": "source-action residual",
}


def _transfer_settings(cell_dir: Path, method: str, seed: int, notes: list[str]) -> dict[str, Any]:
    """The transfer settings a cell's ``transfer.json`` records (``transfer.toml``'s, with the
    experiment file's ``[transfer]`` on top), those its method uses, labelled for the table."""
    from itskill.rl.checkpoint import CheckpointError
    from itskill.transfer.train import network_settings, read_transfer

    if not (cell_dir / TRANSFER_FILE).is_file():
        return {}
    try:
        record = read_transfer(cell_dir)
    except CheckpointError as err:
        notes.append(f"transfer settings of {method_label(method)} seed {seed}: {err}")
        return {}
    shown = {True: "on", False: "off"}
    return {
        _TRANSFER_SETTING_LABELS[name]: (
            ", ".join(map(str, value)) or "none" if isinstance(value, list)
            else shown.get(value, value) if isinstance(value, bool) else value
        )
        for name, value in network_settings(record).items()
    }  # fmt: skip


def _settings_section(
    doc: Document, task: str, curves: dict, where: _Runs, notes: list[str]
) -> None:
    """The training settings the task's finished runs recorded in their checkpoints.

    They come from the packaged hyper-parameters (with the task's own table) and are not part of
    the experiment file, so the report shows what each run trained with; a setting that differs
    between runs lists its values with the runs that had them, and one only some methods have
    (the transfer settings each uses) names them.
    """
    from itskill.rl.checkpoint import CheckpointError, read_meta

    values: dict[str, dict[str, list[str]]] = {}
    methods: dict[str, dict[str, None]] = {}  # setting -> the methods with it, in order
    for (cell_task, method), runs in curves.items():
        if cell_task != task:
            continue
        for seed, _ in runs:
            try:
                saved = read_meta(where.cell_dir(task, method, seed))
            except CheckpointError as err:
                notes.append(f"training settings of {method_label(method)} seed {seed}: {err}")
                continue
            hp = saved["hyperparams"]
            settings = {
                "algorithm": saved["algo"],
                "environments": hp["num_envs"],
                "initial action log-std": hp["policy"]["log_std_init"],
                **hp[saved["algo"]],
                **_transfer_settings(where.cell_dir(task, method, seed), method, seed, notes),
            }
            for key, value in settings.items():
                shown = f"{value:g}" if isinstance(value, float) else str(value)
                values.setdefault(key, {}).setdefault(shown, []).append(
                    f"{method_label(method)} seed {seed}"
                )
                methods.setdefault(key, {})[method_label(method)] = None
    if not values:
        return
    everyone = {label for having in methods.values() for label in having}
    rows = []
    for key, by_value in values.items():
        if len(by_value) == 1:
            value = next(iter(by_value))
            some = "" if set(methods[key]) == everyone else f" ({', '.join(methods[key])})"
            rows.append([key, value + some])
        else:
            rows.append([key, "; ".join(f"{v} ({', '.join(r)})" for v, r in by_value.items())])
    doc.add(Heading("Training settings", 3))
    doc.table(
        ["setting", "value"],
        rows,
        "as recorded in each finished run's checkpoint.json (the packaged hyper-parameters with "
        "the task's own table; itskill/rl/data/hyperparams.toml) and, for the methods with "
        "sources, its transfer.json (itskill/transfer/data/transfer.toml with the experiment "
        "file's [transfer])",
    )


def _progress_section(
    doc: Document,
    config: ExperimentConfig,
    task: str,
    curves: dict,
    where: _Runs,
    figures: Path,
    notes: list[str],
) -> None:
    """Subtasks finished per evaluation episode: shows which method gets further into the task
    while success is still 0 for all of them."""
    from itskill.tasks import UnknownTaskError, get_task

    by_method: dict[str, list] = {}
    for method in where.methods:
        for seed, _ in curves.get((task, method), []):
            cell_dir = where.cell_dir(task, method, seed)
            try:
                curve = read_curve(cell_dir, where.budget(method), "stages_done")
            except CurveError as err:  # a run from before subtask progress was recorded
                notes.append(f"no subtask progress for {task}: {err}")
                return
            by_method.setdefault(method, []).append(curve)
    if not by_method:
        return
    try:
        subtasks = f"the {len(get_task(task).stages)} subtasks"
    except UnknownTaskError:  # a run made on another machine, with a task file not here
        subtasks = "the subtasks"
    fig = plot_learning_curves(
        _mean_bands(by_method, config.report.grid_points),
        f"{task}: subtasks finished ({config.algo.upper()})",
        figures / f"stages_{task}.png",
        ylabel=f"fraction of {subtasks} finished",
    )
    doc.add(
        Heading("Subtasks finished", 3),
        Figure(
            fig,
            "Fraction of the task's subtasks (stages) finished at the end of a deterministic "
            "evaluation episode (1 on success), mean over seeds with the 95% t-interval.",
        ),
    )
    _fractions_table(
        doc,
        config,
        by_method,
        f"fraction of {subtasks} finished; mean [95% t-interval, cut to 0–100%]",
    )


def _mean_bands(by_method: dict[str, list[Curve]], points: int) -> dict[str, Band]:
    """Each method's mean curve with its interval, on one grid spanning every run."""
    grid = common_grid([c for cs in by_method.values() for c in cs], points)
    return {m: mean_band(cs, grid) for m, cs in by_method.items()}


def _fractions_table(
    doc: Document, config: ExperimentConfig, by_method: dict[str, list[Curve]], caption: str
) -> None:
    """Each method's curve value at the report's fractions of the budget (Table II's layout)."""
    fractions = config.report.fractions
    doc.table(
        [
            "method",
            "seeds",
            *(f"{f:.0%} ({f * config.steps:,.0f})" for f in fractions),
            "best evaluation",
        ],
        [
            [method_label(m), str(len(cs))]
            + [e.format() for e in success_at_fractions(cs, config.steps, fractions)]
            + [best_evaluation(cs).format()]
            for m, cs in by_method.items()
        ],
        caption + "; best evaluation: each seed's highest point, mean over seeds",
    )


def _gain_explanation(
    threshold: float, thresholds: dict[str, Threshold], paper: float | None
) -> str:
    text = (
        f"A seed that never reaches {threshold:.0%} counts as the full budget (censored), which "
        "makes a mean a lower bound (≥). The gain is marked ≥ when only the baseline has such "
        "seeds, ≤ when only the method has, ~ when both have. Its interval: each side's 95% "
        "t-interval carried through the ratio of the means (delta method, Welch degrees of "
        "freedom); none with one seed on either side."
    )
    # The paper's figure is ITN against No_Transfer, whichever baseline the table uses.
    if paper is not None and "itn" in thresholds and "no_transfer" in thresholds:
        measured = threshold_gain(thresholds["itn"], thresholds["no_transfer"], "steps")
        text += (
            f" The paper reports ITN {paper:.2%} more time-efficient than No_Transfer on this task"
        )
        if math.isnan(measured.value):
            text += (
                f"; here it cannot be measured: neither reached {threshold:.0%} in any seed "
                "within the budget."
            )
        else:
            text += f"; measured here: {measured.format()}, which {_verdict(measured, paper)}."
    return text


def _verdict(measured: Gain, paper: float) -> str:
    """How a measured gain compares with the paper's: its interval first, then which way
    censoring biases it."""
    if not measured.has_interval:
        return "cannot be compared with it: one seed, or seeds that all agree, give no interval"
    if not measured.excludes(paper):
        caveat = "; censoring on both sides leaves it open" if measured.bound == "unknown" else ""
        return f"is consistent with it: the paper's figure lies inside the interval{caveat}"
    if measured.value > paper:
        if measured.bound in ("exact", "lower"):
            return "beats it: the whole interval lies above it"
        return "lies above it, but censoring of ITN's seeds may put it lower"
    if measured.bound in ("exact", "upper"):
        return "falls short of it: the whole interval lies below it"
    if measured.bound == "lower":
        return "lies below it, but only as a lower bound: the true gain may reach it"
    return "lies below it; censoring on both sides leaves it open"


def learn_report(learn_dir: str | Path, summary: dict[str, Any]) -> ReportFiles:
    """The single-run report of ``itskill learn``: plan, reward, sources, curve, attention,
    evaluation and the skill added (``summary`` is the pipeline's ``summary.json``)."""
    from itskill.transfer import get_method

    learn_dir = Path(learn_dir)
    figures, videos = learn_dir / FIGURES_DIR, learn_dir / VIDEOS_DIR
    notes: list[str] = []
    plan = summary["plan"]
    doc = Document(f"itskill learn: {summary['command']}")
    header_section(
        doc,
        Sessions(learn_dir / PROVENANCE_FILE),
        {"run directory": str(learn_dir.resolve()), "budget": summary["budget"]},
    )
    doc.add(Heading("Plan"))
    doc.add(Paragraph(f"Task {plan['task']}; objects: {', '.join(plan['objects'])}."))
    doc.add(Bullets(tuple(plan["subtasks"])))
    doc.add(Paragraph(f"Action sequence: {' → '.join(plan['actions'])}."))
    if plan.get("notes"):
        doc.add(Paragraph(f"Notes: {plan['notes']}"))
    reward = summary["reward"]
    doc.add(Heading("Generated reward"))
    expert = reward.get("expert_success")
    doc.add(
        Paragraph(
            f"{reward['iterations']} iteration(s) of {reward['samples']} sample(s) with the "
            f"{reward['llm']} backend; best candidate success {reward['best_success']:.0%}"
            + (f" (expert reward, same budget: {expert:.0%})" if expert is not None else "")
            + f". Search run: {reward['run_dir']}."
        )
    )
    doc.add(Code(read_utf8(best_reward_file(learn_dir, reward)), "python"))
    transfer = summary["transfer"]
    doc.add(Heading("Transfer"))
    doc.add(
        Paragraph(
            f"{method_label(transfer['method'])} with sources {', '.join(transfer['sources'])}, "
            f"{transfer['algo'].upper()}, {transfer['steps']:,} env-steps in "
            f"{transfer['wall_s'] / 60:.1f} min."
        )
    )
    contribution = transfer.get("contribution")
    if contribution:
        doc.table(
            ["segment", *contribution["sources"]],
            [
                [seg, *(f"{v:.2f}" for v in row)]
                for seg, row in zip(contribution["segments"], contribution["matrix"], strict=True)
            ],
            f"Analyzer contribution matrix ({contribution.get('client', '')}): the prior of the "
            "attention for each stage",
        )
    if transfer.get("residual"):
        doc.add(
            Paragraph(
                "Source-action residual: in each stage the action head's output is added to the "
                "action of the source that performs it ("
                + "; ".join(
                    f"{stage}: {src or 'none, the head alone'}"
                    for stage, src in transfer["residual"]
                )
                + ")."
            )
        )
    kept = policy_dir(learn_dir, transfer)
    try:
        curve = read_curve(transfer_dir(learn_dir, transfer), transfer["steps"])
        grid = common_grid([curve], 101)
        fig = plot_learning_curves(
            {transfer["method"]: mean_band([curve], grid)},
            f"{plan['task']}: learning curve",
            figures / "curve.png",
            ReportSettings.threshold,
        )
        doc.add(
            Figure(
                fig,
                "Deterministic success against env-steps during training; the dotted line is "
                f"the {ReportSettings.threshold:.0%} an experiment report times each method to.",
            )
        )
    except CurveError as err:
        notes.append(str(err))
    method = get_method(transfer["method"])
    if method.uses_sources:
        doc.add(Heading("Attention over one episode", 3))
        # The methods that use the analyzer's prior are the ones that weight their sources (ITN
        # and PST by attention corrected by it, NIA by the prior itself); tracing any other
        # fails, and the failure would read as a fault of the run.
        if method.uses_prior:
            attention_section(doc, kept, plan["task"], figures, notes)
        else:
            doc.add(
                Paragraph(
                    f"{method_label(method.name)} has no attention weights: it merges the "
                    "sources' features without weighting them, so there is no attention figure."
                )
            )
    ev = summary["evaluation"]
    doc.add(Heading("Evaluation"))
    chosen = transfer.get("selection")
    which = "the last checkpoint"
    if chosen is not None:
        which = (
            f"the policy that scored best in the evaluations during training "
            f"({chosen['success']:.0%} at {int(chosen['env_steps']):,} env-steps; last "
            f"evaluation {transfer['final_success']:.0%})"
        )
    doc.add(
        Paragraph(
            f"Policy evaluated: {which}, {kept}. Deterministic success "
            f"{ev['success_rate']:.1%} over {ev['episodes']} held-out episodes (95% Wilson "
            f"interval {ev['ci_low']:.1%}–{ev['ci_high']:.1%})."
        )
    )
    if summary.get("video", True):
        video_section(doc, plan["task"], kept, "final", videos, notes)
    skill = summary.get("skill")
    if skill and skill.get("added", True):
        doc.add(Heading("Skill added to the skill space"))
        doc.add(Bullets(tuple(f"{k}: {v}" for k, v in skill.items() if k != "added")))
    elif skill:
        doc.add(Heading("Not added to the skill space"))
        doc.add(
            Paragraph(
                f"The success is below the budget's min_success ({skill['min_success']:.0%}), so "
                "later runs will not retrieve this policy as a source. It stays in "
                f"{kept_policy_words(learn_dir, transfer)}; a larger budget (--steps, in a new "
                "run) may get it there, "
                "and `--resume --min-success X` adds it at a lower threshold X without training "
                "again."
            )
        )
    if notes:
        doc.add(Heading("Notes"), Bullets(tuple(notes)))
    md, html_path = learn_dir / REPORT_MD, learn_dir / REPORT_HTML
    write_document(doc, md, html_path)
    return ReportFiles(md, html_path, tuple(notes))
