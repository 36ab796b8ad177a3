"""`itskill tasks`: list the task suite, show one task.

Imports of itskill.tasks stay inside the functions: they load PyTorch, which other commands and
``itskill --help`` should not wait for.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import typer
from rich.markup import escape
from rich.table import Table

from itskill.cli.common import (
    JsonOpt,
    MarkdownOpt,
    TaskArg,
    check_one_format,
    console,
    print_json,
    user_errors,
)

if TYPE_CHECKING:
    from itskill.tasks.spec import TaskSpec

tasks_app = typer.Typer(no_args_is_help=True, help="The task suite: list tasks, show one.")


def task_dict(spec: TaskSpec) -> dict[str, Any]:
    """Everything a task file says about ``spec``, as JSON-ready data."""
    from itskill.tasks.spec import init_table

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
        "init": init_table(spec.init),
        "stages": [{"name": s.name, "done": s.done.source} for s in spec.stages],
        "success": spec.success.source,
        "max_steps": spec.max_steps,
        "terminate_on_success": spec.terminate_on_success,
        "script": list(spec.script),
        "training_starts": [
            {"share": t.share} | ({"task": t.name} if t.name else {"init": init_table(t.init)})
            for t in spec.training_starts
        ],
        "tags": list(spec.tags),
        "source": spec.source,
    }


def tasks_markdown() -> str:
    """The task list as a Markdown table (docs/tasks.md is this output)."""
    from itskill.tasks import all_tasks

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
    markdown: MarkdownOpt = False,
) -> None:
    """List every task: id, family, kind, Table I flag, command and stages."""
    from itskill.tasks import all_tasks

    check_one_format(as_json, markdown)
    with user_errors():
        tasks = all_tasks()
        if as_json:
            print_json([task_dict(s) for s in tasks.values()])
            return
        if markdown:
            typer.echo(tasks_markdown())
            return
    table = Table(title=f"{len(tasks)} tasks")
    for column in ("id", "family", "kind", "Table I", "command", "stages"):
        table.add_column(column)
    for s in tasks.values():
        stages = ", ".join(st.name for st in s.stages)
        cells = (s.id, s.family, s.kind, "yes" if s.table_i else "", s.command, stages)
        # Cells are markup: a task file's text is escaped ('Pick up the [small] nut').
        table.add_row(*(escape(c) for c in cells))
    console.print(table)


@tasks_app.command("show")
def tasks_show(task: TaskArg, as_json: JsonOpt = False) -> None:
    """Show everything about one task."""
    from itskill.tasks import get_task

    with user_errors():
        data = task_dict(get_task(task))
    if as_json:
        print_json(data)
        return
    console.print(f"[bold]{escape(data['id'])}[/bold]: {escape(data['command'])}")
    rows = [
        ("family / kind", f"{data['family']} / {data['kind']}"),
        ("Table I", "yes" if data["table_i"] else "no"),
    ]
    if data["description"]:
        rows.append(("description", data["description"]))
    rows.append(("skills", ", ".join(data["skills"])))
    rows.append(("actions", " → ".join(data["actions"])))
    for i, part in enumerate(data["objects"]):
        rows.append((f"object {i}", _part_text(part)))
    for j, fx in enumerate(data["fixtures"]):
        rows.append((f"fixture {j}", f"{_part_text(fx['part'])} at xy={fx['xy']} yaw={fx['yaw']}"))
    rows.append(("object → fixture", str(data["object_fixture"])))
    rows.append(("init ee", json.dumps(data["init"]["ee"])))
    for i, obj in enumerate(data["init"]["objects"]):
        rows.append((f"init object {i}", json.dumps(obj)))
    for k, st in enumerate(data["stages"]):
        rows.append((f"stage {k}", f"{st['name']}: {st['done']}"))
    rows.append(("success", data["success"]))
    rows.append(("episode length", f"{data['max_steps']} steps"))
    rows.append(("script", "; ".join(data["script"]) or "(none)"))
    if data["training_starts"]:
        starts = [
            f"{t['share']:.0%} from {t['task']}'s start"
            if "task" in t
            else f"{t['share']:.0%} from {json.dumps(t['init'])}"
            for t in data["training_starts"]
        ]
        rows.append(("training starts", "; ".join(starts)))
    rows.append(("file", data["source"]))
    kv = Table.grid(padding=(0, 2))
    kv.add_column(style="cyan")
    kv.add_column()
    for label, value in rows:
        # Cells are markup: a task file's text is escaped ('Pick up the [small] nut').
        kv.add_row(label, escape(value))
    console.print(kv)


def _part_text(part: dict[str, Any]) -> str:
    dims = ", ".join(
        f"{k}={v * 1000:g} mm"
        for k, v in part.items()
        if isinstance(v, float) and k not in ("rgba",)
    )
    shape = f" {part['shape']}" if "shape" in part else ""
    return f"{part['name']} ({part['kind']}{shape}): {dims}"
