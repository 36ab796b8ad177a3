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
    str, typer.Option(help="'scripted' or a Stable-Baselines3 PPO/A2C checkpoint (.zip).")
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
        result = evaluate(get_task(task), policy, episodes=episodes, seed=seed, num_envs=num_envs)
    _print_eval(result, as_json)


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
        video = render.record(get_task(task), policy, out, episodes, seed=seed, camera=camera)
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
