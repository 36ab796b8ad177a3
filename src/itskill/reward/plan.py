"""The task planner: a short command becomes a validated :class:`TaskPlan`.

The language model reads the command and the task catalogue (every task the scene can run, with its
actions and parts) and answers with the task it means, ordered "First, ... Second, ..." subtasks,
the action sequence and the objects. The reply is checked against the task files: the task must
exist, the actions must be its stage names in order and the objects its parts. A reply that does
not validate is sent back with what is wrong, a few times, before :class:`PlanError`.

A task id needs no model: :func:`plan_for_task` writes the plan straight from the task file.
:meth:`TaskPlan.describe` renders the task-description part of the reward generator's prompt.
"""

from __future__ import annotations

import difflib
from dataclasses import asdict, dataclass
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from itskill.datafile import DataFileError, check_format_text, check_table, read_toml
from itskill.llm.client import LLMClient, Message
from itskill.llm.prompts import planner_messages, task_description
from itskill.llm.replies import JSONReplyError, parse_json_reply
from itskill.sim.parts import BoltSpec, NutSpec
from itskill.tasks import all_tasks, get_task
from itskill.tasks.spec import TaskSpec

PLAN_ATTEMPTS = 3
"""How many replies the planner asks for before giving up on a command."""

LIST_TASKS = "`itskill tasks list`"
"""The command that lists every task, which an error points to instead of listing them all."""
CLOSEST_TASKS = 3
CLOSEST_CUTOFF = 0.5
"""How alike (difflib's ratio) a task's command must be to the user's to be suggested: below it,
"make me a sandwich" would be offered "Grasp the round peg" as its closest task."""

_HOLDING_AFTER = {"grasp", "lift", "carry"}
_RELEASED_AFTER = {"place", "insert", "release", "screw"}


class PlanError(ValueError):
    """A command that cannot be grounded in the scene; the message says why, names the closest
    tasks and how to list them all."""


class PlanDataError(DataFileError):
    """A ``plan.toml`` that does not validate: names the file, the field and the problem."""


PHRASE_FIELDS = frozenset({"object", "fixture"})
"""The placeholders a phrase of ``plan.toml`` may use."""
CORRECTION_FIELDS = frozenset({"problem"})
"""The placeholders the correction note must use, exactly."""


@dataclass(frozen=True)
class TaskPlan:
    """What the robot must do: the task, its ordered subtasks and action sequence, its parts."""

    command: str
    task: str
    subtasks: tuple[str, ...]
    actions: tuple[str, ...]
    objects: tuple[str, ...]
    notes: str = ""

    def describe(self) -> str:
        """The task-description part of the reward generator's prompt.

        Everything a reward writer needs beyond the reward context's documentation: the command,
        the subtasks in order, the stages as ``ctx["stage"]`` counts them with the condition that
        ends each, the parts in their slots, what counts as success, and the planner's notes.
        """
        text = task_description(self.command, self.subtasks, get_task(self.task))
        return f"{text}\nNotes: {self.notes}" if self.notes else text

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Any, where: str = "plan") -> TaskPlan:
        """A plan from :meth:`to_dict`'s output; ``ValueError`` naming ``where`` and the field."""
        if not isinstance(data, dict):
            raise ValueError(f"{where}: expected a JSON object, got {type(data).__name__}")
        values: dict[str, Any] = {}
        for key in ("command", "task", "notes"):
            value = data.get(key, "" if key == "notes" else None)
            if not isinstance(value, str):
                raise ValueError(f"{where}.{key}: expected a string, got {value!r}")
            values[key] = value
        for key in ("subtasks", "actions", "objects"):
            value = data.get(key)
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"{where}.{key}: expected a list of strings, got {value!r}")
            values[key] = tuple(value)
        return cls(**values)


def plan_data_path() -> Path:
    """The packaged ``plan.toml``: ordinals, phrases and the planner's correction note."""
    return Path(str(resources.files("itskill.reward") / "data" / "plan.toml"))


def load_plan_data(path: Path) -> dict[str, Any]:
    """The plan data in ``path``, every entry checked (:class:`PlanDataError` names the first
    problem): ``ordinals`` a list of words, ``correction`` a note with ``{problem}``, ``phrases``
    a table of action -> sentence using ``{object}`` and ``{fixture}``."""
    data = read_toml(path, PlanDataError)
    keys = ("ordinals", "correction", "phrases")
    check_table(path, "", data, PlanDataError, keys)
    for key in keys:
        if key not in data:
            raise PlanDataError(path, key, "missing (required)")
    ordinals = data.get("ordinals")
    if not isinstance(ordinals, list) or not ordinals:
        raise PlanDataError(path, "ordinals", f"expected a non-empty list, got {ordinals!r}")
    for k, word in enumerate(ordinals):
        # An ordinal goes into the sentence as is: a brace in it would do no harm, but a blank
        # would make "First, ..." read ", ...".
        if not isinstance(word, str) or not word.strip():
            raise PlanDataError(path, f"ordinals[{k}]", f"expected a word, got {word!r}")
    # Tried with a part's name in every placeholder, as a plan fills them.
    correction = dict.fromkeys(CORRECTION_FIELDS, "the M12 nut")
    check_format_text(path, "correction", data.get("correction"), correction, PlanDataError, True)
    phrases = check_table(path, "phrases", data["phrases"], PlanDataError)
    phrase_fields = dict.fromkeys(PHRASE_FIELDS, "the M12 nut")
    for action, phrase in phrases.items():
        check_format_text(path, f"phrases.{action}", phrase, phrase_fields, PlanDataError)
    return data


@cache
def _plan_data() -> dict[str, Any]:
    return load_plan_data(plan_data_path())


def _shape(shape: str) -> str:
    return "rectangular" if shape == "rect" else shape


def _part_name(part: Any) -> str:
    """What a sentence calls a part: "the M12 nut", "the round hole"."""
    if isinstance(part, NutSpec | BoltSpec):
        return f"the M{part.thread_diameter * 1000:.0f} {part.kind}"
    return f"the {_shape(part.shape)} {part.kind}"


def subtask_sentences(spec: TaskSpec) -> tuple[str, ...]:
    """The task's stages as ordered sentences: "First, move the gripper to the M12 nut.", ...

    :class:`PlanError` for a task (a user's, say) with more stages than ``plan.toml`` has
    ordinals, or a stage whose action has no phrase there.
    """
    data = _plan_data()
    ordinals, phrases = data["ordinals"], data["phrases"]
    task = f"task {spec.id!r}" + (f" ({spec.source})" if spec.source else "")
    if len(spec.stages) > len(ordinals):
        raise PlanError(
            f"{task} has {len(spec.stages)} stages; {plan_data_path()} has ordinals for "
            f"{len(ordinals)}: add ordinals there, or split the task"
        )
    sentences = []
    holding = False
    for k, stage in enumerate(spec.stages):
        # The last term is the stage's own goal (``engaged(0) and near(1, 0.02)``: object 1).
        slot = int(stage.done.terms[-1][2][0])
        key = stage.name
        if key == "approach" and holding:
            key = "approach_holding"
        if key not in phrases:
            raise PlanError(
                f"{task}: stage {k} action {key!r} has no phrase in {plan_data_path()} "
                f"[phrases]; known actions: {', '.join(sorted(phrases))}"
            )
        fixture = spec.fixtures[spec.object_fixture[slot]].part if spec.fixtures else None
        text = phrases[key].format(
            object=_part_name(spec.objects[slot]),
            fixture=_part_name(fixture) if fixture is not None else "its target",
        )
        sentences.append(f"{ordinals[k]}, {text}.")
        if stage.name in _HOLDING_AFTER:
            holding = True
        elif stage.name in _RELEASED_AFTER:
            holding = False
    return tuple(sentences)


def task_catalogue() -> list[dict[str, Any]]:
    """Every task the planner may choose, as the planner prompt shows it.

    ``actions`` are the task's stage names in order (what ``ctx["stage"]`` counts), the sequence a
    plan must reproduce exactly; ``steps`` the skills' actions the task chains, which a command's
    verbs name ("unscrew the nut and take it off" is unscrew, grasp, lift; the task's stages are
    unscrew and lift).
    """
    return [
        {
            "task": t.id,
            "family": t.family,
            "command": t.command,
            "actions": [s.name for s in t.stages],
            "steps": list(t.actions),
            "objects": [o.name for o in t.objects],
            "fixtures": [f.part.name for f in t.fixtures],
        }
        for t in all_tasks().values()
    ]


def plan_for_task(task_id: str) -> TaskPlan:
    """The plan of a known task, straight from its file (no language model)."""
    spec = get_task(task_id)
    return TaskPlan(
        command=spec.command,
        task=spec.id,
        subtasks=subtask_sentences(spec),
        actions=tuple(s.name for s in spec.stages),
        objects=tuple(o.name for o in spec.objects),
        notes="",
    )


def check_command(command: str) -> None:
    """:class:`PlanError` for an empty or blank command, with an example of a good one, or for
    one that is not text (bytes of another encoding, which Python hands over as lone
    surrogates that no request, cache key or file name can carry)."""
    try:
        command.encode("utf-8")
    except UnicodeEncodeError as err:
        char = ord(command[err.start])
        # Arguments are decoded with surrogateescape: U+DC80..U+DCFF is the raw byte 0x80..0xFF.
        what = f"the byte {char - 0xDC00:#04x}" if 0xDC80 <= char <= 0xDCFF else f"U+{char:04X}"
        raise PlanError(
            f"the command is not UTF-8 text ({what} after {command[: err.start]!r}): type it "
            "again in a UTF-8 terminal"
        ) from None
    if not command.strip():
        example = next(t.command for t in all_tasks().values() if t.table_i)
        raise PlanError(
            f'the command is empty: say what the robot should do, e.g. "{example}", or give a '
            f"task id ({LIST_TASKS} lists them)"
        )


def plan_command(command: str, client: LLMClient, attempts: int = PLAN_ATTEMPTS) -> TaskPlan:
    """Plan ``command`` with ``client``; re-ask up to ``attempts`` times while the reply is invalid.

    Raises :class:`PlanError` for an empty command, when the model says the command cannot be
    grounded in the scene, or gives no valid plan in ``attempts`` replies; the message names the
    closest tasks and how to list them all.
    """
    check_command(command)
    command = " ".join(command.split())
    messages: list[Message] = planner_messages(command, task_catalogue())
    problem = ""
    for _ in range(attempts):
        reply = client.complete(messages, n=1, purpose="plan", temperature=0.0)[0]
        try:
            data = parse_json_reply(reply)
            # A model in JSON mode often writes every key it was shown: "error": null beside a
            # plan is no refusal.
            if data.get("error"):
                raise PlanError(
                    f"cannot plan {command!r} ({client.name}): {data['error']}. "
                    + known_text(command)
                )
            return validate_plan(command, data)
        except (JSONReplyError, _InvalidPlan) as err:
            problem = str(err)
        messages = [
            *messages,
            {"role": "assistant", "content": reply},
            {"role": "user", "content": _plan_data()["correction"].format(problem=problem)},
        ]
    raise PlanError(
        f"no valid plan for {command!r} from {client.name} in {attempts} replies; "
        f"the last one: {problem}. " + known_text(command)
    )


class _InvalidPlan(ValueError):
    """A planner reply that does not validate; its message is sent back to the model."""


def validate_plan(command: str, data: dict[str, Any]) -> TaskPlan:
    """Check a planner reply against the task files; :class:`_InvalidPlan` says what is wrong."""
    tasks = all_tasks()
    task = data.get("task")
    if not isinstance(task, str) or task not in tasks:
        raise _InvalidPlan(f"task {task!r} is not in the catalogue")
    spec = tasks[task]
    stage_names = [s.name for s in spec.stages]
    actions = data.get("actions")
    if actions != stage_names:
        raise _InvalidPlan(
            f"actions {actions!r} are not task {task!r}'s action sequence {stage_names!r}"
        )
    object_names = [o.name for o in spec.objects]
    allowed = object_names + [f.part.name for f in spec.fixtures]
    objects = data.get("objects")
    if (
        not isinstance(objects, list)
        or not all(isinstance(o, str) for o in objects)
        or not set(object_names) <= set(objects) <= set(allowed)
    ):
        raise _InvalidPlan(
            f"objects {objects!r} do not match task {task!r}: expected its parts {object_names!r}"
        )
    subtasks = data.get("subtasks")
    if (
        not isinstance(subtasks, list)
        or len(subtasks) != len(stage_names)
        or not all(isinstance(s, str) and s.strip() for s in subtasks)
    ):
        raise _InvalidPlan(
            f"subtasks must be {len(stage_names)} non-empty sentences, one per action, "
            f"got {subtasks!r}"
        )
    # JSON-mode models write null for an empty field, as for "error" above.
    notes = data.get("notes") or ""
    if not isinstance(notes, str):
        raise _InvalidPlan(f"notes must be a string, got {notes!r}")
    return TaskPlan(
        command=command,
        task=task,
        subtasks=tuple(s.strip() for s in subtasks),
        actions=tuple(stage_names),
        objects=tuple(object_names),
        notes=notes.strip(),
    )


def known_text(command: str) -> str:
    """What an error about ``command`` says is known: the objects and fixtures, the tasks whose
    commands are closest to it, and how to list every task (the full list is thousands of
    characters, too long for an error line)."""
    tasks = list(all_tasks().values())
    objects = sorted({o.name for t in tasks for o in t.objects})
    fixtures = sorted({f.part.name for t in tasks for f in t.fixtures})
    by_command = {t.command.lower(): t for t in tasks}
    close = difflib.get_close_matches(
        command.lower(), list(by_command), n=CLOSEST_TASKS, cutoff=CLOSEST_CUTOFF
    )
    closest = "; ".join(f"{by_command[c].id} ({by_command[c].command})" for c in close)
    return (
        f"Known objects: {', '.join(objects)}; fixtures: {', '.join(fixtures)}. "
        + (f"Closest tasks: {closest}. " if closest else "")
        + f"{LIST_TASKS} shows all {len(tasks)} tasks."
    )
