"""Prompts as text files a user can read and edit, and the builders that fill them.

The templates live in ``itskill/llm/prompts/*.txt`` with ``{placeholder}`` fields (literal braces
doubled, as in :meth:`str.format`). A directory named by ``$ITSKILL_PROMPTS_DIR`` overrides any of
them file by file. Every template is checked against the fields its builder fills: a missing or
unknown field is a :class:`PromptError` naming the template, so an edit that breaks a prompt fails
at once instead of sending a half-filled prompt to a paid model. So is a template that is blank or
not UTF-8 text, an ``$ITSKILL_PROMPTS_DIR`` that is not a directory, and anything in it that is not
a known template's file: a misspelt file would otherwise be ignored without a word.

Structured parts of a prompt sit between tags (``<command>``, ``<catalogue>``,
``<task_description>``, ``<policy_feedback>``, ``<execution_error>``, ``<target>``,
``<sources>``): a model reads them as delimiters, and the offline backend parses them.
"""

from __future__ import annotations

import inspect
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from functools import cache
from importlib import resources
from pathlib import Path

from itskill.datafile import NotUTF8Error, placeholders, utf8_text
from itskill.llm.client import Message
from itskill.sim.context import CONTEXT_DOC
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.tasks.predicates import PREDICATES
from itskill.tasks.spec import TaskSpec

PROMPTS_DIR_ENV = "ITSKILL_PROMPTS_DIR"

TEMPLATE_FIELDS: dict[str, frozenset[str]] = {
    "planner_system": frozenset(),
    "planner_user": frozenset({"catalogue", "command"}),
    "reward_system": frozenset(),
    "reward_environment": frozenset({"context_doc", "observation_layout"}),
    "reward_task": frozenset({"task_description"}),
    "reward_constraints": frozenset(),
    "policy_feedback": frozenset({"success_rate", "stats_table", "code", "iteration"}),
    "execution_error": frozenset({"code", "error", "iteration"}),
    "analyzer_system": frozenset(),
    "analyzer_user": frozenset({"target", "sources"}),
    "analyzer_retry": frozenset({"error", "m", "n"}),
    "task_description": frozenset(
        {"command", "subtasks", "objects", "fixtures", "stages", "success", "predicates"}
    ),
}
"""Every template and the fields it must contain, exactly."""

CATALOGUE_KEYS = ("task", "family", "command", "actions", "steps", "objects", "fixtures")
_OPTIONAL_CATALOGUE_KEYS = {"steps": "actions"}
"""A catalogue key an entry may leave out, and the key whose value it then takes: a catalogue
built before tasks listed their steps apart from their stages."""
TRANSFER_KEYS = ("id", "description", "actions")
STAT_KEYS = ("max", "mean", "min")


class PromptError(ValueError):
    """A template that does not match its builder, or a builder argument of the wrong shape."""


def prompts_dir() -> Path | None:
    """The user's template directory (``$ITSKILL_PROMPTS_DIR``), checked; None when unset.

    :class:`PromptError` if it is not a directory, or holds anything but known templates' files
    (hidden files, such as an editor's, aside): an override that would not be used must say so.
    """
    override = os.environ.get(PROMPTS_DIR_ENV)
    if not override:
        return None
    path = Path(override).expanduser()
    if not path.is_dir():
        # As ITSKILL_TASKS_DIR: a mistyped directory would otherwise leave every packaged prompt
        # in use, and the user believing their edits were sent.
        problem = "not a directory" if path.exists() else "no such directory"
        raise PromptError(f"{path}: {PROMPTS_DIR_ENV}: {problem}")
    known = {f"{name}.txt" for name in TEMPLATE_FIELDS}
    try:
        entries = sorted(path.iterdir())
    except OSError as err:
        raise PromptError(f"{path}: {PROMPTS_DIR_ENV}: cannot read: {err.strerror or err}") from err
    for entry in entries:
        if entry.name.startswith("."):
            continue
        if entry.name not in known:
            raise PromptError(
                f"{entry}: {PROMPTS_DIR_ENV}: not a prompt template's file; known: "
                f"{', '.join(sorted(known))}"
            )
        if not entry.is_file():
            raise PromptError(f"{entry}: {PROMPTS_DIR_ENV}: not a file")
    return path


def _template_path(name: str) -> Path:
    """The file of template ``name``: the user's, if their directory has it, else the packaged."""
    override = prompts_dir()
    if override is not None and (override / f"{name}.txt").is_file():
        return override / f"{name}.txt"
    return Path(str(resources.files("itskill.llm") / "prompts" / f"{name}.txt"))


@cache
def _load_template(path: Path, name: str) -> str:
    try:
        text = utf8_text(path.read_bytes())
    except OSError as err:
        raise PromptError(f"prompt template {name!r}: cannot read {path}: {err}") from err
    except NotUTF8Error as err:
        raise PromptError(f"prompt template {name!r} ({path}): {err}; save it as UTF-8") from err
    check_template(name, text, path)
    return text


def check_template(name: str, text: str, where: Path | str = "") -> None:
    """Raise :class:`PromptError` if ``text`` does not have exactly the fields of ``name``."""
    label = f"prompt template {name!r}" + (f" ({where})" if where else "")
    if not text.strip():
        # A template without fields (a system prompt) would pass the field check empty, and the
        # model would be sent no instructions at all.
        raise PromptError(
            f"{label}: is blank; write the prompt, or delete the file to use the packaged one"
        )
    try:
        fields = placeholders(text)
    except ValueError as err:
        raise PromptError(f"{label}: {err}") from err
    expected = TEMPLATE_FIELDS[name]
    for field in fields:
        if not field.isidentifier():
            raise PromptError(
                f"{label}: field {{{field}}} is not a plain name (literal braces are {{{{ }}}})"
            )
        if field not in expected:
            allowed = ", ".join(sorted(expected)) or "none"
            raise PromptError(f"{label}: unknown field {{{field}}}; allowed fields: {allowed}")
    missing = sorted(expected - set(fields))
    if missing:
        raise PromptError(f"{label}: missing field(s) {', '.join('{' + m + '}' for m in missing)}")
    try:
        # A format spec or conversion ({command:d}) fails only when the prompt is built.
        text.format(**dict.fromkeys(expected, "text"))
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as err:
        raise PromptError(f"{label}: cannot be filled with text: {err}") from err


def template_text(name: str) -> str:
    """Template ``name`` as it will be rendered: the user's override where
    ``$ITSKILL_PROMPTS_DIR`` has one, else the packaged file (checked either way)."""
    if name not in TEMPLATE_FIELDS:
        raise PromptError(f"unknown prompt template {name!r}; known: {', '.join(TEMPLATE_FIELDS)}")
    return _load_template(_template_path(name), name)


def render(name: str, **fields: str) -> str:
    """Template ``name`` filled with ``fields``."""
    return template_text(name).format(**fields).strip() + "\n"


# --------------------------------------------------------------------------- planner
def planner_messages(command: str, catalogue: list[dict]) -> list[Message]:
    """The task planner's prompt: the command and the catalogue of trainable tasks (as JSON)."""
    if not isinstance(command, str) or not command.strip():
        raise PromptError("the command is empty: say what the robot should do")
    for k, entry in enumerate(catalogue):
        missing = [
            key
            for key in CATALOGUE_KEYS
            if key not in entry and key not in _OPTIONAL_CATALOGUE_KEYS
        ]
        if missing:
            raise PromptError(f"catalogue entry {k} lacks {', '.join(missing)}")
    shown = [
        {
            key: entry[key if key in entry else _OPTIONAL_CATALOGUE_KEYS[key]]
            for key in CATALOGUE_KEYS
        }
        for entry in catalogue
    ]
    body = json.dumps(shown)
    return [
        {"role": "system", "content": render("planner_system")},
        {
            "role": "user",
            "content": render("planner_user", catalogue=body, command=command.strip()),
        },
    ]


# --------------------------------------------------------------------------- reward generator
def reward_messages(task_description: str) -> list[Message]:
    """The reward generator's prompt: system, then environment, task description and constraints.

    The last three parts go in one user message: some chat templates (llama.cpp, Ollama) reject
    consecutive messages of the same role.
    """
    if not task_description.strip():
        raise PromptError("the task description is empty")
    user = "\n".join(
        [
            render(
                "reward_environment",
                context_doc=CONTEXT_DOC,
                observation_layout=OBSERVATION_LAYOUT.describe(),
            ),
            render("reward_task", task_description=task_description.strip()),
            render("reward_constraints"),
        ]
    )
    return [
        {"role": "system", "content": render("reward_system")},
        {"role": "user", "content": user},
    ]


def policy_feedback(
    code: str,
    success_rate: float,
    stats: Mapping[str, Mapping[str, float]],
    iteration: int = 1,
) -> str:
    """The Eureka reflection: how the policy trained with ``code`` did, component by component.

    ``iteration`` (1-based) is the iteration the reply is for. The best reward often stays the
    same from one iteration to the next; without the number the request would be the same too,
    and a seeded or cached model would answer with the rewards it has already written.
    """
    if not 0.0 <= float(success_rate) <= 1.0:
        raise PromptError(f"success_rate must be in [0, 1], got {success_rate!r}")
    rows = ["component | max | mean | min"]
    for name, values in stats.items():
        missing = [key for key in STAT_KEYS if key not in values]
        if missing:
            raise PromptError(f"stats[{name!r}] lacks {', '.join(missing)}")
        numbers = [float(values[key]) for key in STAT_KEYS]
        if not all(math.isfinite(v) for v in numbers):
            raise PromptError(f"stats[{name!r}] has a non-finite value: {numbers}")
        rows.append(f"{name} | " + " | ".join(f"{v:.4g}" for v in numbers))
    return render(
        "policy_feedback",
        success_rate=f"{float(success_rate):.3f}",
        stats_table="\n".join(rows),
        code=code.strip(),
        iteration=str(int(iteration)),
    )


def execution_error_feedback(code: str, error: str, iteration: int = 1) -> str:
    """Ask for a corrected function after ``code`` failed the sandbox or raised.

    ``iteration`` (1-based) is the search iteration the reply is for, as in
    :func:`policy_feedback`: two iterations in a row that train nothing and end on the same
    failure would otherwise send the same request, which the reply cache then answers with the
    replies it already holds."""
    return render(
        "execution_error",
        code=code.strip(),
        error=error.strip() or "(no message)",
        iteration=str(iteration),
    )


# --------------------------------------------------------------------------- analyzer
def analyzer_messages(target: dict, sources: list[dict]) -> list[Message]:
    """The transfer analyzer's prompt: target and sources as JSON ``{id, description, actions}``."""
    for label, entry in [("target", target)] + [
        (f"sources[{k}]", s) for k, s in enumerate(sources)
    ]:
        missing = [key for key in TRANSFER_KEYS if key not in entry]
        if missing:
            raise PromptError(f"{label} lacks {', '.join(missing)}")
        if not entry["actions"]:
            raise PromptError(f"{label} has no actions")
    if not sources:
        raise PromptError("the analyzer needs at least one source")

    def pick(entry: dict) -> dict:
        return {key: entry[key] for key in TRANSFER_KEYS}

    return [
        {"role": "system", "content": render("analyzer_system")},
        {
            "role": "user",
            "content": render(
                "analyzer_user",
                target=json.dumps(pick(target)),
                sources=json.dumps([pick(s) for s in sources], indent=1),
            ),
        },
    ]


def analyzer_retry(error: str, m: int, n: int) -> str:
    """The follow-up that tells the analyzer what was wrong with its reply: ``error``, and the
    shape the matrix must have (``m`` rows, one per target segment; ``n`` columns, one per
    source)."""
    return render("analyzer_retry", error=error, m=str(int(m)), n=str(int(n)))


# --------------------------------------------------------------------------- task description
def task_description(command: str, subtasks: Sequence[str], task: TaskSpec) -> str:
    """The generator's task-description part for a plan of ``task``: ordered subtasks, objects
    and fixtures with their slots, each stage (``ctx["stage"]`` index, name = action, object slot,
    done condition), the success condition and what every condition used means.

    The stage lines read ``stage K: NAME | object I | done when EXPR``; the offline synthesiser
    parses them, so keep that shape if you edit the template.
    """
    objects = []
    for i, part in enumerate(task.objects):
        fixture = task.object_fixture[i] if i < len(task.object_fixture) else 0
        objects.append(f"  object {i}: {part.name} ({_describe_part(part)}), for fixture {fixture}")
    fixtures = [
        f"  fixture {j}: {placed.part.name} ({_describe_part(placed.part)}) at "
        f"x={placed.xy[0]:.3f} m, y={placed.xy[1]:.3f} m"
        for j, placed in enumerate(task.fixtures)
    ] or ["  (none)"]
    stages = []
    used: list[str] = []
    previous: set = set()
    for k, stage in enumerate(task.stages):
        # The stage acts on the object of its new conditions ("engaged(0) and near(1)" after
        # "engaged(0)" is about object 1).
        terms = stage.done.terms
        new = [t for t in terms if not t[0] and t not in previous] or list(terms)
        slot = int(new[-1][2][0])
        stages.append(f"  stage {k}: {stage.name} | object {slot} | done when {stage.done.source}")
        used += [name for _, name, _ in terms]
        previous = set(terms)
    used += [name for _, name, _ in task.success.terms]
    return render(
        "task_description",
        command=command.strip(),
        subtasks="\n".join(f"  {s}" for s in subtasks) or "  (none)",
        objects="\n".join(objects),
        fixtures="\n".join(fixtures),
        stages="\n".join(stages),
        success=task.success.source,
        predicates="\n".join(_describe_predicate(n) for n in dict.fromkeys(used)),
    ).strip()


def _describe_part(part) -> str:
    kind = part.kind
    if kind == "nut":
        return (
            f"hex nut, across-flats {part.across_flats:.4f} m, height {part.height:.4f} m, "
            f"thread pitch {part.pitch:.5f} m"
        )
    if kind == "peg":
        size = (
            f"diameter {part.diameter:.4f} m"
            if part.shape == "round"
            else f"{part.width:.4f} x {part.depth:.4f} m"
        )
        shape = "round" if part.shape == "round" else "rectangular"
        return f"{shape} peg, {size}, length {part.length:.4f} m"
    if kind == "bolt":
        return (
            f"bolt, thread diameter {part.thread_diameter:.4f} m, tip at z={part.tip_z:.4f} m, "
            f"seat (head top) at z={part.seat_z:.4f} m"
        )
    return (
        f"{part.shape} hole, entrance at z={part.entrance_z:.4f} m, depth {part.hole_depth:.4f} m"
    )


def _describe_predicate(name: str) -> str:
    fn = PREDICATES[name]
    params = list(inspect.signature(fn).parameters.values())[1:]  # drop ctx
    signature = ", ".join(
        p.name if p.default is inspect.Parameter.empty else f"{p.name}={p.default}" for p in params
    )
    doc = (inspect.getdoc(fn) or "").split("\n\n")[0]
    doc = re.sub(r"``([^`]*)``", r"\1", " ".join(doc.split()))
    return f"  {name}({signature}): {doc}"
