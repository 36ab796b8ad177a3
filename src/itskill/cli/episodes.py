"""`itskill eval`, `render` and `demo`: run a policy (scripted or trained) on a task.

Imports of itskill.tasks stay inside the commands: they load PyTorch, which other commands and
``itskill --help`` should not wait for.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.table import Table

from itskill.cli.common import (
    SCRIPTED,
    SKILL_PREFIX,
    CameraOpt,
    JsonOpt,
    PolicyOpt,
    SeedOpt,
    TaskArg,
    console,
    episodes_option,
    err_console,
    policy_ref,
    policy_source,
    print_json,
    run_dir_option,
    user_errors,
)
from itskill.files import write_json
from itskill.limits import NUM_ENVS_MAX

if TYPE_CHECKING:
    from itskill.tasks.evaluate import EvalResult
    from itskill.tasks.spec import TaskSpec


def _print_eval(
    result: EvalResult, spec: TaskSpec, as_json: bool, named: str | None = None
) -> None:
    """The result as a line and the steps per subtask, or as JSON; ``named`` is the policy as
    the user named it (``skill:NAME``), shown before where it loaded from."""
    if as_json:
        print_json(result.to_dict())
        return
    shown = result.policy if named is None else f"{named} ({result.policy})"
    console.print(
        f"[bold]{escape(result.task)}[/bold] with {escape(shown)}: "
        f"success {result.successes}/{result.episodes} = [bold]{result.success_rate:.1%}[/bold] "
        f"(95% CI {result.ci_low:.1%}–{result.ci_high:.1%}), "
        f"subtasks done {result.mean_stages_done:.2f}/{result.n_stages}, "
        f"mean length {result.mean_length:.1f} steps, {result.wall_s:.1f} s"
    )
    spent = ", ".join(
        f"{k}.{stage.name} {steps:.1f}"
        for k, (stage, steps) in enumerate(zip(spec.stages, result.stage_steps, strict=True))
    )
    console.print(f"steps per episode in each subtask: {spent}", highlight=False, markup=False)


def eval_cmd(
    task: TaskArg,
    policy: PolicyOpt = SCRIPTED,
    episodes: Annotated[int, episodes_option("Episodes to count.")] = 100,
    seed: SeedOpt = 0,
    num_envs: Annotated[
        int, typer.Option(min=1, max=NUM_ENVS_MAX, help="Environments stepped together.")
    ] = 16,
    starts: Annotated[
        Path | None,
        typer.Option(
            help=escape(
                "A starts file (TOML, [[start]] tables; docs/tasks.md): evaluate from the "
                "task's own start and from each of these."
            ),
        ),
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Evaluate a policy: success rate over N episodes with its 95% interval."""
    from itskill.rl.checkpoint import as_policy
    from itskill.sim.batch import UnreachableStartError
    from itskill.tasks import get_task, make_batch_env
    from itskill.tasks.evaluate import evaluate
    from itskill.tasks.spec import load_starts

    with user_errors():
        source = policy_source(policy)
        ref = as_policy(source)
        spec = get_task(task)
        _note_another_task(policy, source, spec)
        if starts is None:
            result = evaluate(spec, ref, episodes=episodes, seed=seed, num_envs=num_envs)
            _print_eval(result, spec, as_json, policy if policy.startswith(SKILL_PREFIX) else None)
            return
        variants = load_starts(starts, spec)
        # Every start's reach is checked before the first is evaluated, which can take minutes.
        for name, variant in variants:
            try:
                make_batch_env(variant, num_envs=1, n_threads=1).close()
            except UnreachableStartError as err:
                raise UnreachableStartError(f"{starts}: start {name!r}: {err}") from err
        rows = []
        for name, variant in [("the task's own start", spec), *variants]:
            result = evaluate(variant, ref, episodes=episodes, seed=seed, num_envs=num_envs)
            rows.append({"start": name, **result.to_dict()})
            err_console.print(f"{name}: {result.success_rate:.0%}", highlight=False, markup=False)
    if as_json:
        print_json(rows)
        return
    title = f"{task} with {policy}, {episodes} episodes per start (seed {seed})"
    table = Table(title=escape(title))
    for column in ("start", "success", "95% CI", "subtasks done", "mean length"):
        table.add_column(column)
    for row in rows:
        table.add_row(
            escape(row["start"]),
            f"{row['successes']}/{row['episodes']} = {row['success_rate']:.0%}",
            f"{row['ci_low']:.0%}–{row['ci_high']:.0%}",
            f"{row['mean_stages_done']:.2f}/{row['n_stages']}",
            f"{row['mean_length']:.1f}",
        )
    console.print(table)


def _note_another_task(policy: str, source: str | Path, spec: TaskSpec) -> None:
    """Evaluating a policy on a task it was not trained on is a fair question (a source on its
    target), so it runs; the note keeps a mistyped task from passing for the policy's result.
    ``source`` is where ``policy`` loads from (:func:`policy_source`): a checkpoint's directory
    records the task it was trained on, whether named as a run, its weights or a skill."""
    from itskill.rl.checkpoint import (
        META_FILE,
        TASK_CHANGED,
        read_meta,
        trained_on_another_version,
    )

    if not (Path(source) / META_FILE).is_file():
        return
    meta = read_meta(source)
    trained = meta["task"]
    if trained != spec.id:
        note = f"{policy} was trained on {trained}; evaluated on {spec.id}"
    elif trained_on_another_version(meta, spec.fingerprint):
        note = f"{policy} was trained on {trained} as its task file defined it then; {TASK_CHANGED}"
    else:
        return
    err_console.print(f"[yellow]note:[/yellow] {escape(note)}", highlight=False)


def render_cmd(
    task: TaskArg,
    out: Annotated[Path, typer.Option(help="Output video (.mp4).")],
    policy: PolicyOpt = SCRIPTED,
    episodes: Annotated[int, episodes_option("Episodes to film.")] = 1,
    seed: SeedOpt = 0,
    camera: CameraOpt = "front",
    force: Annotated[bool, typer.Option("--force", help="Overwrite --out if it exists.")] = False,
) -> None:
    """Film episodes of a policy to an MP4 file."""
    from itskill.tasks import get_task, render

    _check_camera(camera)
    try:
        render.check_video_path(out)
    except render.RenderError as err:
        raise typer.BadParameter(str(err), param_hint="--out") from err
    _check_overwrite([out], force)
    with user_errors():
        ref = policy_ref(policy)
        video = render.record(get_task(task), ref, out, episodes, seed=seed, camera=camera)
    wins = sum(video.successes)
    console.print(
        f"wrote {video.path} ({video.frames} frames); {wins}/{episodes} succeeded", markup=False
    )


def _check_overwrite(paths: list[Path], force: bool) -> None:
    """Refuse, before any rollout, to write the files ``paths`` over a folder (which --force
    could not replace) or, without ``force``, over files that exist: a mistyped --out would
    replace another video, perhaps the only film of a run since deleted, or a user's own file."""
    folders = [p for p in paths if p.is_dir()]
    if folders:
        raise typer.BadParameter(f"{folders[0]} is a folder; move it or use another --out")
    taken = [p for p in paths if p.exists()]
    if taken and not force:
        raise typer.BadParameter(
            f"{taken[0]} exists; pass --force to overwrite it", param_hint="--out"
        )


def _check_camera(camera: str) -> None:
    from itskill.tasks import render

    if camera not in render.CAMERAS:
        raise typer.BadParameter(f"expected one of {render.CAMERAS}", param_hint="--camera")


def demo(
    task: Annotated[
        str, typer.Option(help="Task id (`itskill tasks list` shows them).")
    ] = "pick_nut_m12",
    episodes: Annotated[int, episodes_option("Episodes to evaluate.")] = 100,
    out: Annotated[Path, run_dir_option("Output folder.")] = Path("runs/demo"),
    seed: SeedOpt = 0,
    camera: CameraOpt = "front",
    force: Annotated[
        bool, typer.Option("--force", help="Overwrite the task's video and summary in --out.")
    ] = False,
) -> None:
    """Check the simulator on this machine: a task's scripted controller, filmed and evaluated.

    Without an OpenGL backend the video is skipped with a warning; the evaluation still runs.
    """
    from itskill.tasks import get_task, render
    from itskill.tasks.evaluate import evaluate

    _check_camera(camera)
    video_path, summary = out / f"{task}.mp4", out / f"{task}_eval.json"
    _check_overwrite([video_path, summary], force)
    with user_errors():
        spec = get_task(task)
        try:
            video = render.record(spec, SCRIPTED, video_path, episodes=1, seed=seed, camera=camera)
            console.print(f"video: {video.path}", markup=False)
        except render.RenderError as err:
            err_console.print(f"[yellow]no video:[/yellow] {escape(str(err))}", highlight=False)
        result = evaluate(spec, SCRIPTED, episodes=episodes, seed=seed)
        _print_eval(result, spec, as_json=False)
        out.mkdir(parents=True, exist_ok=True)
        write_json(summary, result.to_dict())
    console.print(f"summary: {summary}", markup=False)
