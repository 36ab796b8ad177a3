"""Task specifications: TOML files in ``itskill/tasks/data`` validated into ``TaskSpec`` objects.

``parts.toml`` holds part dimensions; each family file (``nutbolt.toml``, ``peghole.toml``) holds
tasks. A user can add a directory of their own files with ``ITSKILL_TASKS_DIR``. Every problem in a
file is reported with the file, the field and what was expected.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import itertools
import json
import math
import os
import re
from dataclasses import MISSING, dataclass, field, is_dataclass, replace
from functools import cache, cached_property
from importlib import resources
from pathlib import Path
from typing import Any, Literal, get_args, get_origin, get_type_hints

from itskill.datafile import DataFileError, check_table, check_type, is_number, read_toml
from itskill.errors import PicklableError
from itskill.limits import EPISODE_STEPS_MAX
from itskill.sim.context import max_grip_offset
from itskill.sim.controller import ControllerConfig
from itskill.sim.layout import MAX_STAGES
from itskill.sim.parts import (
    BoltSpec,
    HoleSpec,
    NutSpec,
    PartSpecError,
    PegSpec,
    PlacedFixture,
    fits,
    fits_turned,
)
from itskill.sim.scene import SceneSpec
from itskill.sim.task import (
    HAND_MODES,
    InitSpec,
    ObjectInit,
    Range,
    SimTask,
    TrainingStart,
    check_start_shares,
    default_object_fixture,
)
from itskill.tasks.predicates import (
    FIXTURE_PREDICATES,
    Expression,
    PredicateError,
    parse,
    predicate_params,
)

TASKS_DIR_ENV = "ITSKILL_TASKS_DIR"
_PART_KINDS = {"nut": NutSpec, "bolt": BoltSpec, "peg": PegSpec, "hole": HoleSpec}
_INIT_MODES = ("table", "gripper", "fingers", "bolt", "hole")
_MAX_NAME = 64
_PLAIN_NAME = re.compile(rf"[a-z0-9_]{{1,{_MAX_NAME}}}")
"""A task id or part name: what every packaged one is, and safe as a file or directory name."""
_KINDS = ("basic", "complex")
"""A basic task is one skill (pretraining trains every basic task); a complex one chains them."""
_CARRY = "carry"
"""A stage name that stands for the lift and approach actions that move a held part (a task's
actions list what a plan does; its stages what ``ctx["stage"]`` counts)."""


@dataclass(frozen=True)
class _Bounds:
    """Where a start value must lie, and how an error says so."""

    low: float
    high: float
    what: str
    unit: str = " m"


_ARM = ControllerConfig()
# A start outside the controller's workspace is one the arm cannot reach (the hand is clipped
# back at the first step, a part there is out of reach), or far outside (x = 1e300) one the
# simulation cannot hold: either way the episodes fail and read as a measured 0%.
_REACH = {
    axis: _Bounds(low, high, f"within the arm's workspace in {axis}")
    for axis, low, high in zip("xyz", _ARM.workspace_low, _ARM.workspace_high, strict=True)
}
_HAND_YAW = _Bounds(*_ARM.yaw_limits, "within the hand's yaw limits", " rad")
_PART_YAW = _Bounds(-2 * math.pi, 2 * math.pi, "at most a turn either way", " rad")
_MODE_FIELDS = {
    "table": {"x", "y", "yaw"},
    "gripper": {"x", "y", "z", "hold"},
    "fingers": {"x", "y", "z"},
    "bolt": {"turns"},
    "hole": {"depth", "yaw"},
}
"""The start fields each mode reads (``BatchEnv._place_object``); a part in the hand takes the
hand's yaw, a part on its fixture the fixture's place."""
_FIXTURE_MODES = ("bolt", "hole", "gripper")
"""The modes whose ``fixture`` counts: the one a part starts on or in, and the hole a held peg
starts with its bottom in (its turn is checked against that hole's bore)."""


class TaskFileError(DataFileError):
    """A task or parts file that does not validate: names the file, the field and the problem."""


class UnknownTaskError(PicklableError, KeyError):
    """A task name that no task file defines."""

    def __init__(self, name: str, known: list[str]) -> None:
        super().__init__(name)
        self.name, self.known = name, known

    def __str__(self) -> str:
        # Ids are lower case: PICK_NUT_M12 is as near pick_nut_m12 as the typo pick_nut_m21.
        close = difflib.get_close_matches(self.name.strip().lower(), self.known, n=3, cutoff=0.8)
        if close:
            # A typo: the few ids it is near, not all of them (`itskill tasks list` has those).
            return (
                f"unknown task {self.name!r}; did you mean {' or '.join(map(repr, close))}? "
                "(`itskill tasks list` shows every task)"
            )
        return f"unknown task {self.name!r}. Known tasks: {', '.join(self.known)}"


@dataclass(frozen=True)
class Stage:
    """A subtask: its name and the predicate that says it is done."""

    name: str
    done: Expression


@dataclass(frozen=True)
class TaskSpec:
    """One task as written in its file, validated."""

    id: str
    family: str
    kind: str
    command: str
    skills: tuple[str, ...]
    actions: tuple[str, ...]
    objects: tuple[NutSpec | PegSpec, ...]
    fixtures: tuple[PlacedFixture, ...]
    object_fixture: tuple[int, ...]
    init: InitSpec
    stages: tuple[Stage, ...]
    success: Expression
    max_steps: int
    script: tuple[str, ...]
    table_i: bool = False
    description: str = ""
    source: str = ""
    terminate_on_success: bool = False
    tags: tuple[str, ...] = field(default=())
    training_starts: tuple[TrainingStart, ...] = field(default=())
    """Starts used only in training: borrowed from other tasks of the same scene (resolved by
    the registry: a start's ``name`` is the task whose ``init`` it is) or written out in the
    task's file (``name`` empty)."""

    def stage_index(self, ctx) -> Any:
        """Current subtask: one past the furthest stage whose ``done`` predicate holds."""
        import numpy as np

        stage = np.zeros(ctx["ee_pos"].shape[0], dtype=np.int64)
        for k, st in enumerate(self.stages):
            stage = np.where(st.done(ctx), k + 1, stage)
        return np.minimum(stage, len(self.stages) - 1)

    @cached_property
    def fingerprint(self) -> str:
        """A sha256 of what an episode of this task is and how it is scored: its parts and
        fixtures, start, stages (which a policy sees), success and length. A checkpoint records
        it, so resuming or re-measuring a run after the task's file changed is refused rather
        than done on another task.

        It is taken over a canonical form (:func:`_canonical`): a part's colour, how an
        expression is spaced or whether it writes out a default argument, and a field added to
        a spec with a default that keeps today's behaviour do not change it. Not covered: the
        training starts (what a run trains on, not the task it is measured on) and the
        predicates' own code. Computed once per spec (a spec does not change)."""
        what = {
            "objects": self.objects,
            "fixtures": self.fixtures,
            "object_fixture": self.object_fixture,
            "init": self.init,
            "stages": self.stages,
            "success": self.success,
            "max_steps": self.max_steps,
            "terminate_on_success": self.terminate_on_success,
        }
        text = json.dumps(_canonical(what), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def to_sim_task(self) -> SimTask:
        return SimTask(
            name=self.id,
            scene=SceneSpec(self.objects, self.fixtures),
            init=self.init,
            max_steps=self.max_steps,
            n_stages=len(self.stages),
            stage_fn=self.stage_index,
            success_fn=self.success,
            object_fixture=self.object_fixture,
            terminate_on_success=self.terminate_on_success,
            training_starts=self.training_starts,
        )


# ---------------------------------------------------------------------- validation helpers
class _Reader:
    """Typed access to one table of a TOML file, with errors that say where."""

    def __init__(self, path: Path, where: str, table: Any) -> None:
        self.path, self.where = path, where
        self.table = check_table(path, where, table, TaskFileError)

    def _fail(self, key: str, problem: str) -> TaskFileError:
        return TaskFileError(self.path, f"{self.where}.{key}", problem)

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        if key not in self.table:
            if default is ...:
                raise self._fail(key, "missing (required)")
            return default
        return check_type(self.path, f"{self.where}.{key}", self.table[key], kind, TaskFileError)

    def strings(self, key: str, default: Any = ...) -> tuple[str, ...]:
        value = self.get(key, list, default)
        if not all(isinstance(v, str) for v in value):
            raise self._fail(key, "expected a list of strings")
        return tuple(value)

    def range(self, key: str, default: tuple[float, float], within: _Bounds | None = None) -> Range:
        """A number or ``[low, high]``; with ``within``, inside those bounds (both ends)."""
        raw = self.table.get(key, list(default))
        value = [raw, raw] if isinstance(raw, int | float) and not isinstance(raw, bool) else raw
        if not isinstance(value, list) or len(value) != 2 or not all(map(is_number, value)):
            raise self._fail(
                key, f"expected a finite number or [low, high] of finite numbers, got {raw!r}"
            )
        if value[1] < value[0]:
            raise self._fail(key, f"expected low <= high, got {value!r}")
        if within is not None and not within.low <= value[0] <= value[1] <= within.high:
            got = repr(raw) if key in self.table else f"nothing ({default[0]:g} by default)"
            raise self._fail(
                key,
                f"expected {within.what}, from {within.low:g} to {within.high:g}{within.unit}, "
                f"got {got}",
            )
        return Range(float(value[0]), float(value[1]))

    def check_keys(self, allowed: set[str]) -> None:
        check_table(self.path, self.where, self.table, TaskFileError, allowed)


_COSMETIC = frozenset({"rgba"})
"""Spec fields that change how a scene looks, not what happens in it."""


def _canonical(value: Any) -> Any:
    """``value`` as JSON-ready data for :attr:`TaskSpec.fingerprint`: an expression as its terms
    with every argument named and defaults filled in, a dataclass as its fields less the
    cosmetic ones and those at their defaults, a tuple as a list."""
    if isinstance(value, Expression):
        return [[neg, name, predicate_params(name, args)] for neg, name, args in value.terms]
    if is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: _canonical(getattr(value, f.name))
            for f in dataclasses.fields(value)
            if f.name not in _COSMETIC and getattr(value, f.name) != f.default
        }
    if isinstance(value, dict):
        return {key: _canonical(v) for key, v in value.items()}
    if isinstance(value, tuple | list):
        return [_canonical(v) for v in value]
    return value


def _load_toml(path: Path) -> dict[str, Any]:
    return read_toml(path, TaskFileError)


def _check_name(path: Path, where: str, name: str, what: str, example: str) -> None:
    """``name`` (a task id or part name) is a plain name: it becomes a directory or file name
    (``runs/<task>/seed0``, ``<task>_eval.json``), where ``../x`` or ``a/b`` would write outside
    the directory meant and an empty one into the directory itself."""
    if not _PLAIN_NAME.fullmatch(name):
        raise TaskFileError(
            path,
            where,
            f"expected a {what} of 1 to {_MAX_NAME} lower-case letters, digits and underscores "
            f"(like {example}), got {name!r}",
        )


def _part_field(reader: _Reader, key: str, hint: Any) -> Any:
    """Field ``key`` of a part table read as the dataclass's type ``hint`` says: a number for a
    float (not a bool, not nan or inf), a whole number for an int, one of the choices for a
    ``Literal``, four numbers for a colour."""
    if hint is float or hint is int:
        return reader.get(key, hint)
    if get_origin(hint) is Literal:
        choices = get_args(hint)
        value = reader.get(key, str)
        if value not in choices:
            raise reader._fail(key, f"expected one of {choices}, got {value!r}")
        return value
    if get_origin(hint) is tuple:  # rgba
        value = reader.get(key, list)
        if len(value) != 4 or not all(map(is_number, value)):
            raise reader._fail(key, f"expected [red, green, blue, alpha], got {value!r}")
        return tuple(float(v) for v in value)
    raise TypeError(f"no reader for {key}: {hint!r}")  # a new field type in sim/parts.py


def load_parts(path: Path) -> dict[str, Any]:
    """Parse a parts file into ``{name: NutSpec | BoltSpec | PegSpec | HoleSpec}``.

    Every field is read as its dataclass declares it; the dataclass then checks the values
    (sizes, shapes, colours), and its :class:`PartSpecError` is reported at the field it names.
    """
    parts: dict[str, Any] = {}
    for kind, table in _load_toml(path).items():
        if kind not in _PART_KINDS:
            raise TaskFileError(
                path, kind, f"unknown part kind; expected one of {list(_PART_KINDS)}"
            )
        cls = _PART_KINDS[kind]
        hints = get_type_hints(cls)
        for name, fields in _Reader(path, kind, table).table.items():
            where = f"{kind}.{name}"
            # Named at its kind: the name itself would garble the field's path.
            _check_name(path, kind, name, "part name", "nut_m12")
            if name in parts:
                # The same name under two kinds: the second would replace the first unseen.
                raise TaskFileError(path, where, f"part already defined as a {parts[name].kind}")
            reader = _Reader(path, where, fields)
            allowed = set(cls.__dataclass_fields__) - {"name", "kind"}
            reader.check_keys(allowed)
            missing = [
                key
                for key, f in cls.__dataclass_fields__.items()
                if key != "name"
                and key not in fields
                and f.default is MISSING
                and f.default_factory is MISSING
            ]
            if missing:
                raise reader._fail(missing[0], "missing (required)")
            values = {key: _part_field(reader, key, hints[key]) for key in fields}
            try:
                parts[name] = cls(name=name, **values)
            except PartSpecError as err:
                raise TaskFileError(path, f"{where}.{err.field}", err.problem) from err
    return parts


_TASK_KEYS = {
    "id", "family", "kind", "command", "description", "skills", "actions", "objects", "fixtures",
    "object_fixture", "init", "stages", "success", "max_steps", "script", "table_i",
    "terminate_on_success", "tags", "training_starts",
}  # fmt: skip


def _parse_task(path: Path, index: int, raw: Any, parts: dict[str, Any]) -> TaskSpec:
    r = _Reader(path, f"task[{index}]", raw)
    task_id = r.get("id", str)
    _check_name(path, f"task[{index}].id", task_id, "task id", "reach_nut_m12")
    r = _Reader(path, f"task {task_id!r}", raw)
    r.check_keys(_TASK_KEYS)

    def part(name: str, kinds: tuple[type, ...], where: str):
        if name not in parts:
            raise TaskFileError(path, where, f"unknown part {name!r}; known: {', '.join(parts)}")
        if not isinstance(parts[name], kinds):
            raise TaskFileError(
                path, where, f"{name!r} is not a {' or '.join(k.__name__ for k in kinds)}"
            )
        return parts[name]

    objects = tuple(
        part(n, (NutSpec, PegSpec), f"task {task_id!r}.objects") for n in r.strings("objects")
    )
    fixtures = []
    for k, fx in enumerate(r.get("fixtures", list, [])):
        fr = _Reader(path, f"task {task_id!r}.fixtures[{k}]", fx)
        fr.check_keys({"part", "xy", "yaw"})
        xy = fr.get("xy", list)
        if len(xy) != 2 or not all(map(is_number, xy)):
            raise TaskFileError(
                path, fr.where + ".xy", f"expected [x, y] of finite numbers, got {xy!r}"
            )
        reach_x, reach_y = _REACH["x"], _REACH["y"]
        if not (reach_x.low <= xy[0] <= reach_x.high and reach_y.low <= xy[1] <= reach_y.high):
            # Off the arm's reach, or off the table altogether (x = 5 hangs it in the air).
            raise TaskFileError(
                path,
                fr.where + ".xy",
                f"expected within the arm's workspace, x from {reach_x.low:g} to "
                f"{reach_x.high:g} m and y from {reach_y.low:g} to {reach_y.high:g} m, got {xy!r}",
            )
        yaw = fr.get("yaw", float, 0.0)
        if not _PART_YAW.low <= yaw <= _PART_YAW.high:
            raise TaskFileError(
                path, fr.where + ".yaw", f"expected {_PART_YAW.what} (radians), got {yaw!r}"
            )
        placed = PlacedFixture(
            part(fr.get("part", str), (BoltSpec, HoleSpec), fr.where + ".part"),
            (float(xy[0]), float(xy[1])),
            yaw,
        )
        for j, other in enumerate(fixtures):
            gap, need = math.dist(placed.xy, other.xy), placed.part.radius + other.part.radius
            if gap < need:
                raise TaskFileError(
                    path, fr.where + ".xy", f"{placed.part.name} would stand inside "
                    f"{other.part.name} (fixtures[{j}]): {gap * 1000:.1f} mm between their "
                    f"axes, {need * 1000:.1f} mm keeps them apart",
                )  # fmt: skip
        fixtures.append(placed)
    if not 1 <= len(objects) <= 2 or len(fixtures) > 2:
        raise TaskFileError(path, f"task {task_id!r}", "expected 1-2 objects and 0-2 fixtures")
    default_map = list(default_object_fixture(len(objects), len(fixtures)))
    object_fixture = tuple(r.get("object_fixture", list, default_map))
    if len(object_fixture) != len(objects) or any(
        # A bool is an int to Python but a mask to NumPy, which then measures every object
        # against the fixtures it selects.
        not isinstance(f, int) or isinstance(f, bool) or not 0 <= f < max(len(fixtures), 1)
        for f in object_fixture
    ):
        raise TaskFileError(
            path, f"task {task_id!r}.object_fixture", "one fixture index per object"
        )

    init = _parse_init(
        _Reader(path, f"task {task_id!r}.init", r.get("init", dict)),
        objects,
        tuple(fixtures),
        object_fixture,
    )

    def expression(text: str, where: str) -> Expression:
        try:
            expr = parse(text)
        except PredicateError as err:
            raise TaskFileError(path, where, str(err)) from err
        bad = [i for i in expr.objects if not 0 <= i < len(objects)]
        if bad:
            raise TaskFileError(path, where, f"object slot {bad[0]} does not exist")
        against_fixture = sorted(expr.names & FIXTURE_PREDICATES)
        if against_fixture and not fixtures:
            raise TaskFileError(
                path, where, f"{against_fixture[0]} needs a fixture; the task has none"
            )
        return expr

    stages = []
    for k, st in enumerate(r.get("stages", list)):
        sr = _Reader(path, f"task {task_id!r}.stages[{k}]", st)
        sr.check_keys({"name", "done"})
        stages.append(Stage(_text(sr, "name"), expression(sr.get("done", str), sr.where + ".done")))
    if not stages:
        raise TaskFileError(path, f"task {task_id!r}.stages", "at least one stage is required")
    if len(stages) > MAX_STAGES:
        # The observation's stage one-hot has that many slots (itskill.sim.layout).
        raise TaskFileError(
            path, f"task {task_id!r}.stages", f"{len(stages)} stages; at most {MAX_STAGES}"
        )
    actions = r.strings("actions")
    if not actions or not all(a.strip() for a in actions):
        raise TaskFileError(
            path,
            f"task {task_id!r}.actions",
            f"expected one or more action names, got {list(actions)!r}",
        )
    _check_stages_follow_actions(path, f"task {task_id!r}", stages, actions)
    kind = r.get("kind", str, "basic")
    if kind not in _KINDS:
        raise TaskFileError(
            path, f"task {task_id!r}.kind", f"expected one of {_KINDS}, got {kind!r}"
        )
    max_steps = r.get("max_steps", int)
    if not 1 <= max_steps <= EPISODE_STEPS_MAX:
        raise TaskFileError(
            path,
            f"task {task_id!r}.max_steps",
            f"expected a whole number of steps from 1 to {EPISODE_STEPS_MAX:,}, got {max_steps}",
        )
    starts = []
    for k, raw_start in enumerate(r.get("training_starts", list, [])):
        sr = _Reader(path, f"task {task_id!r}.training_starts[{k}]", raw_start)
        sr.check_keys({"task", "init", "share"})
        share = sr.get("share", float)
        if ("task" in raw_start) == ("init" in raw_start):
            raise TaskFileError(path, sr.where, "expected either task (a task's start) or init")
        if "init" in raw_start:
            # Like a starts file's start: what the table leaves out keeps the task's own start.
            start_init = _parse_init(
                _changed_init(path, sr.where + ".init", init_table(init), sr.get("init", dict)),
                objects,
                tuple(fixtures),
                object_fixture,
            )
            name = ""
        else:
            # The other task's init; the registry fills it in once every file is read.
            start_init, name = init, sr.get("task", str)
        try:
            starts.append(TrainingStart(start_init, share, name))
        except ValueError as err:
            raise TaskFileError(path, sr.where + ".share", str(err)) from err
    try:
        check_start_shares(tuple(starts))
    except ValueError as err:
        raise TaskFileError(path, f"task {task_id!r}.training_starts", str(err)) from err
    spec = TaskSpec(
        id=task_id,
        family=r.get("family", str),
        kind=kind,
        command=_text(r, "command"),
        description=r.get("description", str, ""),
        skills=r.strings("skills"),
        actions=actions,
        objects=objects,
        fixtures=tuple(fixtures),
        object_fixture=object_fixture,
        init=init,
        stages=tuple(stages),
        success=expression(r.get("success", str), f"task {task_id!r}.success"),
        max_steps=max_steps,
        script=r.strings("script", ()),
        table_i=r.get("table_i", bool, False),
        terminate_on_success=r.get("terminate_on_success", bool, False),
        tags=r.strings("tags", ()),
        source=str(path),
        training_starts=tuple(starts),
    )
    _check_script(path, spec)
    _check_parts_fit(path, spec)
    _check_stage_holds_into_hole(path, spec)
    return spec


def _text(r: _Reader, key: str) -> str:
    """A required string that says something: an empty command or stage name is shown, sent to
    a language model and embedded as if it were one."""
    value = r.get(key, str)
    if not value.strip():
        raise r._fail(key, f"expected some text, got {value!r}")
    return value


def _check_stages_follow_actions(
    path: Path, where: str, stages: list[Stage], actions: tuple[str, ...]
) -> None:
    """Each stage is one of the task's actions, in the actions' order.

    The packaged tasks imply no more: an action may have no stage of its own (removenut's
    grasp ends with its lift stage), and a ``carry`` stage stands for the lift and approach
    actions that move a held part (pickplace2_nuts).
    """
    rest = list(actions)
    for k, stage in enumerate(stages):
        if stage.name == _CARRY:
            continue
        if stage.name not in actions:
            problem = f"stage {stage.name!r} is not one of the task's actions {list(actions)!r}"
        elif stage.name not in rest:
            problem = (
                f"stage {stage.name!r} is out of order: the stages follow the actions "
                f"{list(actions)!r} in order"
            )
        else:
            del rest[: rest.index(stage.name) + 1]
            continue
        raise TaskFileError(
            path,
            f"{where}.stages[{k}].name",
            f"{problem} (an action may have no stage; a {_CARRY!r} stage stands for lift and "
            "approach)",
        )


def _check_script(path: Path, spec: TaskSpec) -> None:
    """A bad script step fails at load, naming the file and the step, not at its first run."""
    # scripted.py builds its phases from a TaskSpec, so it imports this module.
    from itskill.tasks.scripted import ScriptError, compile_script

    try:
        compile_script(spec)
    except ScriptError as err:
        raise TaskFileError(path, f"task {spec.id!r}.script[{err.index}]", err.problem) from err


def _check_stage_holds_into_hole(path: Path, spec: TaskSpec) -> None:
    """A stage ending with a peg over its hole (``above_fixture``) and followed by one ending
    with it inserted or seated must go on holding as the peg goes down: a stage's index is one
    past the furthest stage done, so where neither holds it falls back to an earlier stage,
    whose skill then pulls the peg out, and the expert reward drops by the stage bonuses in
    between.

    Only the depth is checked, and only against the stage right after: the stage's other terms
    (its radius, an ``aligned`` tolerance tighter than ``inserted``'s) can still fail on the
    way down, and hand the peg back one stage while its approach still holds."""
    for k in range(len(spec.stages) - 1):
        over = [
            predicate_params(n, a)
            for neg, n, a in spec.stages[k].done.terms
            if n == "above_fixture" and not neg
        ]
        into = [
            (n, predicate_params(n, a))
            for neg, n, a in spec.stages[k + 1].done.terms
            if n in ("inserted", "seated") and not neg
        ]
        for above, (name, deep) in itertools.product(over, into):
            hole = spec.fixtures[spec.object_fixture[above["i"]]].part
            if deep["i"] != above["i"] or not isinstance(hole, HoleSpec):
                continue
            # Inserted from a fraction of the hole's depth; seated within a tolerance of its floor.
            need = (
                deep["fraction"] * hole.hole_depth
                if name == "inserted"
                else hole.hole_depth - deep["tolerance"]
            )
            depth = above["depth"]
            # With a margin: 0.9 of 2 cm is 0.018000000000000002, and 0.018 is deep enough.
            if depth < need - 1e-9:
                raise TaskFileError(
                    path,
                    f"task {spec.id!r}.stages[{k}].done",
                    f"above_fixture stops holding {depth * 1000:g} mm into {hole.name}, and "
                    f"stage {k + 1} ({spec.stages[k + 1].name!r}) is done only from "
                    f"{need * 1000:g} mm: between the two the task's stage falls back while the "
                    f"part goes in; give above_fixture a depth (its fourth argument) of at least "
                    f"{math.ceil(need * 1e6 - 1e-6) / 1e6:g}",
                )


_FIT_PREDICATES = frozenset({"engaged", "seated", "inserted"})
"""The predicates that hold only for a part on or in its fixture."""


def _check_parts_fit(path: Path, spec: TaskSpec) -> None:
    """Each part the task must put on or into its fixture (a predicate that holds only there, or
    a script step that does it) fits it: a nut meant for another thread's bolt, or a peg for a
    hole it does not fit, made a task whose success could never happen. A part the task only
    picks up, carries over or pushes beside a fixture may be any part."""
    from itskill.tasks.scripted import fitting_step_slots

    to_fit = {
        int(args[0])
        for expr in (*(stage.done for stage in spec.stages), spec.success)
        for negated, name, args in expr.terms
        if name in _FIT_PREDICATES and not negated
    } | fitting_step_slots(spec)
    for k in sorted(to_fit):
        placed = spec.fixtures[spec.object_fixture[k]]
        if not fits(spec.objects[k], placed.part):
            raise TaskFileError(
                path,
                f"task {spec.id!r}.objects[{k}]",
                f"{spec.objects[k].name} does not fit fixture {spec.object_fixture[k]} "
                f"({placed.part.name}), where the task puts it",
            )


def _parse_init(
    ir: _Reader,
    objects: tuple[NutSpec | PegSpec, ...],
    fixtures: tuple[PlacedFixture, ...],
    object_fixture: tuple[int, ...],
) -> InitSpec:
    """A task's start (an ``[task.init]`` table, or a start of a starts file) for its parts."""
    path = ir.path
    ir.check_keys({"ee", "objects"})
    er = _Reader(path, ir.where + ".ee", ir.get("ee", dict, {}))
    er.check_keys({"x", "y", "z", "yaw"})
    obj_inits = []
    raw_inits = ir.get("objects", list)
    if len(raw_inits) != len(objects):
        raise TaskFileError(
            path, ir.where + ".objects", f"expected {len(objects)} entries, one per object"
        )
    seated: dict[int, int] = {}  # fixture -> the object starting on it
    for k, oi in enumerate(raw_inits):
        orr = _Reader(path, f"{ir.where}.objects[{k}]", oi)
        orr.check_keys(
            {"mode", "x", "y", "z", "yaw", "turns", "depth", "hold", "fixture", "symmetric_yaw"}
        )
        mode = orr.get("mode", str)
        if mode not in _INIT_MODES:
            raise TaskFileError(
                path, orr.where + ".mode", f"expected one of {_INIT_MODES}, got {mode!r}"
            )
        if "hold" in oi and mode != "gripper":
            raise TaskFileError(path, orr.where + ".hold", "only a part in the gripper has a hold")
        hold = orr.range("hold", (0.0, 0.0))
        symmetric_yaw = orr.get("symmetric_yaw", bool, False)
        if "symmetric_yaw" in oi and mode not in HAND_MODES:
            raise TaskFileError(
                path,
                orr.where + ".symmetric_yaw",
                f"only a part in the hand ({', '.join(HAND_MODES)}) takes symmetric_yaw; a part "
                f"in mode {mode!r} has its own yaw",
            )
        bound = max_grip_offset(objects[k].height)
        if max(-hold.low, hold.high) > bound:
            # The start would put the part in the fingers where `grasped` says it is not held,
            # and a learner that trusts `grasped` opens its hand.
            raise TaskFileError(
                path,
                orr.where + ".hold",
                f"{objects[k].name} counts as grasped with its centre at most "
                f"{bound * 1000:.1f} mm from the grip point; got [{hold.low}, {hold.high}] m",
            )
        fixture = orr.get("fixture", int, object_fixture[k])
        if mode in ("bolt", "hole"):
            want = BoltSpec if mode == "bolt" else HoleSpec
            if not (0 <= fixture < len(fixtures)) or not isinstance(fixtures[fixture].part, want):
                raise TaskFileError(
                    path, orr.where + ".fixture", f"mode {mode!r} needs a {want.__name__} fixture"
                )
            part, seat = objects[k], fixtures[fixture].part
            if fixture in seated:
                # A bolt's shank is shorter than two nuts are tall: they start inside each other
                # whatever their turns, as two pegs in one hole do.
                raise TaskFileError(
                    path,
                    orr.where + ".fixture",
                    f"{part.name} would start on {seat.name} with objects[{seated[fixture]}]: "
                    "one part per fixture",
                )
            seated[fixture] = k
            if mode == "hole" and not fits(part, seat):
                # A peg wider than the bore started stuck inside it.
                what = "does not fit" if isinstance(part, PegSpec) else "is not a peg for"
                raise TaskFileError(path, orr.where + ".mode", f"{part.name} {what} {seat.name}")
            if mode == "bolt" and not fits(part, seat):
                raise TaskFileError(
                    path,
                    orr.where + ".mode",
                    f"{part.name} does not screw onto {seat.name}: mode 'bolt' needs a nut of "
                    f"its thread ({seat.thread_diameter * 1000:g} mm, pitch "
                    f"{seat.pitch * 1000:g} mm)",
                )
        elif not 0 <= fixture < max(len(fixtures), 1):
            raise TaskFileError(
                path, orr.where + ".fixture", f"the task has {len(fixtures)} fixture(s)"
            )
        bounds = {key: _REACH[key] for key in "xyz"} | {"yaw": _PART_YAW}
        if mode == "bolt":
            # The nut's bottom stays on the thread: at most at the shank's tip.
            bolt = fixtures[fixture].part
            bounds["turns"] = _Bounds(
                0.0,
                bolt.shank_length / bolt.pitch + 1e-9,
                f"a place on {bolt.name}'s thread",
                " turns",
            )
        if mode == "hole":
            # From the entrance (0) to the bottom of the hole, the table.
            hole = fixtures[fixture].part
            bounds["depth"] = _Bounds(0.0, hole.hole_depth, f"a depth inside {hole.name}")
        ranges = {}
        for key in ("x", "y", "z", "yaw", "turns", "depth"):
            if key in _MODE_FIELDS[mode]:
                ranges[key] = orr.range(key, (0.0, 0.0), bounds[key])
                continue
            # A field the mode does not read would be ignored without a word; 0, the value it
            # takes when left out, is let through.
            ranges[key] = orr.range(key, (0.0, 0.0))
            if ranges[key] != Range(0.0, 0.0):
                raise TaskFileError(
                    path,
                    f"{orr.where}.{key}",
                    f"mode {mode!r} does not use {key} (it uses "
                    f"{', '.join(sorted(_MODE_FIELDS[mode]))}); leave it out",
                )
        if mode == "hole" and isinstance(objects[k], PegSpec):
            _check_turn_fits(path, orr.where + ".yaw", objects[k], fixtures[fixture], ranges["yaw"])
        obj_inits.append(
            ObjectInit(mode=mode, hold=hold, fixture=fixture, symmetric_yaw=symmetric_yaw, **ranges)
        )
    if sum(o.mode in HAND_MODES for o in obj_inits) > 1:
        raise TaskFileError(
            path, ir.where + ".objects", "at most one object can start in the gripper"
        )
    _check_parts_apart(path, ir.where, obj_inits, objects, fixtures)
    defaults = {"x": _EE_X, "y": _EE_Y, "z": _EE_Z, "yaw": (0.0, 0.0)}
    ee = {k: er.range(k, d, _HAND_YAW if k == "yaw" else _REACH[k]) for k, d in defaults.items()}
    for init, part in zip(obj_inits, objects, strict=True):
        placed = fixtures[init.fixture] if init.fixture < len(fixtures) else None
        if (
            init.mode == "gripper"
            and isinstance(part, PegSpec)
            and placed is not None
            and isinstance(placed.part, HoleSpec)
            and init.z.low + init.hold.low - part.height / 2 < placed.part.entrance_z
            and _gap(init.x, init.y, *(Range(c, c) for c in placed.xy)) < placed.part.radius
        ):
            # Held with its bottom in the hole (extract's start), it is turned as the hand is.
            hand = ee["yaw"]
            turn = Range(hand.low - placed.yaw, hand.high - placed.yaw)  # from the hole's axes
            _check_turn_fits(path, f"{er.where}.yaw", part, placed, turn)
    if any(o.mode in HAND_MODES for o in obj_inits):
        for key in ("x", "y", "z"):
            if ee[key] != Range(*defaults[key]):
                # It was read, checked and then ignored without a word.
                raise TaskFileError(
                    path,
                    f"{er.where}.{key}",
                    "the hand starts at the held part's x, y and z (its object's start); "
                    "leave ee.x, ee.y and ee.z out (ee.yaw still applies)",
                )
    return InitSpec(
        ee_x=ee["x"],
        ee_y=ee["y"],
        ee_z=ee["z"],
        ee_yaw=ee["yaw"],
        objects=tuple(obj_inits),
    )


_EE_X, _EE_Y, _EE_Z = (0.45, 0.45), (0.0, 0.0), (0.2, 0.2)
"""The hand's start where ``ee`` leaves it out and no part starts in the hand."""

_ON_TABLE = ("table", "fingers")
"""The start modes that stand a part on the table: at its x and y, or between the open fingers
at the hand's."""


def _gap(x: Range, y: Range, other_x: Range, other_y: Range) -> float:
    """The least distance between a point of the box ``x`` × ``y`` and one of the other box."""
    dx = max(x.low - other_x.high, other_x.low - x.high, 0.0)
    dy = max(y.low - other_y.high, other_y.low - y.high, 0.0)
    return math.hypot(dx, dy)


def _check_turn_fits(
    path: Path, where: str, peg: PegSpec, placed: PlacedFixture, turn: Range
) -> None:
    """Refuse a range of turns from the hole's axes at which ``peg``, started in ``placed``'s
    hole, would be wider than the bore: the physics started it inside the walls (reading
    engaged), or snapped it back to another yaw than the one asked for."""
    hole = placed.part
    if not isinstance(hole, HoleSpec):
        return
    turns = [turn.low + (turn.high - turn.low) * j / 64 for j in range(65)]
    wide = next((t for t in turns if not fits_turned(peg, hole, t)), None)
    if wide is not None:
        raise TaskFileError(
            path,
            where,
            f"{peg.name} turned {wide:g} rad from {hole.name}'s axes is wider than its bore; "
            "narrow the yaw range",
        )


def _check_parts_apart(
    path: Path,
    where: str,
    inits: list[ObjectInit],
    objects: tuple[NutSpec | PegSpec, ...],
    fixtures: tuple[PlacedFixture, ...],
) -> None:
    """Refuse a start that can put a part on the table inside a fixture or another part, or a
    held part's bottom under the table: the physics pushed them apart at the first step, or
    held them stuck, and the episodes measured 0% without a word."""
    for k, (init, part) in enumerate(zip(inits, objects, strict=True)):
        at = f"{where}.objects[{k}]"
        if init.mode == "gripper" and init.z.low + init.hold.low < part.height / 2 - 1e-6:
            raise TaskFileError(
                path, at + ".z", f"{part.name}'s bottom would start under the table (z + hold "
                f"must be at least half its height, {part.height / 2:g} m)",
            )  # fmt: skip
        if init.mode not in _ON_TABLE:
            continue
        others = [
            (f.part.name, Range(f.xy[0], f.xy[0]), Range(f.xy[1], f.xy[1]), f.part.radius)
            for f in fixtures
        ] + [
            (objects[j].name, inits[j].x, inits[j].y, objects[j].radius)
            for j in range(k)
            if inits[j].mode in _ON_TABLE
        ]
        for name, x, y, radius in others:
            gap, need = _gap(init.x, init.y, x, y), part.radius + radius
            if gap < need:
                raise TaskFileError(
                    path, at, f"{part.name} can start inside {name}: its x and y ranges come "
                    f"within {gap * 1000:.1f} mm of it, {need * 1000:.1f} mm keeps them apart",
                )  # fmt: skip


def init_table(init: InitSpec) -> dict[str, Any]:
    """``init`` as the table a task file writes for it (the inverse of :func:`_parse_init`)."""

    def span(r: Range) -> list[float]:
        return [r.low, r.high]

    # Only the fields the part's mode reads: the others are ignored, and a reader shown them
    # (``itskill tasks show``) would take them for part of the start.
    objects = [
        {"mode": o.mode}
        | ({"fixture": o.fixture} if o.mode in _FIXTURE_MODES else {})
        | {k: span(getattr(o, k)) for k in sorted(_MODE_FIELDS[o.mode])}
        | ({"symmetric_yaw": True} if o.symmetric_yaw else {})
        for o in init.objects
    ]
    ee = {k: span(getattr(init, f"ee_{k}")) for k in ("x", "y", "z", "yaw")}
    return {"ee": ee, "objects": objects}


def load_starts(path: str | Path, spec: TaskSpec) -> list[tuple[str, TaskSpec]]:
    """The named starts of a starts file, each as ``spec`` beginning there.

    The file holds ``[[start]]`` tables, each a ``name`` and the fields of ``[task.init]`` that
    change: ``ee`` (a table) and ``objects`` (a list with one table per object); a field left
    out keeps the task's own value, so ``objects = [{ x = [0.552, 0.553] }]`` moves only the
    first part's x. An optional top-level ``task`` names the task the starts were written for.
    """
    path = Path(path)
    data = _load_toml(path)
    unknown = sorted(set(data) - {"task", "start"})
    if unknown:
        raise TaskFileError(path, unknown[0], "unknown top-level key; expected task and [[start]]")
    if data.get("task", spec.id) != spec.id:
        raise TaskFileError(path, "task", f"written for {data['task']!r}, not {spec.id!r}")
    raw_starts = data.get("start", [])
    if not isinstance(raw_starts, list) or not raw_starts:
        raise TaskFileError(path, "start", "expected one or more [[start]] tables")
    own = init_table(spec.init)
    starts = []
    for k, raw in enumerate(raw_starts):
        r = _Reader(path, f"start[{k}]", raw)
        r.check_keys({"name", "ee", "objects"})
        # The name labels the start's row of results: an empty one labels nothing and a repeated
        # one makes two rows that cannot be told apart.
        name = _text(r, "name")
        if any(name == other for other, _ in starts):
            raise TaskFileError(path, f"start[{k}].name", f"{name!r} names an earlier start too")
        changes = {key: raw[key] for key in ("ee", "objects") if key in raw}
        init = _parse_init(
            _changed_init(path, f"start {name!r}", own, changes),
            spec.objects,
            spec.fixtures,
            spec.object_fixture,
        )
        starts.append((name, replace(spec, init=init)))
    return starts


def _changed_init(path: Path, where: str, own: dict[str, Any], changes: Any) -> _Reader:
    """The init table ``own`` (:func:`init_table`) with ``changes`` applied: the ``ee`` fields
    and, per object, the fields that ``changes`` names; the rest keeps ``own``'s values."""
    r = _Reader(path, where, changes)
    r.check_keys({"ee", "objects"})
    ee_changes = _Reader(path, f"{where}.ee", r.get("ee", dict, {})).table
    ee = own["ee"] | ee_changes
    object_changes = r.get("objects", list, [])
    if len(object_changes) > len(own["objects"]):
        raise TaskFileError(
            path, f"{where}.objects", f"the task has {len(own['objects'])} object(s)"
        )
    padded = [*object_changes, *[{}] * (len(own["objects"]) - len(object_changes))]
    objects = []
    for i, (base, raw_change) in enumerate(zip(own["objects"], padded, strict=True)):
        change = _Reader(path, f"{where}.objects[{i}]", raw_change).table
        if "mode" in change and change["mode"] != base["mode"]:
            base = {"mode": change["mode"]}  # another mode: nothing of the old start applies
        objects.append(base | change)
    if any(o.get("mode") in HAND_MODES for o in objects):
        # The hand starts at the held part: only an ee position written here is refused, not
        # the one a task whose own start has the part elsewhere left behind.
        ee = {k: v for k, v in ee.items() if k not in ("x", "y", "z") or k in ee_changes}
    return _Reader(path, where, {"ee": ee, "objects": objects})


def load_task_file(path: Path, parts: dict[str, Any]) -> list[TaskSpec]:
    """The tasks of one task file, built from ``parts`` (part name -> spec); a
    :class:`TaskFileError` names the file and field of anything wrong."""
    data = _load_toml(path)
    unknown = set(data) - {"task"}
    if unknown:
        raise TaskFileError(
            path, sorted(unknown)[0], "unknown top-level key; tasks go in [[task]] tables"
        )
    raw_tasks = data.get("task", [])
    if not isinstance(raw_tasks, list):
        raise TaskFileError(
            path, "task", f"expected [[task]] tables, got {type(raw_tasks).__name__}"
        )
    return [_parse_task(path, i, raw, parts) for i, raw in enumerate(raw_tasks)]


def _task_dirs() -> list[Path]:
    dirs = [Path(str(resources.files("itskill.tasks") / "data"))]
    user = os.environ.get(TASKS_DIR_ENV)
    if user:
        # A mistyped directory would otherwise leave its tasks "unknown" without saying why.
        path = Path(user).expanduser()
        if not path.is_dir():
            problem = "not a directory" if path.exists() else "no such directory"
            raise TaskFileError(path, TASKS_DIR_ENV, problem)
        dirs.append(path)
    return dirs


@cache
def _registry(dirs: tuple[Path, ...]) -> dict[str, TaskSpec]:
    parts: dict[str, Any] = {}
    part_files: dict[str, Path] = {}
    for d in dirs:
        path = d / "parts.toml"
        if not path.is_file():
            continue
        for name, part in load_parts(path).items():
            if name in parts:
                # Like a repeated task id: a user's part silently replacing a packaged one would
                # change every packaged task built from it.
                raise TaskFileError(
                    path, f"{part.kind}.{name}", f"part already defined in {part_files[name]}"
                )
            parts[name], part_files[name] = part, path
    tasks: dict[str, TaskSpec] = {}
    for d in dirs:
        for path in sorted(d.glob("*.toml")):
            if path.name == "parts.toml":
                continue
            for spec in load_task_file(path, parts):
                if spec.id in tasks:
                    raise TaskFileError(
                        path, f"task {spec.id!r}", f"id already defined in {tasks[spec.id].source}"
                    )
                tasks[spec.id] = spec
    return {name: _resolve_starts(spec, tasks) for name, spec in tasks.items()}


def _resolve_starts(spec: TaskSpec, tasks: dict[str, TaskSpec]) -> TaskSpec:
    """``spec`` with each training start's init taken from the task it names, which must have
    the same parts and fixtures (a start is a state of this task's scene)."""
    if not spec.training_starts:
        return spec
    resolved = []
    for k, start in enumerate(spec.training_starts):
        if not start.name:  # written out in the task's own file
            resolved.append(start)
            continue
        where = f"task {spec.id!r}.training_starts[{k}].task"
        other = tasks.get(start.name)
        if other is None:
            raise TaskFileError(Path(spec.source), where, f"unknown task {start.name!r}")
        if (other.objects, other.fixtures) != (spec.objects, spec.fixtures):
            raise TaskFileError(
                Path(spec.source), where, f"{start.name!r} has other parts or fixtures"
            )
        resolved.append(TrainingStart(other.init, start.share, start.name))
    return replace(spec, training_starts=tuple(resolved))


def all_tasks() -> dict[str, TaskSpec]:
    """Every task, by id, in file order."""
    return _registry(tuple(_task_dirs()))


def get_task(name: str) -> TaskSpec:
    """The task called ``name``; :class:`UnknownTaskError` lists the known ones."""
    tasks = all_tasks()
    if name not in tasks:
        raise UnknownTaskError(name, list(tasks))
    return tasks[name]
