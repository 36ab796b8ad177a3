"""Assemble a task scene with ``mujoco.MjSpec``: table, Panda, parts, fixtures and thread couplings.

Physics choices (each measured in a prototype, see docs/simulation.md): a 4 ms step (5 ms dropped a
third of fast lifts), an elliptic friction cone with a high ``impratio`` so grasped parts do not
creep, and stiff part contacts.

Nuts hang on a chain of six joints (slide x, y, z, hinge yaw, hinge tilt x, tilt y) instead of a
free joint, so that a thread coupling can be expressed as joint equality constraints that each
environment switches on and off in its own ``MjData.eq_active`` (see :mod:`itskill.sim.thread`).
Each bolt also owns a mocap "thread crest" disc at its tip: it catches a nut that is lowered onto
the bolt, the way the first thread would, and is moved out of the way while the nut is engaged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from itskill.sim.panda import ARM_JOINTS, FINGER_JOINTS, GRIP_SITE, PREFIX, load_panda_spec
from itskill.sim.parts import (
    CONTACT_ROBOT_TABLE,
    CONTACT_TABLE,
    BoltSpec,
    HoleSpec,
    NutSpec,
    PartSpec,
    PegSpec,
    PlacedFixture,
    build_bolt,
    build_hole,
    build_nut,
    build_peg,
    fits,
)

TIMESTEP = 0.004
TABLE_HALF = (0.45, 0.55)
TABLE_CENTER_X = 0.45
PARKED_Z = -0.3
"""Where a crest disc waits while its nut is engaged: inside the table, where nothing collides."""
CREST_OVERHANG = 0.00075
"""How far the crest disc reaches past the bore flats, radially."""


@dataclass(frozen=True)
class SceneSpec:
    """What a scene holds: up to two movable parts and up to two fixtures."""

    objects: tuple[PartSpec, ...]
    fixtures: tuple[PlacedFixture, ...]

    def __post_init__(self) -> None:
        if not 1 <= len(self.objects) <= 2:
            raise ValueError("a scene holds 1 or 2 movable parts")
        if len(self.fixtures) > 2:
            raise ValueError("a scene holds at most 2 fixtures")


@dataclass
class ThreadPair:
    """A nut/bolt pair whose thread can couple: ids of the five equalities that lock it."""

    obj: int
    fixture: int
    eq_ids: tuple[int, ...]
    lead: float
    """Nut travel per radian of turn (pitch / 2 pi)."""
    seat_center_z: float
    crest_mocap: int


@dataclass
class Scene:
    """A compiled scene and the indices the environment reads every step."""

    spec: SceneSpec
    model: mujoco.MjModel
    grip_site: int
    arm_qpos: np.ndarray
    arm_dof: np.ndarray
    finger_qpos: np.ndarray
    obj_bodies: np.ndarray
    obj_qpos: list[np.ndarray]
    """qpos addresses of each object's joints (6 for a nut chain, 7 for a peg's free joint)."""
    obj_dof: list[np.ndarray]
    threads: list[ThreadPair] = field(default_factory=list)
    crest_home: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def _add_table(spec: mujoco.MjSpec) -> None:
    spec.add_texture(
        name="grid",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.62, 0.55, 0.46],
        rgb2=[0.58, 0.51, 0.42],
        width=256,
        height=256,
    )
    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.75, 0.8, 0.86],
        rgb2=[0.3, 0.33, 0.38],
        width=256,
        height=256,
    )
    table_mat = spec.add_material(name="table", texrepeat=[8, 8], reflectance=0.0)
    table_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    world = spec.worldbody
    # The table top is a plane: cylinders and boxes get several contact points on a plane (a
    # standing 4 mm peg stays up), and nothing pushed off the table can fall forever.
    table = world.add_geom(
        name="table",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[TABLE_HALF[0], TABLE_HALF[1], 0.02],
        pos=[TABLE_CENTER_X, 0, 0],
        material="table",
    )
    table.friction = [0.6, 0.005, 0.0001]
    table.contype = CONTACT_TABLE | CONTACT_ROBOT_TABLE
    table.conaffinity = CONTACT_TABLE
    world.add_light(pos=[0.5, -0.4, 1.6], dir=[-0.1, 0.3, -1], diffuse=[0.5, 0.5, 0.5])
    # Both cameras look at the workspace centre, above where parts and fixtures sit, with room
    # for the hand over them.
    world.add_camera(name="front", pos=[1.05, 0.0, 0.40], xyaxes=[0, 1, 0, -0.479, 0, 0.878])
    world.add_camera(
        name="closeup", pos=[0.8, -0.22, 0.2], xyaxes=[0.618, 0.786, 0, -0.306, 0.24, 0.922]
    )


def _add_object(spec: mujoco.MjSpec, index: int, part: PartSpec) -> mujoco.MjsBody:
    body = spec.worldbody.add_body(name=f"obj{index}")
    if isinstance(part, NutSpec):
        for axis, name in (((1, 0, 0), "x"), ((0, 1, 0), "y"), ((0, 0, 1), "z")):
            body.add_joint(name=f"obj{index}_{name}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=axis)
        for axis, name in (((0, 0, 1), "yaw"), ((1, 0, 0), "tiltx"), ((0, 1, 0), "tilty")):
            joint = body.add_joint(
                name=f"obj{index}_{name}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis
            )
            if name != "yaw":
                # Armature keeps the chain's mass matrix regular when a fallen nut's tilt lines up
                # two hinge axes (tilt x at 90 degrees), which otherwise made the step blow up.
                joint.armature = 1e-6
            if name == "yaw":
                # Friction on the turn makes the thread self-locking, as real threads are: the
                # nut's weight cannot back-drive it down the bolt.
                joint.frictionloss = 2e-3
        build_nut(body, part)
    else:
        body.add_freejoint(name=f"obj{index}_free")
        build_peg(body, part)
    return body


def _add_fixture(spec: mujoco.MjSpec, index: int, placed: PlacedFixture) -> None:
    x, y = placed.xy
    body = spec.worldbody.add_body(
        name=f"fix{index}",
        pos=[x, y, 0.0],
        quat=[math.cos(placed.yaw / 2), 0, 0, math.sin(placed.yaw / 2)],
    )
    if isinstance(placed.part, BoltSpec):
        build_bolt(body, placed.part)
        crest = spec.worldbody.add_body(name=f"crest{index}", mocap=True, pos=[x, y, PARKED_Z])
        bolt = placed.part
        crest.add_geom(
            name=f"crest{index}_geom",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[bolt.thread_diameter / 2 + CREST_OVERHANG + 0.00025, 0.0005, 0],
            rgba=list(bolt.rgba),
            friction=[1.0, 0.01, 0.001],
        )
    else:
        build_hole(body, placed.part)


def _add_thread_equalities(spec: mujoco.MjSpec, obj: int, fix: int, nut: NutSpec, placed) -> None:
    bolt: BoltSpec = placed.part
    seat_center = bolt.seat_z + nut.height / 2
    lead = nut.pitch / (2 * math.pi)
    # The turn is the dependent joint (yaw = (z - seat) / lead), not the height: MuJoCo scales a
    # constraint's softness by the inverse inertia of its first joint, and a nut's spin inertia is
    # so small that a z-first equality pushed with about 1 mN against the nut's 0.15 N weight, so
    # an "engaged" nut slid down the bolt.
    locks = (
        ("x", None, [placed.xy[0], 0, 0, 0, 0]),
        ("y", None, [placed.xy[1], 0, 0, 0, 0]),
        ("yaw", "z", [-seat_center / lead, 1 / lead, 0, 0, 0]),
        ("tiltx", None, [0, 0, 0, 0, 0]),
        ("tilty", None, [0, 0, 0, 0, 0]),
    )
    for joint1, joint2, coef in locks:
        eq = spec.add_equality(
            name=f"thread{obj}_{fix}_{joint1}",
            type=mujoco.mjtEq.mjEQ_JOINT,
            name1=f"obj{obj}_{joint1}",
            name2=f"obj{obj}_{joint2}" if joint2 else "",
            active=False,
        )
        eq.data[: len(coef)] = coef
        eq.solref = [0.008, 1.0]


def build_scene(scene_spec: SceneSpec) -> Scene:
    """Compile the scene for ``scene_spec`` and collect the indices the environment needs."""
    spec = mujoco.MjSpec()
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.4, 0.4, 0.4]
    spec.stat.center = [0.45, 0.0, 0.1]
    spec.stat.extent = 0.8
    _add_table(spec)
    robot = load_panda_spec()
    spec.worldbody.add_frame().attach_body(robot.body("link0"), PREFIX, "")

    for i, part in enumerate(scene_spec.objects):
        _add_object(spec, i, part)
    for j, placed in enumerate(scene_spec.fixtures):
        _add_fixture(spec, j, placed)
    pairs = [
        (i, j)
        for i, part in enumerate(scene_spec.objects)
        for j, placed in enumerate(scene_spec.fixtures)
        if isinstance(part, NutSpec) and fits(part, placed.part)
    ]
    for i, j in pairs:
        _add_thread_equalities(spec, i, j, scene_spec.objects[i], scene_spec.fixtures[j])

    model = spec.compile()
    return _index(scene_spec, model, pairs)


def _index(scene_spec: SceneSpec, model: mujoco.MjModel, pairs) -> Scene:
    def jnt(name: str) -> int:
        return model.joint(name).id

    arm = [jnt(n) for n in ARM_JOINTS]
    obj_qpos, obj_dof = [], []
    for i, part in enumerate(scene_spec.objects):
        names = (
            [f"obj{i}_{n}" for n in ("x", "y", "z", "yaw", "tiltx", "tilty")]
            if isinstance(part, NutSpec)
            else [f"obj{i}_free"]
        )
        ids = [jnt(n) for n in names]
        if isinstance(part, PegSpec):
            obj_qpos.append(np.arange(model.jnt_qposadr[ids[0]], model.jnt_qposadr[ids[0]] + 7))
            obj_dof.append(np.arange(model.jnt_dofadr[ids[0]], model.jnt_dofadr[ids[0]] + 6))
        else:
            obj_qpos.append(model.jnt_qposadr[ids].copy())
            obj_dof.append(model.jnt_dofadr[ids].copy())
    threads = []
    for i, j in pairs:
        nut: NutSpec = scene_spec.objects[i]
        bolt: BoltSpec = scene_spec.fixtures[j].part
        eq_ids = tuple(
            model.equality(f"thread{i}_{j}_{n}").id for n in ("x", "y", "yaw", "tiltx", "tilty")
        )
        threads.append(
            ThreadPair(
                obj=i,
                fixture=j,
                eq_ids=eq_ids,
                lead=nut.pitch / (2 * math.pi),
                seat_center_z=bolt.seat_z + nut.height / 2,
                crest_mocap=int(model.body_mocapid[model.body(f"crest{j}").id]),
            )
        )
    crest_home = np.zeros((model.nmocap, 3))
    for j, placed in enumerate(scene_spec.fixtures):
        if isinstance(placed.part, BoltSpec):
            mocap = model.body_mocapid[model.body(f"crest{j}").id]
            crest_home[mocap] = [placed.xy[0], placed.xy[1], placed.part.tip_z - 0.0005]
    return Scene(
        spec=scene_spec,
        model=model,
        grip_site=model.site(GRIP_SITE).id,
        arm_qpos=model.jnt_qposadr[arm].copy(),
        arm_dof=model.jnt_dofadr[arm].copy(),
        finger_qpos=model.jnt_qposadr[[jnt(n) for n in FINGER_JOINTS]].copy(),
        obj_bodies=np.array([model.body(f"obj{i}").id for i in range(len(scene_spec.objects))]),
        obj_qpos=obj_qpos,
        obj_dof=obj_dof,
        threads=threads,
        crest_home=crest_home,
    )


def offscreen_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
    """A renderer of ``width`` x ``height`` pixels for ``model``, whose offscreen buffer is
    enlarged first where the image is bigger than it (MuJoCo's error otherwise sends the user
    to a model XML that a scene built in code does not have)."""
    if width < 1 or height < 1:
        raise ValueError(f"an image needs a positive size, got {width} x {height}")
    buffer = model.vis.global_
    buffer.offwidth, buffer.offheight = max(buffer.offwidth, width), max(buffer.offheight, height)
    return mujoco.Renderer(model, height=height, width=width)


def fixture_anchor(placed: PlacedFixture) -> np.ndarray:
    """The point a part is brought to: a bolt's tip or a hole's entrance centre."""
    z = placed.part.tip_z if isinstance(placed.part, BoltSpec) else placed.part.entrance_z
    return np.array([placed.xy[0], placed.xy[1], z])


__all__ = [
    "HoleSpec",
    "Scene",
    "SceneSpec",
    "ThreadPair",
    "build_scene",
    "fixture_anchor",
    "offscreen_renderer",
]
