"""`itskill learn "COMMAND"`: plan, generate the reward, transfer, evaluate, add the skill."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from itskill.cli.common import (
    console,
    err_console,
    run_dir_option,
    seed_option,
    steps_option,
    user_errors,
)


def learn_cmd(
    command: Annotated[
        str,
        typer.Argument(
            help="What the robot should do, e.g. 'Pick up the nut and place it on the bolt'."
        ),
    ],
    budget: Annotated[
        str, typer.Option(help="tiny (about 1.5 minutes), default, or full (the paper's settings).")
    ] = "default",
    steps: Annotated[
        int | None,
        steps_option("Env-steps of the transfer training (overrides the budget's)."),
    ] = None,
    llm: Annotated[
        str | None,
        typer.Option(
            help="offline (rule-based, no network) or openai:MODEL "
            "(OPENAI_BASE_URL and OPENAI_API_KEY; any OpenAI-compatible server); "
            "default $ITSKILL_LLM_MODEL, else offline."
        ),
    ] = None,
    out: Annotated[
        Path | None, run_dir_option("Run directory (default: runs/learn/<command slug>).")
    ] = None,
    seed: Annotated[
        int,
        seed_option(
            "Seed of the run: the transfer training, and the reward search's seeds shifted by it."
        ),
    ] = 0,
    resume: Annotated[
        bool, typer.Option("--resume", help="Continue an interrupted run in the same directory.")
    ] = False,
    budgets: Annotated[
        Path | None, typer.Option(help="A budgets file instead of the packaged learn.toml.")
    ] = None,
    video: Annotated[
        bool, typer.Option("--video/--no-video", help="Film the final policy in the report.")
    ] = True,
    min_success: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            max=1.0,
            help="Success the new skill needs to join the skill space (default: the budget's; "
            "on --resume, the run's; given on --resume, a policy kept out is added if it "
            "reaches it).",
        ),
    ] = None,
) -> None:
    """Learn a new task from a command, end to end, and add it to the skill space."""  # fmt: skip
    from itskill.experiments.learn import learn, learn_dir
    from itskill.experiments.learn_layout import LEARN_FILE

    try:
        with user_errors():
            learn(
                command, budget, steps, llm, out, seed, resume, budgets, video, console,
                min_success,
            )  # fmt: skip
    except KeyboardInterrupt:
        # Stopped before its plan, a new run leaves nothing (--resume would find no run).
        if (learn_dir(command, out) / LEARN_FILE).is_file():
            hint = "continue with the same command and --resume"
        else:
            hint = "nothing was kept; run the same command again"
        err_console.print(f"interrupted; {hint}")
        raise typer.Exit(130) from None
