"""`itskill experiment run FILE.toml` and `itskill report RUN`: experiments and their reports."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from itskill.cli.common import (
    console,
    err_console,
    run_dir_option,
    user_errors,
    workers_option,
)
from itskill.limits import EPISODES_MAX

experiment_app = typer.Typer(
    no_args_is_help=True,
    help="Experiments: tasks × methods × seeds, resumable, on local processes or Ray.",
)


@experiment_app.command("run")
def experiment_run(
    file: Annotated[Path, typer.Argument(help="Experiment file (see experiments/*.toml).")],
    out: Annotated[
        Path | None,
        run_dir_option("Run directory (default: the experiment's name under runs/experiments)."),
    ] = None,
    executor: Annotated[
        str | None, typer.Option(help=escape("local or ray (default: the file's [execution])."))
    ] = None,
    workers: Annotated[
        int | None,
        workers_option(
            escape(
                "Cells run at once (default: the file's [execution] workers, else one per core)."
            )
        ),
    ] = None,
    ray_address: Annotated[str | None, typer.Option(help="Ray cluster address.")] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Continue a run: finished cells are skipped.")
    ] = False,
    report: Annotated[
        bool, typer.Option("--report/--no-report", help="Write the report at the end.")
    ] = True,
) -> None:
    """Train every task × method × seed cell of FILE, then write the report."""
    from itskill.executors import EXECUTORS
    from itskill.experiments.config import load_experiment
    from itskill.experiments.runner import CONFIG_FILE, run_experiment

    if executor is not None and executor not in EXECUTORS:
        raise typer.BadParameter(f"expected one of {list(EXECUTORS)}", param_hint="--executor")
    run_dir = out
    try:
        with user_errors():
            config = load_experiment(file)
            run_dir = out or Path("runs/experiments") / config.name
            summary = run_experiment(
                config, run_dir, executor, workers, ray_address, resume, file, console
            )
    except KeyboardInterrupt:
        # Only a recorded run (its config.json) can be resumed: --resume before that is refused.
        if run_dir is not None and (run_dir / CONFIG_FILE).is_file():
            hint = f"continue with: itskill experiment run {file} --out {run_dir} --resume"
        else:
            hint = "no run was recorded yet; run the same command again"
        err_console.print(f"interrupted; {hint}", markup=False)
        raise typer.Exit(130) from None
    console.print(
        f"{len(summary.finished)} cells trained, {len(summary.skipped)} already done, "
        f"{len(summary.failed)} failed; run directory {summary.run_dir}",
        markup=False,
    )
    if report:
        _write_report(summary.run_dir)
    if summary.failed:
        raise typer.Exit(1)


class PolicyChoice(str, Enum):
    """Which of a cell's policies ``held-out`` measures (:data:`held_out.POLICY_DIRS`)."""

    final = "final"
    best = "best"


@experiment_app.command("held-out")
def experiment_held_out(
    run: Annotated[Path, typer.Argument(help="An experiment run directory.")],
    episodes: Annotated[
        int, typer.Option(min=1, max=EPISODES_MAX, help="Held-out episodes per cell.")
    ] = 200,
    workers: Annotated[
        int | None, workers_option("Cells measured at once (default: one per core).")
    ] = None,
    policy: Annotated[
        PolicyChoice,
        typer.Option(
            help="The final policy, or the best/ one (chosen on the run's evaluation episodes)."
        ),
    ] = PolicyChoice.final,
) -> None:
    """Measure every finished cell's final (or best) policy on held-out episodes (seed 10,000),
    for the report to show beside the evaluation it was drawn or chosen at. Cells already
    measured are skipped."""
    from itskill.experiments.held_out import measure_held_out
    from itskill.experiments.runner import Cell

    def heard(cell: Cell, record: dict[str, Any] | None, error: str | None) -> None:
        if error is not None:
            err_console.print(f"{cell.name}: failed: {error}", markup=False)
        else:
            console.print(
                f"{cell.name} ({policy.value}): {record['success']:.1%} of {record['episodes']} "
                "held-out episodes "
                f"[{record['ci_low']:.1%}, {record['ci_high']:.1%}], {record['wall_s']:.0f} s",
                markup=False,
            )

    try:
        with user_errors():
            summary = measure_held_out(run, episodes, workers, heard, policy.value)
    except KeyboardInterrupt:
        err_console.print(
            "interrupted; the cells measured so far are kept: run the same command to measure "
            "the others",
            markup=False,
        )
        raise typer.Exit(130) from None
    unfinished = (
        f", {len(summary.unfinished)} not finished (no readable result.json: "
        f"`itskill experiment run FILE --resume --out {run}` finishes them)"
        if summary.unfinished
        else ""
    )
    console.print(
        f"{len(summary.measured)} cells measured, {len(summary.skipped)} already measured, "
        f"{len(summary.failed)} failed{unfinished}; `itskill report {run}` shows them",
        markup=False,
    )
    if summary.failed:
        raise typer.Exit(1)


def report_cmd(
    run: Annotated[Path, typer.Argument(help="An experiment run directory.")],
    out: Annotated[
        str | None,
        typer.Option(
            help="Where to write the report, with a copy of RUN's small files (default: inside "
            "RUN): a directory holding none of the files it writes, or an earlier report of RUN "
            "to write again (`.` where you are in one)."
        ),
    ] = None,
    video: Annotated[
        bool, typer.Option("--video/--no-video", help="Render a rollout of the best policy.")
    ] = True,
    baseline_run: Annotated[
        Path | None,
        typer.Option(
            help="Another experiment run of the baseline method on RUN's tasks, trained the same "
            "way for a longer budget: its runs stand in for RUN's baseline runs, so that a "
            "baseline that never reaches the threshold within RUN's budget is measured further."
        ),
    ] = None,
) -> None:
    """Write report.md and report.html (figures, tables, video) for an experiment run."""
    if out is not None and not out.strip():
        # As a Path, "" is the current directory: a mistyped variable would fill it.
        raise typer.BadParameter(
            "name a directory for the report ('.' for this one)", param_hint="--out"
        )
    _write_report(run, None if out is None else Path(out), video, baseline_run)


def _write_report(
    run: Path, out: Path | None = None, video: bool = True, baseline_run: Path | None = None
) -> None:
    """Write the report of experiment run ``run`` and say where, after its notes (what it left
    out and why); a directory it cannot report on is a one-line error."""
    from itskill.experiments.report import experiment_report

    with user_errors():
        files = experiment_report(run, out, video=video, baseline_run=baseline_run)
    for note in files.notes:
        err_console.print(f"[yellow]note:[/yellow] {escape(note)}", highlight=False)
    # Not markup: the paths are under the user's run directory ('runs/[v2]').
    console.print(f"report: {files.markdown} and {files.html}", markup=False)
