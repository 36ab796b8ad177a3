"""The ``itskill`` command: one Typer app, a module per command group.

Thin by design: each command parses its options, calls one library function and prints the result.
"""

from __future__ import annotations

import typer

from itskill.cli.episodes import demo, eval_cmd, render_cmd
from itskill.cli.skills import skills_app
from itskill.cli.tasks import tasks_app
from itskill.cli.train import train_cmd

app = typer.Typer(
    no_args_is_help=True,
    add_completion=False,
    help="Robot manipulation skills on MuJoCo Franka tasks (hex nuts on bolts, pegs in holes).",
)
app.add_typer(tasks_app, name="tasks")
app.add_typer(skills_app, name="skills")
app.command("eval")(eval_cmd)
app.command("train")(train_cmd)
app.command("render")(render_cmd)
app.command("demo")(demo)

__all__ = ["app"]
