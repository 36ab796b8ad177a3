"""Task specifications: TOML files in ``itskill/tasks/data`` validated into ``TaskSpec`` objects.

``parts.toml`` holds part dimensions; each family file (``nutbolt.toml``, ``peghole.toml``) holds
tasks. A user can add a directory of their own files with ``ITSKILL_TASKS_DIR``. Every problem in a
file is reported with the file, the field and what was expected.
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field, replace
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from itskill.datafile import DataFileError, is_number, read_toml
from itskill.errors import PicklableError
from itskill.sim.context import max_grip_offset
from itskill.sim.parts import BoltSpec, HoleSpec, NutSpec, PegSpec, PlacedFixture
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
from itskill.tasks.predicates import Expression, PredicateError, parse

TASKS_DIR_ENV = "ITSKILL_TASKS_DIR"
_PART_KINDS = {"nut": NutSpec, "bolt": BoltSpec, "peg": PegSpec, "hole": HoleSpec}
_INIT_MODES = ("table", "gripper", "fingers", "bolt", "hole")


class TaskFileError(DataFileError):
    """A task or parts file that does not validate: names the file, the field and the problem."""


class UnknownTaskError(PicklableError, KeyError):
    """A task name that no task file defines."""

    def __init__(self, name: str, known: list[str]) -> None:
        super().__init__(name)
        self.name, self.known = name, known

    def __str__(self) -> str:
        close = difflib.get_close_matches(self.name, self.known, n=3, cutoff=0.8)
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
        if not isinstance(table, dict):
            raise TaskFileError(path, where, f"expected a table, got {type(table).__name__}")
        self.path, self.where, self.table = path, where, table

    def _fail(self, key: str, problem: str) -> TaskFileError:
        return TaskFileError(self.path, f"{self.where}.{key}", problem)

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        if key not in self.table:
            if default is ...:
                raise self._fail(key, "missing (required)")
            return default
        value = self.table[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind in (int, float)):
            name = (
                kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            )
            raise self._fail(key, f"expected {name}, got {type(value).__name__} {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise self._fail(key, f"expected a finite number, got {value!r}")
        return value

    def strings(self, key: str, default: Any = ...) -> tuple[str, ...]:
        value = self.get(key, list, default)
        if not all(isinstance(v, str) for v in value):
            raise self._fail(key, "expected a list of strings")
        return tuple(value)

    def range(self, key: str, default: tuple[float, float]) -> Range:
        raw = self.table.get(key, list(default))
        value = [raw, raw] if isinstance(raw, int | float) and not isinstance(raw, bool) else raw
        if not isinstance(value, list) or len(value) != 2 or not all(map(is_number, value)):
            raise self._fail(
                key, f"expected a finite number or [low, high] of finite numbers, got {raw!r}"
            )
        if value[1] < value[0]:
            raise self._fail(key, f"expected low <= high, got {value!r}")
        return Range(float(value[0]), float(value[1]))

    def check_keys(self, allowed: set[str]) -> None:
        unknown = sorted(set(self.table) - allowed)
        if unknown:
            raise self._fail(unknown[0], f"unknown field; allowed: {', '.join(sorted(allowed))}")


def _load_toml(path: Path) -> dict[str, Any]:
    return read_toml(path, TaskFileError)


def load_parts(path: Path) -> dict[str, Any]:
    """Parse a parts file into ``{name: NutSpec | BoltSpec | PegSpec | HoleSpec}``."""
    parts: dict[str, Any] = {}
    for kind, table in _load_toml(path).items():
        if kind not in _PART_KINDS:
            raise TaskFileError(
                path, kind, f"unknown part kind; expected one of {list(_PART_KINDS)}"
            )
        cls = _PART_KINDS[kind]
        for name, fields in _Reader(path, kind, table).table.items():
            reader = _Reader(path, f"{kind}.{name}", fields)
            allowed = set(cls.__dataclass_fields__) - {"name", "kind"}
            reader.check_keys(allowed)
            values = dict(fields)
            for key, value in values.items():
                if isinstance(value, float):
                    # The parts' own checks let inf through, and nan where they check nothing.
                    reader.get(key, float)
            if "rgba" in values:
                rgba = reader.get("rgba", list)
                if len(rgba) != 4 or not all(map(is_number, rgba)):
                    raise TaskFileError(
                        path,
                        f"{kind}.{name}.rgba",
                        f"expected [red, green, blue, alpha], got {rgba!r}",
                    )
                values["rgba"] = tuple(float(v) for v in rgba)
            try:
                parts[name] = cls(name=name, **values)
            except (TypeError, ValueError) as err:
                raise TaskFileError(path, f"{kind}.{name}", str(err)) from err
    return parts


_TASK_KEYS = {
    "id", "family", "kind", "command", "description", "skills", "actions", "objects", "fixtures",
    "object_fixture", "init", "stages", "success", "max_steps", "script", "table_i",
    "terminate_on_success", "tags", "training_starts",
}  # fmt: skip


def _parse_task(path: Path, index: int, raw: Any, parts: dict[str, Any]) -> TaskSpec:
    r = _Reader(path, f"task[{index}]", raw)
    task_id = r.get("id", str)
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
        placed = PlacedFixture(
            part(fr.get("part", str), (BoltSpec, HoleSpec), fr.where + ".part"),
            (float(xy[0]), float(xy[1])),
            fr.get("yaw", float, 0.0),
        )
        fixtures.append(placed)
    if not 1 <= len(objects) <= 2 or len(fixtures) > 2:
        raise TaskFileError(path, f"task {task_id!r}", "expected 1-2 objects and 0-2 fixtures")
    default_map = list(default_object_fixture(len(objects), len(fixtures)))
    object_fixture = tuple(r.get("object_fixture", list, default_map))
    if len(object_fixture) != len(objects) or any(
        not isinstance(f, int) or not 0 <= f < max(len(fixtures), 1) for f in object_fixture
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
        return expr

    stages = []
    for k, st in enumerate(r.get("stages", list)):
        sr = _Reader(path, f"task {task_id!r}.stages[{k}]", st)
        sr.check_keys({"name", "done"})
        stages.append(
            Stage(sr.get("name", str), expression(sr.get("done", str), sr.where + ".done"))
        )
    if not stages:
        raise TaskFileError(path, f"task {task_id!r}.stages", "at least one stage is required")
    max_steps = r.get("max_steps", int)
    if max_steps < 1:
        raise TaskFileError(path, f"task {task_id!r}.max_steps", "expected a positive integer")
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
        kind=r.get("kind", str, "basic"),
        command=r.get("command", str),
        description=r.get("description", str, ""),
        skills=r.strings("skills"),
        actions=r.strings("actions"),
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
    return spec


def _check_script(path: Path, spec: TaskSpec) -> None:
    """A bad script step fails at load, naming the file and the step, not at its first run."""
    # scripted.py builds its phases from a TaskSpec, so it imports this module.
    from itskill.tasks.scripted import ScriptError, compile_script

    try:
        compile_script(spec)
    except ScriptError as err:
        raise TaskFileError(path, f"task {spec.id!r}.script[{err.index}]", err.problem) from err


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
    for k, oi in enumerate(raw_inits):
        orr = _Reader(path, f"{ir.where}.objects[{k}]", oi)
        orr.check_keys({"mode", "x", "y", "z", "yaw", "turns", "depth", "hold", "fixture"})
        mode = orr.get("mode", str)
        if mode not in _INIT_MODES:
            raise TaskFileError(
                path, orr.where + ".mode", f"expected one of {_INIT_MODES}, got {mode!r}"
            )
        if "hold" in oi and mode != "gripper":
            raise TaskFileError(path, orr.where + ".hold", "only a part in the gripper has a hold")
        hold = orr.range("hold", (0.0, 0.0))
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
            if mode == "hole" and not isinstance(part, PegSpec):
                raise TaskFileError(path, orr.where + ".mode", f"{part.name} is not a peg")
            if mode == "bolt" and not (
                isinstance(part, NutSpec)
                and (part.thread_diameter, part.pitch) == (seat.thread_diameter, seat.pitch)
            ):
                raise TaskFileError(
                    path,
                    orr.where + ".mode",
                    f"{part.name} does not screw onto {seat.name}: mode 'bolt' needs a nut of "
                    f"its thread ({seat.thread_diameter * 1000:g} mm, pitch "
                    f"{seat.pitch * 1000:g} mm)",
                )
        obj_inits.append(
            ObjectInit(
                mode=mode,
                x=orr.range("x", (0.0, 0.0)),
                y=orr.range("y", (0.0, 0.0)),
                z=orr.range("z", (0.0, 0.0)),
                yaw=orr.range("yaw", (0.0, 0.0)),
                turns=orr.range("turns", (0.0, 0.0)),
                depth=orr.range("depth", (0.0, 0.0)),
                hold=hold,
                fixture=fixture,
            )
        )
    if sum(o.mode in HAND_MODES for o in obj_inits) > 1:
        raise TaskFileError(
            path, ir.where + ".objects", "at most one object can start in the gripper"
        )
    return InitSpec(
        ee_x=er.range("x", (0.45, 0.45)),
        ee_y=er.range("y", (0.0, 0.0)),
        ee_z=er.range("z", (0.2, 0.2)),
        ee_yaw=er.range("yaw", (0.0, 0.0)),
        objects=tuple(obj_inits),
    )


def init_table(init: InitSpec) -> dict[str, Any]:
    """``init`` as the table a task file writes for it (the inverse of :func:`_parse_init`)."""

    def span(r: Range) -> list[float]:
        return [r.low, r.high]

    objects = [
        {"mode": o.mode, "fixture": o.fixture}
        | {k: span(getattr(o, k)) for k in ("x", "y", "z", "yaw", "turns", "depth")}
        | ({"hold": span(o.hold)} if o.mode == "gripper" else {})
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
        name = r.get("name", str)
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
    ee = own["ee"] | _Reader(path, f"{where}.ee", r.get("ee", dict, {})).table
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
    for d in dirs:
        if (d / "parts.toml").is_file():
            parts.update(load_parts(d / "parts.toml"))
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
