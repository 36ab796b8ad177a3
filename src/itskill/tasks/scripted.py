"""Scripted waypoint controller: each task's ``script`` (task-file data) run as a state machine.

A script is a list of steps, each ``"primitive arg ..."``; ``I`` is an object slot. Vocabulary:

``reach I``
    Move the open fingers onto object ``I``.
``hover I [H]``
    Move the grip point ``H`` metres over object ``I``'s fixture point (default 0.05) and stay.
``grasp I``
    Turn the open fingers to object ``I``'s grip faces at its grip point and close them, without
    lifting.
``pick I [Z]``
    Hover over object ``I`` with the fingers turned to its grip faces, descend, close, and lift
    until the part's bottom is ``Z`` metres above the table (default 0.06).
``carry I``
    Raise the held object ``I`` to travel height, bring it over its fixture and turn it to the
    fixture's yaw (a rectangular peg), ending with its bottom a little above the fixture point.
``place I``
    A nut: lower it onto its bolt's tip until the thread engages. A peg: hold it centred a few
    millimetres above its hole's entrance.
``insert I``
    Lower the held peg ``I`` into its hole, correcting its position as it goes.
``release``
    Open the fingers and back off upwards.
``lift Z``
    Raise the grip point by ``Z`` metres, keeping the fingers as they are.
``screw I`` / ``unscrew I``
    Regrasp-and-twist cycles on nut ``I``: grip its flats at one end of the hand's yaw range, turn
    to the other end (clockwise seen from above to screw down), open, turn back, and repeat until
    the nut is seated (screw) or off the bolt (unscrew), which ends the step with the nut held.
``push I DX DY``
    Push object ``I`` along the table with the closed fingers until its centre is about a
    centimetre short of (DX, DY) from its fixture's point, which it slides the rest of the way.

After the last step the hand holds still. Each step expands into primitive :class:`Phase` objects
(a goal pose for the grip point, a finger command and an end condition); a policy keeps one program
counter per environment, so environments in a batch run the same program independently.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from itskill.sim.batch import NUT_GRIP_YAW
from itskill.sim.context import wrap_angle
from itskill.sim.controller import ControllerConfig
from itskill.sim.parts import NutSpec, PegSpec, yaw_symmetry
from itskill.sim.scene import TIMESTEP
from itskill.tasks.predicates import fixture_offset, hole_depth
from itskill.tasks.spec import TaskSpec

Ctx = dict[str, np.ndarray]
GoalFn = Callable[[Ctx, np.ndarray, "State"], tuple[np.ndarray, np.ndarray]]
"""``(ctx, rows, state) -> (grip point goal (n, 3), hand yaw goal (n,))`` for the given rows."""
TestFn = Callable[[Ctx, np.ndarray, "State"], np.ndarray]
"""``(ctx, rows, state) -> bool (n,)``: a phase's end condition, or a branch's condition."""

_CTRL = ControllerConfig()
_CONTROL_DT = _CTRL.substeps * TIMESTEP
VELOCITY_LEAD = 1.0
"""Steer from where the hand will be this many control periods ahead at its current speed."""
YAW_MARGIN = 0.05
"""Keep turn goals this far inside the hand's yaw limits, where the IK still tracks them."""
YAW_LOW, YAW_HIGH = _CTRL.yaw_limits[0] + YAW_MARGIN, _CTRL.yaw_limits[1] - YAW_MARGIN
FLOOR_Z = _CTRL.workspace_low[2]
TRAVEL_Z = 0.07
"""Height of a held part's bottom while it is carried: clears bolts, blocks and the other part."""
CARRY_SPEED = 0.5
"""Translation action cap while carrying a part sideways."""
MAX_SPEEDUP = 0.35
"""Largest increase of a translation action from one step to the next."""
INSERT_SPEED = 0.5
"""Translation action cap while a peg goes into its hole."""
HOVER = 0.012
"""A carried part's bottom ends ``carry`` this far above its fixture point."""
PUSH_SPEED = 0.6
"""Translation action cap while pushing: a part pushed faster slides far past the hand's stop."""
PUSH_LEAD = 0.03
"""How far ahead of the hand a push aims each step (less lets the part drift sideways)."""
PUSH_STOP = 0.01
"""A push ends when the part is this close to its target along the push line."""


class ScriptError(ValueError):
    """A task script that names an unknown primitive or has wrong arguments.

    ``index`` is the bad step's position in the script and ``problem`` what is wrong with it, so a
    task-file loader can name the field; the message names the task and the step too.
    """

    def __init__(self, message: str, index: int | None = None, problem: str = "") -> None:
        super().__init__(message)
        self.index, self.problem = index, problem or message


@dataclass
class State:
    """Per-environment program state."""

    pc: np.ndarray
    """Index of the current phase."""
    t: np.ndarray
    """Control steps spent in the current phase."""
    anchor: np.ndarray
    """Grip point when the current phase began (n, 3)."""
    anchor_yaw: np.ndarray
    """Hand yaw when the current phase began."""
    last_move: np.ndarray
    """The previous translation action (n, 3)."""
    yaw_command: np.ndarray
    """The controller's commanded hand yaw, integrated from our own actions as it does: steering
    the measured yaw instead winds the command up while the wrist lags, and the hand overshoots."""


@dataclass(frozen=True)
class Phase:
    """One waypoint: drive the grip point to ``goal`` with the fingers ``closed`` until ``done``.

    A phase with ``branch`` set is instantaneous: it jumps ``branch`` phases (relative, may be
    negative) when its ``done`` holds, else falls through to the next phase.
    """

    name: str
    goal: GoalFn
    closed: bool
    done: TestFn
    timeout: int = 1000
    branch: int | None = None
    speed: float = 1.0
    """Largest translation action: a part swung at full speed pivots out of the grip."""
    turn_speed: float = 0.3
    """Largest yaw action. The wrist servo cannot follow full-speed turns: its lag throws the
    arm's posture off and can stall the hand for seconds, so only twisting a nut turns fast."""


# --------------------------------------------------------------------------- part geometry
@dataclass(frozen=True)
class _Part:
    """What the controller needs to know about object slot ``index``."""

    index: int
    spec: NutSpec | PegSpec

    @property
    def is_nut(self) -> bool:
        return isinstance(self.spec, NutSpec)

    @property
    def yaw_period(self) -> float:
        """Symmetry of the part's grip faces: a hex nut's flats repeat every 60 degrees."""
        return yaw_symmetry(self.spec)

    @property
    def yaw_offset(self) -> float:
        """Part yaw minus hand yaw at which the fingers close on grip faces."""
        return NUT_GRIP_YAW if self.is_nut else 0.0

    @property
    def grip_offset(self) -> float:
        """Grip point above the part's centre.

        A peg is held 5 mm above its centre: high enough that the fingertips clear the hole block
        at full depth, low enough that it does not lever itself out of the grip (held 12 mm up,
        40% of rectangular pegs tilted in the fingers and caught on the hole's edge)."""
        return 0.0 if self.is_nut else 0.005

    def grip_yaw(self, ctx: Ctx, rows: np.ndarray, toward: np.ndarray) -> np.ndarray:
        """The grip-face hand yaw nearest ``toward`` (the current yaw for a round part)."""
        if self.yaw_period == 0.0:
            return ctx["ee_yaw"][rows]
        base = ctx["obj_yaw"][rows, self.index] - self.yaw_offset
        period = self.yaw_period
        return _within_reach(base + period * np.round((toward - base) / period), period)

    def grip_point(self, ctx: Ctx, rows: np.ndarray) -> np.ndarray:
        pos = ctx["obj_pos"][rows, self.index].copy()
        pos[:, 2] = np.maximum(pos[:, 2] + self.grip_offset, FLOOR_Z)
        return pos

    def bottom_to_fixture(self, ctx: Ctx, rows: np.ndarray) -> np.ndarray:
        """Fixture point minus the part's bottom centre (n, 3)."""
        return ctx["obj_to_fix"][rows, self.index]


def _within_reach(yaw: np.ndarray, period: float) -> np.ndarray:
    """``yaw``, or where it is outside the hand's range the yaw a symmetry ``period`` away:
    the part looks the same either way, and the wrist stops at its limits (a goal past one left
    a turned hole's peg 8 degrees off, more than it enters with)."""
    yaw = np.where(yaw > YAW_HIGH, yaw - period, yaw)
    return np.where(yaw < YAW_LOW, yaw + period, yaw)


def _fixture_yaw_goal(part: _Part, ctx: Ctx, rows: np.ndarray) -> np.ndarray:
    """Hand yaw that lines a held part up with its fixture (only a rectangular peg cares)."""
    if part.is_nut or part.yaw_period == 0.0:
        return ctx["ee_yaw"][rows]
    goal = ctx["ee_yaw"][rows] - ctx["yaw_error"][rows, part.index]
    return _within_reach(goal, part.yaw_period)


def _near(ctx: Ctx, rows: np.ndarray, goal: np.ndarray, tol: float) -> np.ndarray:
    return np.linalg.norm(ctx["ee_pos"][rows] - goal, axis=-1) < tol


def _never(ctx: Ctx, rows: np.ndarray, st: State) -> np.ndarray:
    """End condition of a phase that lasts until the episode ends."""
    return np.zeros(len(rows), dtype=bool)


def _always(ctx: Ctx, rows: np.ndarray, st: State) -> np.ndarray:
    return np.ones(len(rows), dtype=bool)


def _reached(goal: GoalFn, tol: float, yaw_tol: float = 0.04) -> TestFn:
    """End condition: the grip point is within ``tol`` of ``goal`` and the hand's yaw too."""

    def done(ctx: Ctx, rows: np.ndarray, st: State) -> np.ndarray:
        pos, yaw = goal(ctx, rows, st)
        yaw_ok = np.abs(ctx["ee_yaw"][rows] - yaw) < yaw_tol
        return _near(ctx, rows, pos, tol) & yaw_ok

    return done


def _after(steps: int) -> TestFn:
    return lambda ctx, rows, st: st.t[rows] >= steps


def _hold(ctx: Ctx, rows: np.ndarray, st: State) -> tuple[np.ndarray, np.ndarray]:
    return st.anchor[rows], st.anchor_yaw[rows]


# --------------------------------------------------------------------------- primitives
def _reach(part: _Part) -> list[Phase]:
    def goal(ctx, rows, st):
        return part.grip_point(ctx, rows), ctx["ee_yaw"][rows]

    return [Phase("reach", goal, False, _never)]


def _hover(part: _Part, height: float = 0.05) -> list[Phase]:
    """Move the grip point ``height`` over the part's fixture point and stay there."""

    def goal(ctx, rows, st):
        target = ctx["ee_pos"] + fixture_offset(ctx, part.index, height)
        return target[rows], ctx["ee_yaw"][rows]

    return [Phase("hover", goal, False, _never)]


def _grasp(part: _Part, hover: float) -> list[Phase]:
    """Hover ``hover`` metres over the grip point with the fingers turned, descend and close."""

    def above(ctx, rows, st):
        pos = part.grip_point(ctx, rows)
        pos[:, 2] += hover
        return pos, part.grip_yaw(ctx, rows, ctx["ee_yaw"][rows])

    def at(ctx, rows, st):
        return part.grip_point(ctx, rows), part.grip_yaw(ctx, rows, ctx["ee_yaw"][rows])

    return [
        Phase("hover", above, False, _reached(above, 0.004), timeout=60),
        Phase("descend", at, False, _reached(at, 0.0015, yaw_tol=np.inf), timeout=15),
        Phase("close", _hold, True, _after(4)),
    ]


def _raise_to(part: _Part, bottom_z: float) -> Phase:
    """Lift the held part until its bottom is at ``bottom_z``."""

    def goal(ctx, rows, st):
        pos = st.anchor[rows].copy()
        pos[:, 2] = (
            ctx["ee_pos"][rows, 2] + bottom_z + 0.003 - ctx["obj_bottom_z"][rows, part.index]
        )
        return pos, st.anchor_yaw[rows]

    def done(ctx, rows, st):
        return ctx["obj_bottom_z"][rows, part.index] >= bottom_z

    return Phase("lift part", goal, True, done, timeout=20)


def _pick(part: _Part, bottom_z: float = 0.06) -> list[Phase]:
    return [*_grasp(part, hover=0.04), _raise_to(part, bottom_z)]


def _servo_part(part: _Part, height: float, ctx: Ctx, rows: np.ndarray) -> np.ndarray:
    """Grip point goal that puts the held part's bottom ``height`` above its fixture point."""
    offset = part.bottom_to_fixture(ctx, rows).copy()
    offset[:, 2] += height
    return ctx["ee_pos"][rows] + offset


def _carry(part: _Part) -> list[Phase]:
    def up(ctx, rows, st):
        # Turn the part to the fixture's yaw here, before moving: turning the wrist while
        # travelling fast stalls the arm.
        pos = st.anchor[rows].copy()
        pos[:, 2] = ctx["ee_pos"][rows, 2] + TRAVEL_Z - ctx["obj_bottom_z"][rows, part.index]
        return pos, _fixture_yaw_goal(part, ctx, rows)

    def over(ctx, rows, st):
        pos = _servo_part(part, 0.0, ctx, rows)
        pos[:, 2] = ctx["ee_pos"][rows, 2] + TRAVEL_Z - ctx["obj_bottom_z"][rows, part.index]
        return pos, _fixture_yaw_goal(part, ctx, rows)

    def hover(ctx, rows, st):
        return _servo_part(part, HOVER, ctx, rows), _fixture_yaw_goal(part, ctx, rows)

    return [
        Phase("raise", up, True, _reached(up, 0.01, 0.02), timeout=15),
        Phase("travel", over, True, _reached(over, 0.006, 0.02), timeout=40, speed=CARRY_SPEED),
        Phase("hover", hover, True, _reached(hover, 0.001, 0.02), timeout=20),
    ]


def _place(part: _Part) -> list[Phase]:
    if part.is_nut:

        def onto(ctx, rows, st):
            # Aim below the tip: the nut's bottom stops on the thread crest and engages there.
            return _servo_part(part, -0.003, ctx, rows), ctx["ee_yaw"][rows]

        def engaged(ctx, rows, st):
            return ctx["engaged"][rows, part.index] > 0.5

        return [Phase("lower onto bolt", onto, True, engaged, timeout=25)]

    def hover(ctx, rows, st):
        return _servo_part(part, 0.005, ctx, rows), _fixture_yaw_goal(part, ctx, rows)

    return [Phase("hover", hover, True, _never)]


def _insert(part: _Part) -> list[Phase]:
    def down(ctx, rows, st):
        depth = hole_depth(ctx, part.index)[rows]
        return _servo_part(part, -0.8 * depth, ctx, rows), _fixture_yaw_goal(part, ctx, rows)

    def entrance(ctx, rows, st):
        return _servo_part(part, 0.002, ctx, rows), _fixture_yaw_goal(part, ctx, rows)

    near_entrance = _reached(entrance, 0.0015, yaw_tol=np.inf)

    def centred(ctx, rows, st):
        lateral = np.linalg.norm(part.bottom_to_fixture(ctx, rows)[:, :2], axis=-1)
        return near_entrance(ctx, rows, st) & (lateral < 0.0003)

    # Centre over the entrance first: a peg that enters off-centre tilts and jams half-way.
    return [
        Phase("centre", entrance, True, centred, timeout=12),
        # Never done: it keeps the peg deep and its yaw lined up, which the walls can disturb.
        Phase("insert", down, True, _never, speed=INSERT_SPEED),
    ]


def _lift(height: float, closed: bool | None = None) -> list[Phase]:
    """Raise the grip point ``height`` metres; ``closed`` None keeps the fingers as they are."""

    def up(ctx, rows, st):
        pos = st.anchor[rows].copy()
        pos[:, 2] += height
        return pos, st.anchor_yaw[rows]

    return [Phase("lift", up, closed, _reached(up, 0.004), timeout=20)]


def _release() -> list[Phase]:
    # Let the fingers open fully before moving, so they do not drag the part up with them.
    return [Phase("open", _hold, False, _after(3)), *_lift(0.03, closed=False)]


def _twist(part: _Part, sign: float) -> list[Phase]:
    """Regrasp-and-turn cycles: ``sign`` -1 screws down (clockwise from above), +1 unscrews."""
    start, end = (YAW_HIGH, YAW_LOW) if sign < 0 else (YAW_LOW, YAW_HIGH)
    i = part.index

    def finished(ctx, rows, st):
        if sign < 0:
            seated = ctx["seat_gap"][rows, i] <= 0.5 * part.spec.pitch
            return (ctx["engaged"][rows, i] > 0.5) & seated
        return ctx["engaged"][rows, i] < 0.5

    def regrasp(ctx, rows, st):
        return part.grip_point(ctx, rows), part.grip_yaw(ctx, rows, np.full(len(rows), start))

    def turn(ctx, rows, st):
        return part.grip_point(ctx, rows), np.full(len(rows), end)

    def turned(ctx, rows, st):
        return (np.abs(ctx["ee_yaw"][rows] - end) < 0.05) | finished(ctx, rows, st)

    return [
        Phase("regrasp", regrasp, False, _reached(regrasp, 0.002), timeout=40, turn_speed=1.0),
        Phase("grip", regrasp, True, _after(3)),
        Phase("turn", turn, True, turned, timeout=40, turn_speed=1.0),
        Phase("finished?", _hold, True, finished, branch=3),
        Phase("let go", _hold, False, _after(2)),
        Phase("again", _hold, False, _always, branch=-5),
    ]


def _push(part: _Part, dx: float, dy: float) -> list[Phase]:
    standoff = 0.012 + part.spec.grasp_width / 2 if part.is_nut else 0.012

    def target(ctx, rows):
        fix = ctx["obj_fixture"][rows, part.index].astype(int)
        return ctx["fix_pos"][rows, fix, :2] + np.array([dx, dy])

    def toward(ctx, rows):
        """Unit direction from the part to its target (n, 2) and the distance left (n, 1)."""
        gap = target(ctx, rows) - ctx["obj_pos"][rows, part.index, :2]
        distance = np.linalg.norm(gap, axis=-1, keepdims=True)
        return gap / np.maximum(distance, 1e-6), distance

    def behind(ctx, rows, st, z):
        d, _ = toward(ctx, rows)
        pos = np.empty((len(rows), 3))
        pos[:, :2] = ctx["obj_pos"][rows, part.index, :2] - d * standoff
        pos[:, 2] = z
        # The closed fingers make a paddle, turned a quarter turn from the push direction (pushed
        # end-on, 72% of 100 nuts reach the target instead of 95%); it is symmetric, so any yaw
        # modulo pi will do: keep it near home.
        return pos, wrap_angle(np.arctan2(d[:, 1], d[:, 0]) + math.pi / 2, math.pi)

    def above(ctx, rows, st):
        return behind(ctx, rows, st, 0.05)

    def low(ctx, rows, st):
        return behind(ctx, rows, st, FLOOR_Z)

    def shove(ctx, rows, st):
        # Advance towards the target while sliding sideways to stay behind the part: aimed at the
        # target instead, the hand lets the part drift off the line it is pushed along (76%).
        d, remaining = toward(ctx, rows)
        hand = ctx["ee_pos"][rows, :2]
        off = ctx["obj_pos"][rows, part.index, :2] - d * standoff - hand
        sideways = off - (off * d).sum(-1, keepdims=True) * d
        pos = np.empty((len(rows), 3))
        pos[:, :2] = hand + d * np.minimum(remaining, PUSH_LEAD) + sideways
        pos[:, 2] = FLOOR_Z
        return pos, st.anchor_yaw[rows]

    def arrived(ctx, rows, st):
        # Stop a little short along the line the push began on: the part slides on about a
        # centimetre after the hand stops, and near the target the direction to it swings about.
        goal = target(ctx, rows)
        line = goal - st.anchor[rows, :2]
        line /= np.maximum(np.linalg.norm(line, axis=-1, keepdims=True), 1e-6)
        short = ((goal - ctx["obj_pos"][rows, part.index, :2]) * line).sum(-1)
        return short < PUSH_STOP

    return [
        Phase("above", above, True, _reached(above, 0.005, 0.1), timeout=40),
        Phase("down", low, True, _reached(low, 0.003, 0.1), timeout=15),
        Phase("push", shove, True, arrived, timeout=60, speed=PUSH_SPEED),
        *_lift(0.03),
    ]


_PRIMITIVES: dict[str, tuple[Callable[..., list[Phase]], bool, int]] = {
    # name: (builder, takes an object slot first, how many extra numbers it accepts)
    "reach": (_reach, True, 0),
    "hover": (_hover, True, 1),
    "pick": (_pick, True, 1),
    "grasp": (lambda part: _grasp(part, hover=0.0), True, 0),
    "carry": (_carry, True, 0),
    "place": (_place, True, 0),
    "insert": (_insert, True, 0),
    "release": (_release, False, 0),
    "lift": (_lift, False, 1),
    "screw": (lambda part: _twist(part, -1.0), True, 0),
    "unscrew": (lambda part: _twist(part, +1.0), True, 0),
    "push": (_push, True, 2),
}


FIXTURE_STEPS = frozenset({"hover", "carry", "place", "insert", "screw", "unscrew", "push"})
"""The primitives that move a part to or about its fixture."""


def fitting_step_slots(spec: TaskSpec) -> set[int]:
    """The object slots ``spec``'s (compiled, so valid) script puts on or into their fixtures:
    inserted, screwed down, or a nut placed on its bolt's thread."""
    slots = set()
    for step in spec.script:
        name, *args = step.split()
        slot = int(float(args[0])) if args else -1
        if name in ("insert", "screw") or (
            name == "place" and isinstance(spec.objects[slot], NutSpec)
        ):
            slots.add(slot)
    return slots


_HEIGHT_STEPS = ("hover", "pick", "lift")
"""Steps whose numbers (after the object slot) are heights in metres."""


def compile_script(spec: TaskSpec) -> list[Phase]:
    """Expand ``spec.script`` into phases; :class:`ScriptError` names any bad step."""
    phases: list[Phase] = []
    for k, step in enumerate(spec.script):

        def bad(problem: str, k: int = k, step: str = step) -> ScriptError:
            return ScriptError(f"task {spec.id!r} script[{k}] {step!r}: {problem}", k, problem)

        name, *args = step.split() or [""]
        if name not in _PRIMITIVES:
            raise bad(f"unknown primitive {name!r}; known: {', '.join(_PRIMITIVES)}")
        if phases and phases[-1].done is _never:
            # It would load and never run: the step before holds its goal to the episode's end.
            raise bad(
                f"follows {spec.script[k - 1]!r}, which never ends (it holds its goal until "
                "the episode does): that step must be the script's last"
            )
        builder, needs_object, extra = _PRIMITIVES[name]
        if name in FIXTURE_STEPS and not spec.fixtures:
            # It steered to the fixture slot's zeros: the robot's base.
            raise bad(f"{name} needs a fixture; the task has none")
        try:
            numbers = [float(a) for a in args]
        except ValueError as err:
            raise bad("arguments must be numbers") from err
        # float() reads "nan" and "inf", which became NaN actions that broke the simulation.
        if not all(math.isfinite(v) for v in numbers):
            raise bad("arguments must be finite numbers")
        call_args: list = []
        if needs_object:
            if (
                not numbers
                or not numbers[0].is_integer()
                or not 0 <= numbers[0] < len(spec.objects)
            ):
                raise bad("the first argument must be an object slot")
            slot = int(numbers.pop(0))
            call_args.append(_Part(slot, spec.objects[slot]))
        if len(numbers) > extra or (name in ("lift", "push") and len(numbers) != extra):
            raise bad("wrong number of arguments")
        top = _CTRL.workspace_high[2]
        if name in _HEIGHT_STEPS and not all(0 <= v <= top for v in numbers):
            # A negative height drives the hand into the fixture or ends the lift at once; one
            # over the arm's reach is a goal it never gets to.
            raise bad(f"a height must be from 0 to {top:g} m (the arm's reach)")
        phases.extend(builder(*call_args, *numbers))
    return phases


class ScriptedPolicy:
    """Runs ``spec.script`` in each of ``num_envs`` environments: ``actions = policy(ctx)``."""

    def __init__(self, spec: TaskSpec, num_envs: int) -> None:
        if not spec.script:
            raise ScriptError(f"task {spec.id!r} has no script")
        self.spec = spec
        self.num_envs = num_envs
        self.phases = compile_script(spec)
        self.state = State(
            pc=np.zeros(num_envs, dtype=np.int64),
            t=np.zeros(num_envs, dtype=np.int64),
            anchor=np.zeros((num_envs, 3)),
            anchor_yaw=np.zeros(num_envs),
            last_move=np.zeros((num_envs, 3)),
            yaw_command=np.zeros(num_envs),
        )
        self._fresh = np.ones(num_envs, dtype=bool)

    def reset(self, env_ids: np.ndarray | None = None) -> None:
        """Restart the program in ``env_ids`` (all environments if None)."""
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids, dtype=np.int64)
        self.state.pc[ids] = 0
        self.state.t[ids] = 0
        # Anchors are taken from the next context these environments are seen in.
        self._fresh[ids] = True

    def _enter(self, ctx: Ctx, rows: np.ndarray, pc: np.ndarray) -> None:
        st = self.state
        st.pc[rows] = pc
        st.t[rows] = 0
        st.anchor[rows] = ctx["ee_pos"][rows]
        st.anchor_yaw[rows] = ctx["ee_yaw"][rows]

    def _advance(self, ctx: Ctx) -> None:
        """Move every environment past the phases whose end condition holds."""
        st, n_phases = self.state, len(self.phases)
        # Branches take no time, so a few transitions can happen in one control step.
        for _ in range(4):
            moved = False
            for k in np.unique(st.pc[st.pc < n_phases]):
                phase = self.phases[k]
                rows = np.flatnonzero(st.pc == k)
                done = phase.done(ctx, rows, st) | (st.t[rows] >= phase.timeout)
                if phase.branch is not None:
                    # A branch decides at once: jump where it holds, fall through where not.
                    self._enter(ctx, rows, k + np.where(done, phase.branch, 1))
                    moved = True
                    continue
                if not done.any():
                    continue
                self._enter(ctx, rows[done], np.full(int(done.sum()), k + 1))
                moved = True
            if not moved:
                break

    def __call__(self, ctx: dict[str, np.ndarray]) -> np.ndarray:
        """Actions (num_envs, 5) for the current context."""
        st = self.state
        fresh = np.flatnonzero(self._fresh)
        if len(fresh):
            self._enter(ctx, fresh, np.zeros(len(fresh), dtype=np.int64))
            st.yaw_command[fresh] = ctx["ee_yaw"][fresh]
            st.last_move[fresh] = 0.0
            self._fresh[fresh] = False
        self._advance(ctx)

        goal = ctx["ee_pos"].copy()
        goal_yaw = ctx["ee_yaw"].copy()
        closed = ctx["grip_closed"] > 0.5
        speed = np.ones(self.num_envs)
        turn = np.ones(self.num_envs)
        for k in np.unique(st.pc):
            rows = np.flatnonzero(st.pc == k)
            if k >= len(self.phases):  # program finished: hold still
                goal[rows], goal_yaw[rows] = st.anchor[rows], st.anchor_yaw[rows]
                continue
            phase = self.phases[k]
            goal[rows], goal_yaw[rows] = phase.goal(ctx, rows, st)
            speed[rows], turn[rows] = phase.speed, phase.turn_speed
            if phase.closed is not None:
                closed[rows] = phase.closed
        st.t += 1

        actions = np.empty((self.num_envs, 5))
        # Aim from where the hand will be after one more period at its current speed: the arm
        # lags its command, and plain proportional steps overshoot by a centimetre.
        ahead = ctx["ee_pos"] + VELOCITY_LEAD * _CONTROL_DT * ctx["ee_vel"]
        actions[:, :3] = (goal - ahead) / _CTRL.pos_step
        # Yaw goals lie inside the hand's range, so no wrapping: a twist must go the long way round.
        actions[:, 3] = np.clip((goal_yaw - st.yaw_command) / _CTRL.yaw_step, -turn, turn)
        st.yaw_command = np.clip(st.yaw_command + actions[:, 3] * _CTRL.yaw_step, *_CTRL.yaw_limits)
        # Speed up gradually (slowing down is free): a jolt from rest to full speed slides a held
        # part along the finger pads.
        limit = np.minimum(speed[:, None], np.abs(st.last_move) + MAX_SPEEDUP)
        actions[:, :3] = np.clip(actions[:, :3], -limit, limit)
        st.last_move = actions[:, :3].copy()
        actions[:, 4] = np.where(closed, 1.0, -1.0)
        return np.clip(actions, -1.0, 1.0)


def run_episodes(
    task: str, episodes: int, num_envs: int = 16, seed: int = 0, noise: float = 0.0
) -> list[bool]:
    """Success of ``episodes`` episodes of ``task``'s script on ``num_envs`` envs: those
    :func:`itskill.tasks.evaluate.evaluate` counts (a quota per environment, so the sample is not
    biased towards short episodes, which end early on success). ``noise``: the standard deviation
    of Gaussian noise added to its actions (:func:`~itskill.tasks.evaluate.with_noise`)."""
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import SCRIPTED, evaluate, with_noise

    policy = with_noise(SCRIPTED, noise, seed)
    return evaluate(get_task(task), policy, episodes, seed, num_envs).outcomes
