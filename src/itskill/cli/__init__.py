"""The ``itskill`` command: one Typer app, a module per command group.

Thin by design: each command parses its options, calls one library function and prints the result.
"""

from __future__ import annotations

import signal
import warnings

import typer

from itskill.cli.common import show_warning_line
from itskill.cli.episodes import demo, eval_cmd, render_cmd
from itskill.cli.experiment import experiment_app, report_cmd
from itskill.cli.learn import learn_cmd
from itskill.cli.reward import plan_cmd, reward_app
from itskill.cli.skills import skills_app
from itskill.cli.tasks import tasks_app
from itskill.cli.train import train_cmd
from itskill.cli.transfer import transfer_app

app = typer.Typer(
    no_args_is_help=True,
    add_completion=False,
    help="Robot manipulation skills on MuJoCo Franka tasks (hex nuts on bolts, pegs in holes).",
)


@app.callback()
def _before_every_command() -> None:
    """Robot manipulation skills on MuJoCo Franka tasks (hex nuts on bolts, pegs in holes)."""
    # A batch scheduler's or `kill`'s SIGTERM, and a closed terminal's SIGHUP, stop a command as
    # Ctrl-C does: the training in progress saves its checkpoint and the run can be resumed.
    # Left at their defaults they ended the process there and then, losing everything since the
    # last checkpoint.
    # A signal the command was started with ignored stays ignored: `nohup` ignores SIGHUP so
    # that a run outlives the terminal.
    for sig in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, signal.default_int_handler)
    # Again per command (itskill.cli.common sets it on import, for the simulator's import-time
    # warning): whoever runs the app in-process, a test runner among them, may have replaced it.
    warnings.showwarning = show_warning_line


app.add_typer(tasks_app, name="tasks")
app.add_typer(skills_app, name="skills")
app.command("eval")(eval_cmd)
app.command("train")(train_cmd)
app.command("render")(render_cmd)
app.command("demo")(demo)
app.command("plan")(plan_cmd)
app.add_typer(reward_app, name="reward")
app.add_typer(transfer_app, name="transfer")
app.add_typer(experiment_app, name="experiment")
app.command("report")(report_cmd)
app.command("learn")(learn_cmd)

__all__ = ["app"]
