"""What every command shares: consoles, option types, error handling, JSON output."""

from __future__ import annotations

import json
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, TextIO

import typer
from rich.console import Console
from rich.markup import escape

from itskill.files import is_unusable_path, json_safe, path_error_message
from itskill.limits import EPISODES_MAX, SEED_MAX, STEPS_MAX, WORKERS_MAX

# No emoji codes: user text such as `skill:x:` must print as typed, and escape() leaves them.
console = Console(emoji=False)


# Soft wrap: a long path in an error message must stay copyable, not be folded at 80 columns.
err_console = Console(stderr=True, soft_wrap=True, emoji=False)
_python_showwarning = warnings.showwarning


def show_warning_line(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: TextIO | None = None,
    line: str | None = None,
) -> None:
    """``warnings.showwarning`` for the commands: itskill's own warnings as one yellow line on
    stderr (the source line that raised one means nothing to a user), others as Python shows
    them."""
    if category.__module__.partition(".")[0] == "itskill":
        err_console.print(f"[yellow]warning:[/yellow] {escape(str(message))}", highlight=False)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


# Set on import, not per command: the command modules import the simulator, whose MUJOCO_GL
# check warns as it is imported.
warnings.showwarning = show_warning_line


USAGE_ERROR = 2


TaskArg = Annotated[str, typer.Argument(help="Task id (see `itskill tasks list`).")]


def _a_policy(value: str) -> str:
    # An empty --policy (a variable that expanded to nothing) would be read as the current
    # directory and fail on its missing checkpoint.json, a message about the wrong thing.
    if not value:
        raise typer.BadParameter("a policy is required: 'scripted', skill:NAME or a checkpoint")
    return value


SCRIPTED = "scripted"
"""The task's scripted controller, as ``--policy`` names it: the evaluators'
:data:`itskill.tasks.evaluate.SCRIPTED`, whose module loads PyTorch, which a command imports only
once it runs."""


PolicyOpt = Annotated[
    str,
    typer.Option(
        help="'scripted', 'skill:NAME' (a skill of the skill space), a training run directory "
        "(itskill train --out; its last checkpoint, RUN/best for its best evaluated policy), "
        "its policy.safetensors or an SB3 .zip.",
        callback=_a_policy,
    ),
]


def seed_option(help: str) -> Any:
    """A ``--seed`` option: a non-negative integer NumPy and Stable-Baselines3 can seed with."""
    return typer.Option(help=help, min=0, max=SEED_MAX)


SeedOpt = Annotated[int, seed_option("Seed of the initial-state sequence.")]


def _not_the_current_directory(value: Path | None) -> Path | None:
    # Typer reads an empty --out (a variable that expanded to nothing) as ".", which would put
    # the run's checkpoints and logs among the user's own files.
    if value is not None and value.expanduser().resolve() == Path.cwd().resolve():
        raise typer.BadParameter("name a directory of its own, not the current one")
    return value


def run_dir_option(help: str) -> Any:
    """An option naming a directory itskill fills (a run, a library): anything but the current
    directory."""
    return typer.Option(help=help, callback=_not_the_current_directory)


JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")]


MarkdownOpt = Annotated[bool, typer.Option("--markdown", help="Print a Markdown table.")]


def check_one_format(as_json: bool, markdown: bool) -> None:
    """Refuse ``--json`` with ``--markdown``: a command prints one format, and choosing one
    silently hands whoever wanted the other the wrong output."""
    if as_json and markdown:
        raise typer.BadParameter("give --json or --markdown, not both", param_hint="--markdown")


CameraOpt = Annotated[str, typer.Option(help="Camera: front or closeup.")]


HyperparamsOpt = Annotated[
    Path | None,
    typer.Option(
        help="A hyper-parameter TOML file instead of the packaged one, whole: a field it leaves "
        "out takes the dataclass default, not the packaged value (copy the packaged file)."
    ),
]


EvalEveryOpt = Annotated[
    int | None,
    typer.Option(
        min=1,
        help="Evaluate the deterministic policy every N env-steps (eval.csv); the best one is "
        "kept in OUT/best.",
    ),
]


def episodes_option(help: str) -> Any:
    """An episode-count option: 1 to :data:`EPISODES_MAX`."""
    return typer.Option(help=help, min=1, max=EPISODES_MAX)


def workers_option(help: str) -> Any:
    """A ``--workers`` option: 1 to :data:`WORKERS_MAX` processes (or Ray tasks) at once, as the
    settings files allow."""
    return typer.Option(help=help, min=1, max=WORKERS_MAX)


def steps_option(help: str, least: int = 1) -> Any:
    """An env-step budget option: ``least`` to :data:`STEPS_MAX`."""
    return typer.Option(help=help, min=least, max=STEPS_MAX)


EvalEpisodesOpt = Annotated[int, episodes_option("Episodes per evaluation.")]


def print_trained(what: str, result: Any, steps: int) -> None:
    """One line on a finished training run (a ``TrainResult``) asked for ``steps`` env-steps:
    steps, where, its best policy."""
    # Training stops at the first whole rollout at or past the budget: say so, or a user who
    # asked for 64 reads 128 as a bug.
    past = f" (whole rollouts: {steps:,} asked)" if result.num_timesteps > steps else ""
    line = (
        f"trained {what}: {result.num_timesteps:,} env-steps in total{past}{result.resume_note}; "
    )
    line += f"checkpoint in {result.run_dir}"
    if result.best is not None:
        line += (
            f"; best evaluation {result.best['success']:.0%} at "
            f"{int(result.best['env_steps']):,} env-steps, policy in {result.run_dir}/best"
        )
    # Not markup: the task and the run directory are the user's text ('runs/[v2]').
    console.print(line, highlight=False, markup=False)


def usage_error(message: str) -> typer.Exit:
    """Print ``message`` as one red ``error:`` line on stderr; returns the exit (code 2) to raise.

    The message is printed as written: the file and skill names in it are the user's text, and
    rich would read ``reward[v2].py`` or ``pick[/v2]`` as markup (dropping text, or failing).
    """
    err_console.print(f"[red]error:[/red] {escape(message)}", highlight=False)
    return typer.Exit(USAGE_ERROR)


USER_ERRORS: tuple[tuple[str, str], ...] = (
    # Every data file (tasks, parts, hyper-parameters, search and transfer settings, experiments,
    # learn budgets) reports through a subclass of this one.
    ("itskill.datafile", "DataFileError"),
    ("itskill.executors", "ExecutorError"),
    ("itskill.curves", "CurveError"),
    ("itskill.experiments.learn", "LearnError"),
    ("itskill.experiments.report", "ReportError"),
    ("itskill.experiments.runner", "ExperimentRunError"),
    ("itskill.files", "CorruptFileError"),
    ("itskill.llm.client", "LLMError"),
    ("itskill.llm.prompts", "PromptError"),
    ("itskill.reward.plan", "PlanError"),
    ("itskill.reward.search", "RewardSearchError"),
    ("itskill.rl.demos", "DemoError"),
    ("itskill.rl.train", "ResumeMismatchError"),
    ("itskill.rl.train", "RewardLoadError"),
    ("itskill.sim.batch", "UnreachableStartError"),
    ("itskill.skills.store", "SkillSpaceError"),
    ("itskill.tasks.evaluate", "CheckpointError"),
    ("itskill.tasks.render", "RenderError"),
    ("itskill.tasks.scripted", "ScriptError"),
    ("itskill.tasks.spec", "UnknownTaskError"),
    ("itskill.transfer.analyzer", "AnalyzerError"),
    ("itskill.transfer.sources", "IncompatibleSourceError"),
    ("itskill.transfer.sources", "SourceError"),
    ("itskill.transfer.trace", "TraceError"),
)
"""The errors the user can act on (their input, files or environment), as (defining module,
class name): :func:`user_errors` prints them as one line."""


def _is_user_error(err: Exception) -> bool:
    """Whether ``err`` is one of :data:`USER_ERRORS`."""
    # Only classes of modules already imported: an error of a module never imported cannot have
    # been raised, and importing them all to check (PyTorch, for itskill.rl.train) would make
    # every such message, and every command, wait seconds.
    classes = tuple(
        getattr(sys.modules[module], name) for module, name in USER_ERRORS if module in sys.modules
    )
    return isinstance(err, classes)


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn errors the user can act on (:data:`USER_ERRORS`, a path that cannot be used) into a
    red one-line message and exit code 2; any other error is a bug and keeps its traceback."""
    try:
        yield
    except OSError as err:
        if not is_unusable_path(err):
            raise
        raise usage_error(path_error_message(err)) from err
    except Exception as err:
        if not _is_user_error(err):
            raise
        raise usage_error(str(err)) from err


def print_json(data: Any) -> None:
    """Print ``data`` as indented JSON that any reader takes (a non-finite number, as a skill
    space written before its measurements were checked may hold, as null)."""
    # Plain stdout, not rich: JSON must not be wrapped or coloured.
    typer.echo(json.dumps(json_safe(data), indent=2))


SKILL_PREFIX = "skill:"


def policy_source(policy: str) -> str | Path:
    """Where the policy ``policy`` names loads from: for ``skill:NAME`` (a skill of the skill
    space), a training run directory or a checkpoint file (its ``policy.safetensors``, as the
    skill space lists it, or an SB3 ``.zip``), the checkpoint's directory or ``.zip``; other
    references (``scripted``, a path that does not exist) as given, to be refused with their own
    message."""
    from itskill.rl.checkpoint import policy_location

    if policy.startswith(SKILL_PREFIX):
        return policy_location(skill_checkpoint(policy[len(SKILL_PREFIX) :]))
    if Path(policy).is_file():
        return policy_location(policy)
    return policy


def policy_ref(policy: str) -> Any:
    """The policy ``policy`` names (:func:`policy_source`) as the evaluators take it: a
    checkpoint's directory becomes a policy factory (:func:`itskill.rl.checkpoint.as_policy`)."""
    from itskill.rl.checkpoint import as_policy

    return as_policy(policy_source(policy))


def skill_checkpoint(name: str) -> Path:
    """The checkpoint file of skill ``name``; :class:`CheckpointError` if the skill is unknown or
    its checkpoint is gone (the space keeps a skill whose files were deleted or moved)."""
    from itskill.skills import open_skill_space
    from itskill.skills.store import SkillSpaceError
    from itskill.tasks.evaluate import CheckpointError

    ref = SKILL_PREFIX + name
    try:
        with open_skill_space() as space:
            policy_file = space.checkpoint_path(space.get(name))
    except SkillSpaceError as err:
        raise CheckpointError(ref, str(err)) from err
    if not policy_file.is_file():
        raise CheckpointError(
            ref,
            f"the checkpoint of skill {name!r} is missing: no file {policy_file} (deleted or "
            f"moved; `itskill skills remove {name}` drops the skill)",
        )
    return policy_file
