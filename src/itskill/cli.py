"""The ``itskill`` command: inspect tasks, evaluate and film policies, run the demo.

Thin by design: each command parses its options, calls one library function and prints the result.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from itskill.tasks import TaskFileError, UnknownTaskError, all_tasks, get_task, render
from itskill.tasks.evaluate import SCRIPTED, CheckpointError, EvalResult, evaluate
from itskill.tasks.spec import TaskSpec

app = typer.Typer(
    no_args_is_help=True,
    add_completion=False,
    help="Robot manipulation skills on MuJoCo Franka tasks (hex nuts on bolts, pegs in holes).",
)
tasks_app = typer.Typer(no_args_is_help=True, help="The task suite: list tasks, show one.")
app.add_typer(tasks_app, name="tasks")

console = Console()
# Soft wrap: a long path in an error message must stay copyable, not be folded at 80 columns.
err_console = Console(stderr=True, soft_wrap=True)

USAGE_ERROR = 2

TaskArg = Annotated[str, typer.Argument(help="Task id (see `itskill tasks list`).")]
PolicyOpt = Annotated[
    str,
    typer.Option(help="'scripted', a training run directory (itskill train --out) or an SB3 .zip."),
]
SeedOpt = Annotated[int, typer.Option(help="Seed of the initial-state sequence.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")]
CameraOpt = Annotated[str, typer.Option(help="Camera: front or closeup.")]


@contextmanager
def _user_errors() -> Iterator[None]:
    """Turn errors caused by the user's input into a red message and exit code 2."""
    try:
        yield
    except (UnknownTaskError, TaskFileError, CheckpointError, render.RenderError) as err:
        err_console.print(f"[red]error:[/red] {err}", highlight=False, markup=True)
        raise typer.Exit(USAGE_ERROR) from err


def _print_json(data: Any) -> None:
    # Plain stdout, not rich: JSON must not be wrapped or coloured.
    typer.echo(json.dumps(data, indent=2))


def _range(r) -> list[float]:
    return [r.low, r.high]


def task_dict(spec: TaskSpec) -> dict[str, Any]:
    """Everything a task file says about ``spec``, as JSON-ready data."""
    init = spec.init
    return {
        "id": spec.id,
        "family": spec.family,
        "kind": spec.kind,
        "table_i": spec.table_i,
        "command": spec.command,
        "description": spec.description,
        "skills": list(spec.skills),
        "actions": list(spec.actions),
        "objects": [asdict(o) for o in spec.objects],
        "fixtures": [
            {"part": asdict(f.part), "xy": list(f.xy), "yaw": f.yaw} for f in spec.fixtures
        ],
        "object_fixture": list(spec.object_fixture),
        "init": {
            "ee": {
                "x": _range(init.ee_x),
                "y": _range(init.ee_y),
                "z": _range(init.ee_z),
                "yaw": _range(init.ee_yaw),
            },
            "objects": [
                {
                    "mode": o.mode,
                    "fixture": o.fixture,
                    **{k: _range(getattr(o, k)) for k in ("x", "y", "z", "yaw", "turns", "depth")},
                }
                for o in init.objects
            ],
        },
        "stages": [{"name": s.name, "done": s.done.source} for s in spec.stages],
        "success": spec.success.source,
        "max_steps": spec.max_steps,
        "terminate_on_success": spec.terminate_on_success,
        "script": list(spec.script),
        "tags": list(spec.tags),
        "source": spec.source,
    }


def tasks_markdown() -> str:
    """The task list as a Markdown table (docs/tasks.md is this output)."""
    rows = [
        "| id | family | kind | Table I | command | stages |",
        "|---|---|---|---|---|---|",
    ]
    for spec in all_tasks().values():
        stages = ", ".join(s.name for s in spec.stages)
        table_i = "yes" if spec.table_i else ""
        rows.append(
            f"| `{spec.id}` | {spec.family} | {spec.kind} | {table_i} | {spec.command} | {stages} |"
        )
    return "\n".join(rows)


@tasks_app.command("list")
def tasks_list(
    as_json: JsonOpt = False,
    markdown: Annotated[bool, typer.Option("--markdown", help="Print a Markdown table.")] = False,
) -> None:
    """List every task: id, family, kind, Table I flag, command and stages."""
    with _user_errors():
        tasks = all_tasks()
        if as_json:
            _print_json([task_dict(s) for s in tasks.values()])
            return
        if markdown:
            typer.echo(tasks_markdown())
            return
    table = Table(title=f"{len(tasks)} tasks")
    for column in ("id", "family", "kind", "Table I", "command", "stages"):
        table.add_column(column)
    for s in tasks.values():
        stages = ", ".join(st.name for st in s.stages)
        table.add_row(s.id, s.family, s.kind, "yes" if s.table_i else "", s.command, stages)
    console.print(table)


@tasks_app.command("show")
def tasks_show(task: TaskArg, as_json: JsonOpt = False) -> None:
    """Show everything about one task."""
    with _user_errors():
        data = task_dict(get_task(task))
    if as_json:
        _print_json(data)
        return
    console.print(f"[bold]{data['id']}[/bold]: {data['command']}")
    kv = Table.grid(padding=(0, 2))
    kv.add_column(style="cyan")
    kv.add_column()
    kv.add_row("family / kind", f"{data['family']} / {data['kind']}")
    kv.add_row("Table I", "yes" if data["table_i"] else "no")
    if data["description"]:
        kv.add_row("description", data["description"])
    kv.add_row("skills", ", ".join(data["skills"]))
    kv.add_row("actions", " → ".join(data["actions"]))
    for i, part in enumerate(data["objects"]):
        kv.add_row(f"object {i}", _part_text(part))
    for j, fx in enumerate(data["fixtures"]):
        kv.add_row(f"fixture {j}", f"{_part_text(fx['part'])} at xy={fx['xy']} yaw={fx['yaw']}")
    kv.add_row("object → fixture", str(data["object_fixture"]))
    kv.add_row("init ee", json.dumps(data["init"]["ee"]))
    for i, obj in enumerate(data["init"]["objects"]):
        kv.add_row(f"init object {i}", json.dumps(obj))
    for k, st in enumerate(data["stages"]):
        kv.add_row(f"stage {k}", f"{st['name']}: {st['done']}")
    kv.add_row("success", data["success"])
    kv.add_row("episode length", f"{data['max_steps']} steps")
    kv.add_row("script", "; ".join(data["script"]) or "(none)")
    kv.add_row("file", data["source"])
    console.print(kv)


def _part_text(part: dict[str, Any]) -> str:
    dims = ", ".join(
        f"{k}={v * 1000:g} mm"
        for k, v in part.items()
        if isinstance(v, float) and k not in ("rgba",)
    )
    shape = f" {part['shape']}" if "shape" in part else ""
    return f"{part['name']} ({part['kind']}{shape}): {dims}"


def _print_eval(result: EvalResult, as_json: bool) -> None:
    if as_json:
        _print_json(result.to_dict())
        return
    console.print(
        f"[bold]{result.task}[/bold] with {result.policy}: "
        f"success {result.successes}/{result.episodes} = [bold]{result.success_rate:.1%}[/bold] "
        f"(95% CI {result.ci_low:.1%}–{result.ci_high:.1%}), "
        f"mean length {result.mean_length:.1f} steps, {result.wall_s:.1f} s"
    )


@app.command("eval")
def eval_cmd(
    task: TaskArg,
    policy: PolicyOpt = SCRIPTED,
    episodes: Annotated[int, typer.Option(min=1, help="Episodes to count.")] = 100,
    seed: SeedOpt = 0,
    num_envs: Annotated[int, typer.Option(min=1, help="Environments stepped together.")] = 16,
    as_json: JsonOpt = False,
) -> None:
    """Evaluate a policy: success rate over N episodes with its 95% interval."""
    with _user_errors():
        ref = _policy_ref(policy)
        result = evaluate(get_task(task), ref, episodes=episodes, seed=seed, num_envs=num_envs)
    _print_eval(result, as_json)


def _policy_ref(policy: str) -> Any:
    """A training run directory becomes its checkpoint's policy; other references pass through."""
    from itskill.rl.checkpoint import as_policy

    return as_policy(policy)


@app.command("train")
def train_cmd(
    task: TaskArg,
    algo: Annotated[str, typer.Option(help="a2c (the paper's algorithm) or ppo.")] = "ppo",
    steps: Annotated[int, typer.Option(min=1, help="Total env-steps (a rerun resumes).")] = 100_000,
    seed: Annotated[int, typer.Option(help="Seed of the run.")] = 0,
    reward: Annotated[
        str, typer.Option(help="'expert' or a .py file defining compute_reward(ctx).")
    ] = "expert",
    out: Annotated[Path, typer.Option(help="Run directory (checkpoints, metrics).")] = Path(
        "runs/train"
    ),
    num_envs: Annotated[
        int | None, typer.Option(min=1, help="Environments stepped together.")
    ] = None,
    hyperparams: Annotated[
        Path | None, typer.Option(help="A hyper-parameter TOML file instead of the packaged one.")
    ] = None,
) -> None:
    """Train a policy with A2C or PPO; rerun the same command to resume from the last checkpoint."""
    from itskill.rl.config import HyperparamError
    from itskill.rl.train import ResumeMismatchError, RewardLoadError, train

    if algo not in ("a2c", "ppo"):
        raise typer.BadParameter("expected a2c or ppo", param_hint="--algo")
    try:
        with _user_errors():
            result = train(
                task, algo, steps, seed, reward, out, num_envs, hyperparams, console=console
            )
    except (HyperparamError, RewardLoadError, ResumeMismatchError) as err:
        err_console.print(f"[red]error:[/red] {err}", highlight=False, markup=True)
        raise typer.Exit(USAGE_ERROR) from err
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    console.print(
        f"trained {task} with {algo}: {result.num_timesteps} env-steps in total"
        + (f" (resumed from {result.resumed_from})" if result.resumed_from else "")
        + f"; checkpoint in {result.run_dir}"
    )


@app.command("render")
def render_cmd(
    task: TaskArg,
    out: Annotated[Path, typer.Option(help="Output video (.mp4).")],
    policy: PolicyOpt = SCRIPTED,
    episodes: Annotated[int, typer.Option(min=1, help="Episodes to film.")] = 1,
    seed: SeedOpt = 0,
    camera: CameraOpt = "front",
) -> None:
    """Film episodes of a policy to an MP4 file."""
    _check_camera(camera)
    with _user_errors():
        ref = _policy_ref(policy)
        video = render.record(get_task(task), ref, out, episodes, seed=seed, camera=camera)
    wins = sum(video.successes)
    console.print(f"wrote {video.path} ({video.frames} frames); {wins}/{episodes} succeeded")


def _check_camera(camera: str) -> None:
    if camera not in render.CAMERAS:
        raise typer.BadParameter(f"expected one of {render.CAMERAS}", param_hint="--camera")


@app.command("demo")
def demo(
    task: Annotated[str, typer.Option(help="A Table I task.")] = "pick_nut_m12",
    episodes: Annotated[int, typer.Option(min=1, help="Episodes to evaluate.")] = 100,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/demo"),
    seed: SeedOpt = 0,
    camera: CameraOpt = "front",
) -> None:
    """The main job for now: a scripted rollout of a task, filmed and evaluated.

    Without an OpenGL backend the video is skipped with a warning; the evaluation still runs.
    """
    _check_camera(camera)
    with _user_errors():
        spec = get_task(task)
        try:
            video = render.record(
                spec, SCRIPTED, out / f"{task}.mp4", episodes=1, seed=seed, camera=camera
            )
            console.print(f"video: {video.path}")
        except render.RenderError as err:
            err_console.print(f"[yellow]no video:[/yellow] {err}", highlight=False)
        result = evaluate(spec, SCRIPTED, episodes=episodes, seed=seed)
    _print_eval(result, as_json=False)
    out.mkdir(parents=True, exist_ok=True)
    summary = out / f"{task}_eval.json"
    summary.write_text(json.dumps(result.to_dict(), indent=2) + "\n")
    console.print(f"summary: {summary}")


# ---------------------------------------------------------------------- skills
# Imports of itskill.skills stay inside the commands: the other commands should not pay for them.
skills_app = typer.Typer(
    no_args_is_help=True, help="The skill space: learned skills, their checkpoints, retrieval."
)
app.add_typer(skills_app, name="skills")

SkillArg = Annotated[str, typer.Argument(help="Skill id or name (see `itskill skills list`).")]


@contextmanager
def _skill_errors() -> Iterator[None]:
    """Unknown skill or task, unreadable or newer database, missing checkpoint: exit code 2."""
    from rich.markup import escape

    from itskill.skills import SkillSpaceError

    try:
        yield
    except (SkillSpaceError, UnknownTaskError, TaskFileError) as err:
        err_console.print(f"[red]error:[/red] {escape(str(err))}", highlight=False)
        raise typer.Exit(USAGE_ERROR) from err


def _skill_table(rows: list[tuple[Any, float | None]], title: str) -> Table:
    table = Table(title=title)
    scored = any(score is not None for _, score in rows)
    columns = ("score",) if scored else ()
    for column in (*columns, "id", "name", "task", "success", "actions", "checkpoint"):
        table.add_column(column)
    for s, score in rows:
        success = "" if s.success_rate is None else f"{s.success_rate:.1%}"
        cells = (f"{score:.3f}",) if scored else ()
        table.add_row(
            *cells, str(s.id), s.name, s.task_id, success, " → ".join(s.actions), s.checkpoint
        )
    return table


@skills_app.command("list")
def skills_list(as_json: JsonOpt = False) -> None:
    """List every skill in the skill space ($ITSKILL_HOME/skills.sqlite)."""
    from itskill.skills import open_skill_space

    with _skill_errors(), open_skill_space() as space:
        skills = space.list()
        path = space.path
    if as_json:
        _print_json([s.to_dict() for s in skills])
        return
    console.print(_skill_table([(s, None) for s in skills], f"{len(skills)} skills in {path}"))


@skills_app.command("show")
def skills_show(skill: SkillArg, as_json: JsonOpt = False) -> None:
    """Show one skill: its description, actions, checkpoint and metrics."""
    from itskill.skills import open_skill_space

    with _skill_errors(), open_skill_space() as space:
        found = space.get(skill)
        ckpt = space.checkpoint_path(found)
    data = {**found.to_dict(), "checkpoint_path": str(ckpt), "checkpoint_exists": ckpt.is_file()}
    if as_json:
        _print_json(data)
        return
    kv = Table.grid(padding=(0, 2))
    kv.add_column(style="cyan")
    kv.add_column()
    for key, value in data.items():
        kv.add_row(key, " → ".join(value) if key == "actions" else str(value))
    console.print(kv)


@skills_app.command("search")
def skills_search(
    query: Annotated[str, typer.Argument(help="A task command, e.g. 'Pick up the round peg'.")],
    k: Annotated[int, typer.Option("-k", min=1, help="How many skills to return.")] = 5,
    exclude_task: Annotated[
        list[str] | None, typer.Option(help="Leave out skills of this task id (repeatable).")
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """The skills most similar to QUERY (cosine similarity of sentence embeddings)."""
    from itskill.skills import open_skill_space, search

    with _skill_errors(), open_skill_space() as space:
        hits = search(space, query, k=k, exclude_tasks=set(exclude_task or ()))
    if as_json:
        _print_json([{"score": score, **s.to_dict()} for s, score in hits])
        return
    console.print(_skill_table(list(hits), f"top {len(hits)} for {query!r}"))


@skills_app.command("add")
def skills_add(
    task: Annotated[str, typer.Option(help="Task id the skill solves.")],
    checkpoint: Annotated[Path, typer.Option(help="Trained policy checkpoint (must exist).")],
    name: Annotated[str | None, typer.Option(help="Unique name (default: the task id).")] = None,
    description: Annotated[
        str | None, typer.Option(help="Task command (default: the task's command).")
    ] = None,
    actions: Annotated[
        str | None, typer.Option(help="Comma-separated actions (default: the task's actions).")
    ] = None,
    success: Annotated[float | None, typer.Option(min=0, max=1, help="Success rate.")] = None,
    ci_low: Annotated[float | None, typer.Option(min=0, max=1, help="95% CI low.")] = None,
    ci_high: Annotated[float | None, typer.Option(min=0, max=1, help="95% CI high.")] = None,
    steps: Annotated[int | None, typer.Option(min=0, help="Training env-steps.")] = None,
    wall_s: Annotated[float | None, typer.Option(min=0, help="Training wall seconds.")] = None,
    algo: Annotated[str | None, typer.Option(help="Algorithm, e.g. ppo or a2c.")] = None,
    seed: Annotated[int | None, typer.Option(help="Training seed.")] = None,
    as_json: JsonOpt = False,
) -> None:
    """Add a learned skill (its checkpoint must exist)."""
    from itskill.skills import Skill, open_skill_space

    if (ci_low is None) != (ci_high is None):
        raise typer.BadParameter("give both --ci-low and --ci-high, or neither")
    with _skill_errors():
        spec = get_task(task)
        acts = spec.actions if actions is None else tuple(a.strip() for a in actions.split(","))
        skill = Skill(
            name=name or spec.id,
            task_id=spec.id,
            description=description or spec.command,
            actions=tuple(a for a in acts if a),
            # Absolute: a path relative to the shell's directory means nothing to other processes.
            checkpoint=str(checkpoint.expanduser().resolve()),
            success_rate=success,
            success_ci=None if ci_low is None else (ci_low, ci_high),
            train_steps=steps,
            train_wall_s=wall_s,
            algo=algo,
            seed=seed,
        )
        with open_skill_space() as space:
            added = space.add(skill)
    if as_json:
        _print_json(added.to_dict())
        return
    console.print(f"added skill {added.id}: {added.name} ({added.task_id})")


@skills_app.command("remove")
def skills_remove(skill: SkillArg, as_json: JsonOpt = False) -> None:
    """Remove a skill from the skill space (its checkpoint file is left in place)."""
    from itskill.skills import open_skill_space

    with _skill_errors(), open_skill_space() as space:
        removed = space.remove(skill)
    if as_json:
        _print_json(removed.to_dict())
        return
    console.print(f"removed skill {removed.id}: {removed.name}")


@skills_app.command("install")
def skills_install(
    library: Annotated[Path, typer.Argument(help="Library directory with a manifest.json.")],
    as_json: JsonOpt = False,
) -> None:
    """Register every skill of a library directory (skipping names already present)."""
    from itskill.skills import install_library, open_skill_space

    with _skill_errors(), open_skill_space() as space:
        added = install_library(space, library)
    if as_json:
        _print_json([s.to_dict() for s in added])
        return
    console.print(f"installed {len(added)} skill(s) from {library}")


@skills_app.command("pretrain")
def skills_pretrain(
    tasks: Annotated[
        list[str] | None,
        typer.Option("--tasks", help="Tasks to train (default: every basic task)."),
    ] = None,
    steps: Annotated[int, typer.Option(help="Env-steps per skill.")] = 300_000,
    algo: Annotated[str, typer.Option(help="a2c or ppo.")] = "ppo",
    seed: Annotated[int, typer.Option()] = 0,
    episodes: Annotated[int, typer.Option(help="Evaluation episodes per skill.")] = 100,
    executor: Annotated[str, typer.Option(help="local (one job per core) or ray.")] = "local",
    workers: Annotated[int | None, typer.Option(help="Parallel jobs (local executor).")] = None,
    ray_address: Annotated[str | None, typer.Option(help="Ray cluster address.")] = None,
    runs: Annotated[Path, typer.Option(help="Training run directories (resumable).")] = Path(
        "runs/pretrain"
    ),
    library: Annotated[
        Path | None, typer.Option(help="Library directory (default: the skill space's own).")
    ] = None,
) -> None:
    """Train skills from scratch with expert rewards, evaluate each, add them to the skill space.

    Rerunning the same command resumes unfinished trainings from their last checkpoint.
    """
    from itskill.executors import ExecutorError
    from itskill.skills import open_skill_space
    from itskill.skills.pretrain import PretrainConfig, basic_tasks, pretrain

    config = PretrainConfig(algo=algo, steps=steps, seed=seed, eval_episodes=episodes)

    def report(task: str, entry, error) -> None:
        if error is not None:
            console.print(f"[red]{task}: failed: {type(error).__name__}: {error}[/red]")
        else:
            lo, hi = entry.success_ci
            console.print(
                f"{task}: success {entry.success:.0%} (95% CI {lo:.0%}-{hi:.0%}) after "
                f"{entry.steps:,} env-steps, {entry.wall_s / 60:.1f} min"
            )

    with _user_errors(), _skill_errors(), open_skill_space() as space:
        try:
            pretrain(
                tasks or basic_tasks(),
                config,
                runs,
                library or space.library_dir,
                space,
                executor=executor,
                workers=workers,
                ray_address=ray_address,
                on_result=report,
            )
        except ExecutorError as err:
            console.print(f"[red]{err}[/red]")
            raise typer.Exit(2) from err
