"""Task files: errors that say where, the predicate language, stages, the packaged suite."""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import itskill.tasks.spec as spec_module
from itskill.sim.task import Range
from itskill.tasks import TaskFileError, UnknownTaskError, all_tasks, get_task, make_batch_env
from itskill.tasks.predicates import PREDICATES, PredicateError, parse
from itskill.tasks.spec import load_parts, load_task_file

PARTS_FILE = Path(spec_module.__file__).parent / "data" / "parts.toml"

VALID = """\
[[task]]
id = "my_pick"
family = "nutbolt"
kind = "basic"
command = "Pick up the M12 nut"
skills = ["Pick"]
actions = ["approach", "grasp"]
objects = ["nut_m12"]
fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]
max_steps = 60
success = "lifted(0, 3) and grasped(0)"
stages = [
  { name = "approach", done = "near(0, 0.02)" },
  { name = "grasp", done = "grasped(0)" },
]
[task.init]
ee = { x = [0.4, 0.5], y = [-0.08, 0.08], z = [0.15, 0.22] }
objects = [
  { mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] },
]
"""


@pytest.fixture(scope="module")
def parts():
    return load_parts(PARTS_FILE)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "mytasks.toml"
    path.write_text(text)
    return path


def test_valid_file_loads(tmp_path, parts):
    (task,) = load_task_file(write(tmp_path, VALID), parts)
    assert task.id == "my_pick"
    assert task.command == "Pick up the M12 nut"
    assert task.max_steps == 60
    assert [s.name for s in task.stages] == ["approach", "grasp"]
    assert task.objects[0].name == "nut_m12"
    assert task.source.endswith("mytasks.toml")


# Each case: an edit to the valid file, the field the error must name, a word of the problem.
BROKEN = {
    "toml_syntax": (("max_steps = 60", "max_steps = = 60"), "TOML syntax", "line"),
    "unknown_field": (("max_steps = 60", "max_steps = 60\ncolour = 'red'"), "colour", "unknown"),
    "missing_command": (('command = "Pick up the M12 nut"\n', ""), "command", "missing"),
    "wrong_type": (("max_steps = 60", 'max_steps = "ten"'), "max_steps", "int"),
    # An evaluation's first episode ran without end and without a word.
    "endless_episode": (("max_steps = 60", "max_steps = 100000000000"), "max_steps", "10,000"),
    "no_episode": (("max_steps = 60", "max_steps = 0"), "max_steps", "from 1"),
    "unknown_predicate": (('done = "grasped(0)"', 'done = "flying(0)"'), "stages[1]", "flying"),
    "unknown_part": (('objects = ["nut_m12"]', 'objects = ["nut_m99"]'), "objects", "nut_m99"),
    "init_count": (
        ('objects = ["nut_m12"]', 'objects = ["nut_m12", "nut_m16"]'),
        "init.objects",
        "expected 2",
    ),
    "hold_off_hand": (
        ('{ mode = "table", x', '{ mode = "table", hold = 0.005, x'),
        "init.objects[0].hold",
        "gripper",
    ),
    "symmetric_yaw_off_hand": (
        ('{ mode = "table", x', '{ mode = "table", symmetric_yaw = true, x'),
        "init.objects[0].symmetric_yaw",
        "only a part in the hand",
    ),
    "symmetric_yaw_not_bool": (
        (
            '{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }',
            '{ mode = "gripper", x = 0.5, z = 0.05, symmetric_yaw = 1 }',
        ),
        "init.objects[0].symmetric_yaw",
        "bool",
    ),
    # A bool is an int to Python but a mask to NumPy.
    "object_fixture_bool": (
        (
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]',
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]\nobject_fixture = [true]',
        ),
        "object_fixture",
        "one fixture index per object",
    ),
    "hold_beyond_grasped": (
        (
            '{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }',
            '{ mode = "gripper", x = 0.5, z = 0.05, hold = [-0.012, 0.003] }',
        ),
        "init.objects[0].hold",
        "11.4 mm",
    ),
    # TOML reads nan and inf: accepted, they failed at the first reset with an OverflowError.
    "nan_in_range": (("z = [0.15, 0.22]", "z = [nan, 0.22]"), "init.ee.z", "got [nan, 0.22]"),
    "inf_in_range": (
        ("x = [0.45, 0.58]", "x = [0.45, inf]"),
        "init.objects[0].x",
        "expected a finite number or [low, high] of finite numbers, got [0.45, inf]",
    ),
    "nan_as_range": (
        ('{ mode = "table", x', '{ mode = "table", yaw = nan, x'),
        "init.objects[0].yaw",
        "got nan",
    ),
    "inf_fixture_xy": (("xy = [0.55, 0.12]", "xy = [0.55, inf]"), "fixtures[0].xy", "finite"),
    "nan_fixture_yaw": (
        ("xy = [0.55, 0.12] }", "xy = [0.55, 0.12], yaw = nan }"),
        "fixtures[0].yaw",
        "expected a finite number, got nan",
    ),
    "object_slot": (('success = "lifted(0, 3)', 'success = "lifted(1, 3)'), "success", "slot 1"),
    "predicate_arguments": (
        ('success = "lifted(0, 3)', 'success = "lifted(0, 3, 4, 5)'),
        "success",
        "lifted takes (i, heights=3.0), got 4",
    ),
    "start_share": (
        (
            "max_steps = 60",
            'max_steps = 60\ntraining_starts = [{ task = "lift_nut_m12", share = 1.5 }]',
        ),
        "training_starts[0].share",
        "0 < share < 1",
    ),
    # A bad script step failed only when the scripted controller first ran.
    "unknown script primitive": (
        ("max_steps = 60", 'max_steps = 60\nscript = ["pick 0", "juggle 0"]'),
        "script[1]",
        "unknown primitive 'juggle'",
    ),
    "script object slot": (
        ("max_steps = 60", 'max_steps = 60\nscript = ["pick 3"]'),
        "script[0]",
        "object slot",
    ),
    # It loaded and never ran: the reach before it holds its goal to the episode's end.
    "script step after one that never ends": (
        ("max_steps = 60", 'max_steps = 60\nscript = ["reach 0", "lift 0.05"]'),
        "script[1]",
        "follows 'reach 0', which never ends",
    ),
    # float() reads nan: the controller's first action was NaN, then an SVD error.
    "script nan": (
        ("max_steps = 60", 'max_steps = 60\nscript = ["lift nan"]'),
        "script[0]",
        "finite",
    ),
    # Loaded: the hand drove into the fixture, or the lift ended at once.
    "script negative height": (
        ("max_steps = 60", 'max_steps = 60\nscript = ["pick 0 -5"]'),
        "script[0]",
        "a height must be from 0 to 0.45 m",
    ),
    "script height past the reach": (
        ("max_steps = 60", 'max_steps = 60\nscript = ["pick 0", "lift 1e6"]'),
        "script[1]",
        "a height must be from 0 to 0.45 m",
    ),
    # The observation's stage one-hot has 8 slots: it loaded, then failed in BatchEnv.
    "nine stages": (
        (
            '  { name = "grasp", done = "grasped(0)" },\n',
            '  { name = "grasp", done = "grasped(0)" },\n' * 8,
        ),
        "stages",
        "9 stages; at most 8",
    ),
    # Read as lifted(0, 3): the height went into the first optional argument.
    "empty argument": (('success = "lifted(0, 3)', 'success = "lifted(0,, 3)'), "success", "empty"),
    # Parts started inside the bolt or under the table: the physics held them stuck, or pushed
    # them away at the first step, and the episodes measured 0% without a word.
    "part inside fixture": (
        ("x = [0.45, 0.58], y = [-0.14, -0.02] }", "x = [0.45, 0.58], y = [-0.14, 0.12] }"),
        "init.objects[0]",
        "nut_m12 can start inside bolt_m12",
    ),
    "part under the table": (
        (
            '{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }',
            '{ mode = "gripper", x = 0.5, z = 0.011, hold = -0.011 }',
        ),
        "init.objects[0].z",
        "bottom would start under the table",
    ),
    # Both loaded, and the episodes ran from interpenetrating geometry without a word.
    "fixture inside fixture": (
        (
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]',
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }, '
            '{ part = "hole_round_4mm", xy = [0.56, 0.13] }]',
        ),
        "fixtures[1].xy",
        "hole_round_4mm would stand inside bolt_m12 (fixtures[0])",
    ),
    # A step to the fixture in a task without one steered to the robot's base.
    "fixture step without fixture": (
        (
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]',
            'fixtures = []\nscript = ["pick 0", "carry 0"]',
        ),
        "script[1]",
        "carry needs a fixture; the task has none",
    ),
}


@pytest.mark.parametrize("case", list(BROKEN))
def test_malformed_task_file_names_the_file_and_the_field(tmp_path, parts, case):
    (old, new), field, problem = BROKEN[case]
    assert old in VALID
    path = write(tmp_path, VALID.replace(old, new, 1))
    with pytest.raises(TaskFileError) as err:
        load_task_file(path, parts)
    message = str(err.value)
    assert str(path) in message
    assert field in message and field in err.value.where
    assert problem in message
    assert err.value.path == str(path)


@pytest.mark.parametrize(
    ("nut", "problem"), [("nut_m16", "does not screw onto bolt_m12"), ("peg_round_4mm", "")]
)
def test_a_part_started_on_a_bolt_must_screw_onto_it(tmp_path, parts, nut, problem):
    # It loaded, then failed at the first reset with a bare StopIteration or AttributeError.
    # The part is meant for the second fixture, a hole it fits, and started on the bolt.
    text = (
        VALID.replace('objects = ["nut_m12"]', f'objects = ["{nut}"]')
        .replace(
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]',
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }, '
            '{ part = "hole_round_4mm", xy = [0.55, -0.12] }]\nobject_fixture = [1]',
        )
        .replace(
            '{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }',
            '{ mode = "bolt", fixture = 0 }',
        )
    )
    if nut == "nut_m16":
        text = text.replace('"hole_round_4mm"', '"bolt_m16"')
    with pytest.raises(TaskFileError, match=f"init.objects\\[0\\].mode.*{nut} {problem}"):
        load_task_file(write(tmp_path, text), parts)


def test_two_parts_started_on_one_fixture_are_refused(tmp_path, parts):
    # A shank is shorter than two nuts are tall: they started inside each other, whatever their
    # turns, and the episodes ran on without a word.
    text = VALID.replace('objects = ["nut_m12"]', 'objects = ["nut_m12", "nut_m12"]').replace(
        '{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] },',
        '{ mode = "bolt", fixture = 0, turns = 0 },\n  { mode = "bolt", fixture = 0, turns = 3 },',
    )
    with pytest.raises(TaskFileError) as err:
        load_task_file(write(tmp_path, text), parts)
    assert err.value.where.endswith("init.objects[1].fixture")
    assert "nut_m12 would start on bolt_m12 with objects[0]: one part per fixture" in str(err.value)


def test_a_part_measured_against_a_fixture_it_does_not_fit_is_refused(tmp_path, parts):
    # A nut meant for another thread's bolt: the task loaded and succeeded never.
    misfit = VALID.replace('objects = ["nut_m12"]', 'objects = ["nut_m16"]')
    with pytest.raises(TaskFileError, match=r"objects\[0\].*nut_m16 does not fit fixture 0"):
        load_task_file(write(tmp_path, misfit.replace('grasped(0)"\n', 'engaged(0)"\n')), parts)
    # Only picked up, or measured only beside it, it may stand by any fixture.
    load_task_file(write(tmp_path, misfit), parts)
    beside = misfit.replace('grasped(0)"\n', 'not engaged(0) and above_fixture(0, 0.05, 0.1)"\n')
    load_task_file(write(tmp_path, beside), parts)


@pytest.mark.parametrize("hole", ["hole_round_4mm", "hole_rect_14mm"])
def test_a_peg_started_in_a_hole_it_does_not_fit_is_refused(tmp_path, parts, hole):
    # It started stuck in the middle of a bore narrower than itself: a bore of another shape,
    # or of its own shape 2 mm narrower than the 16 mm peg.
    narrow = replace(parts["hole_rect_16mm"], name="hole_rect_14mm", width=0.014)
    text = (
        VALID.replace('objects = ["nut_m12"]', 'objects = ["peg_rect_16mm"]')
        .replace('part = "bolt_m12"', f'part = "{hole}"')
        .replace('{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }', '{ mode = "hole" }')
    )
    with pytest.raises(TaskFileError, match=r"init.objects\[0\].mode.*peg_rect_16mm does not fit"):
        load_task_file(write(tmp_path, text), parts | {narrow.name: narrow})
    wide = text.replace(f'part = "{hole}"', 'part = "hole_rect_16mm"')
    load_task_file(write(tmp_path, wide), parts)  # its own hole takes it


def test_a_stage_over_a_hole_that_stops_holding_before_the_insert_does_is_refused(tmp_path, parts):
    # Between 2 mm (above_fixture's default) and 10 mm in (half the 2 cm hole), neither stage
    # held: the task fell back to its approach while the peg went in.
    text = (
        VALID.replace('objects = ["nut_m12"]', 'objects = ["peg_rect_16mm"]')
        .replace('part = "bolt_m12"', 'part = "hole_rect_16mm"')
        .replace('actions = ["approach", "grasp"]', 'actions = ["place", "insert"]')
        .replace('success = "lifted(0, 3) and grasped(0)"', 'success = "inserted(0, 0.5)"')
        .replace('name = "approach", done = "near(0, 0.02)"', 'name = "place", done = "DONE"')
        .replace('name = "grasp", done = "grasped(0)"', 'name = "insert", done = "inserted(0)"')
        .replace('{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }',
                 '{ mode = "gripper", x = 0.55, y = 0.12, z = 0.05 }')
        .replace("ee = { x = [0.4, 0.5], y = [-0.08, 0.08], z = [0.15, 0.22] }", "")
    )  # fmt: skip
    above = "above_fixture(0, 0.0015, 0.01) and grasped(0)"
    with pytest.raises(
        TaskFileError, match=r"stages\[0\]\.done.*2 mm into hole_rect_16mm.*at least 0\.01"
    ):
        load_task_file(write(tmp_path, text.replace("DONE", above)), parts)
    deep = above.replace("0.01)", "0.01, 0.01)")
    (task,) = load_task_file(write(tmp_path, text.replace("DONE", deep)), parts)
    assert task.stages[0].done.source == deep
    # The depth the message asks for loads, whatever the rounding of fraction x hole depth.
    nine_tenths = text.replace('done = "inserted(0)"', 'done = "inserted(0, 0.9)"')
    with pytest.raises(TaskFileError, match=r"at least 0\.018$"):
        load_task_file(write(tmp_path, nine_tenths.replace("DONE", above)), parts)
    asked = above.replace("0.01)", "0.01, 0.018)")
    load_task_file(write(tmp_path, nine_tenths.replace("DONE", asked)), parts)
    # Seated within 1 mm of the hole's floor: from 19 mm in.
    seated = text.replace('done = "inserted(0)"', 'done = "seated(0, 0.001)"')
    with pytest.raises(TaskFileError, match=r"only from 19 mm.*at least 0\.019$"):
        load_task_file(write(tmp_path, seated.replace("DONE", deep)), parts)


def test_a_fixture_predicate_in_a_task_without_fixtures_is_refused(tmp_path, parts):
    # Its fixture slots read as zeros: "above the fixture" meant above the robot's base.
    text = VALID.replace(
        'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]', "fixtures = []"
    ).replace('done = "grasped(0)"', 'done = "grasped(0) and above_fixture(0)"')
    with pytest.raises(TaskFileError, match=r"stages\[1\]\.done.*above_fixture needs a fixture"):
        load_task_file(write(tmp_path, text), parts)
    (task,) = load_task_file(write(tmp_path, text.replace(" and above_fixture(0)", "")), parts)
    # Nor do its observations: an object was measured against a fixture at the robot's base.
    env = make_batch_env(task, num_envs=2, seed=0)
    try:
        env.reset()
        ctx = env.context()
    finally:
        env.close()
    for key in ("obj_to_fix", "yaw_error", "seat_gap", "insertion_depth", "engaged"):
        assert not ctx[key].any(), key


def test_tasks_that_are_not_task_tables_name_the_file(tmp_path, parts):
    # It was a bare TypeError ('int' object is not iterable) from `itskill tasks list`.
    path = write(tmp_path, "task = 5\n")
    with pytest.raises(TaskFileError, match=r"expected \[\[task\]\] tables, got int") as err:
        load_task_file(path, parts)
    assert (err.value.path, err.value.where) == (str(path), "task")


NUT = "[nut.my_nut]\nacross_flats = 0.02\nheight = 0.01\nthread_diameter = 0.012\npitch = 0.00175\n"


@pytest.mark.parametrize("rgba", ["1", "[1, 0, 0]", '[1, 0, 0, "opaque"]', "[1, 0, 0, nan]"])
def test_a_part_colour_that_is_not_four_numbers_names_the_field(tmp_path, rgba):
    path = tmp_path / "parts.toml"
    path.write_text(f"{NUT}rgba = {rgba}\n")
    with pytest.raises(TaskFileError) as err:
        load_parts(path)
    assert (err.value.path, err.value.where) == (str(path), "nut.my_nut.rgba")
    path.write_text(f"{NUT}rgba = [1, 0, 0, 1]\n")
    assert load_parts(path)["my_nut"].rgba == (1.0, 0.0, 0.0, 1.0)


@pytest.mark.parametrize("size", ["inf", "nan"])
def test_a_part_dimension_that_is_not_finite_names_the_field(tmp_path, size):
    # The parts' own checks let an infinite clearance (and a nan one) through to the simulator.
    path = tmp_path / "parts.toml"
    path.write_text(f"{NUT}bore_clearance = {size}\n")
    with pytest.raises(TaskFileError, match=f"expected a finite number, got {size}") as err:
        load_parts(path)
    assert (err.value.path, err.value.where) == (str(path), "nut.my_nut.bore_clearance")


@pytest.mark.parametrize(("a_file", "problem"), [(False, "no such directory"), (True, "not a")])
def test_a_user_tasks_directory_that_is_not_one_is_named(monkeypatch, tmp_path, a_file, problem):
    # A mistyped ITSKILL_TASKS_DIR was ignored: its tasks were only "unknown".
    user = tmp_path / "mytasks"
    if a_file:
        user.write_text("")
    monkeypatch.setenv(spec_module.TASKS_DIR_ENV, str(user))
    with pytest.raises(TaskFileError) as err:
        all_tasks()
    assert (err.value.path, err.value.where) == (str(user), spec_module.TASKS_DIR_ENV)
    assert problem in err.value.problem


def _user_registry(monkeypatch, tmp_path, starts: str) -> dict:
    """Every task, packaged and ``VALID`` with ``training_starts = starts`` in a user directory."""
    write(tmp_path, VALID.replace("max_steps = 60", f"max_steps = 60\ntraining_starts = {starts}"))
    monkeypatch.setenv(spec_module.TASKS_DIR_ENV, str(tmp_path))
    spec_module._registry.cache_clear()
    try:
        return all_tasks()
    finally:
        spec_module._registry.cache_clear()


def test_training_starts_take_the_named_tasks_start(monkeypatch, tmp_path):
    starts = '[{ task = "lift_nut_m12", share = 0.2 }, { task = "grasp_nut_m12", share = 0.1 }]'
    tasks = _user_registry(monkeypatch, tmp_path, starts)
    lift, grasp = tasks["my_pick"].training_starts
    assert (lift.name, lift.share, lift.init) == ("lift_nut_m12", 0.2, tasks["lift_nut_m12"].init)
    assert (grasp.share, grasp.init) == (0.1, tasks["grasp_nut_m12"].init)
    assert tasks["my_pick"].to_sim_task().training_starts == (lift, grasp)


def test_a_training_start_can_be_written_out_in_the_task(monkeypatch, tmp_path):
    starts = (
        '[{ share = 0.25, init = { ee = { yaw = [-2.0, 3.0] }, objects = [{ mode = "table",'
        " x = [0.5, 0.5], y = [0.0, 0.0] }] } }, "
        '{ task = "grasp_nut_m12", share = 0.1 }]'
    )
    tasks = _user_registry(monkeypatch, tmp_path, starts)
    inline, grasp = tasks["my_pick"].training_starts
    assert (inline.name, inline.share) == ("", 0.25)
    assert (inline.init.ee_yaw.low, inline.init.ee_yaw.high) == (-2.0, 3.0)
    assert inline.init.objects[0].x.low == 0.5
    assert grasp.init == tasks["grasp_nut_m12"].init


def test_a_written_out_training_start_keeps_what_it_leaves_out_from_the_tasks_start(
    monkeypatch, tmp_path
):
    starts = "[{ share = 0.3, init = { objects = [{ y = [-0.1, -0.09] }] } }]"
    task = _user_registry(monkeypatch, tmp_path, starts)["my_pick"]
    (start,) = task.training_starts
    own, changed = task.init.objects[0], start.init.objects[0]
    assert (changed.y.low, changed.y.high) == (-0.1, -0.09)
    assert (changed.mode, changed.x, changed.yaw) == (own.mode, own.x, own.yaw)
    assert (start.init.ee_x, start.init.ee_y, start.init.ee_z) == (
        task.init.ee_x,
        task.init.ee_y,
        task.init.ee_z,
    )


@pytest.mark.parametrize(
    ("starts", "problem"),
    [
        ("[{ share = 0.2 }]", "either task"),
        ('[{ task = "lift_nut_m12", init = { objects = [] }, share = 0.2 }]', "either task"),
        ("[{ share = 0.2, init = { objects = [{}, {}] } }]", "the task has 1 object(s)"),
        ('[{ task = "lift_nut_m99", share = 0.2 }]', "unknown task 'lift_nut_m99'"),
        ('[{ task = "lift_nut_m16", share = 0.2 }]', "other parts or fixtures"),
        (
            '[{ task = "lift_nut_m12", share = 0.6 }, { task = "grasp_nut_m12", share = 0.4 }]',
            "sum to less than 1",
        ),
    ],
)
def test_a_training_start_from_another_scene_or_task_is_refused(
    monkeypatch, tmp_path, starts, problem
):
    with pytest.raises(TaskFileError, match="training_starts") as err:
        _user_registry(monkeypatch, tmp_path, starts)
    assert problem in str(err.value)
    assert "mytasks.toml" in str(err.value)


def test_unknown_task_name_lists_known_tasks():
    with pytest.raises(UnknownTaskError) as err:
        get_task("nope")
    message = str(err.value)
    assert "'nope'" in message
    for known in ("pick_nut_m12", "insert_peg_rect", "pickplace2_nuts"):
        assert known in message
    assert isinstance(err.value, KeyError)  # dict-like lookups can catch it as a KeyError


def test_a_mistyped_task_name_gets_the_near_ones_not_the_whole_catalogue():
    with pytest.raises(UnknownTaskError) as err:
        get_task("pick_nut_m21")
    message = str(err.value)
    assert "did you mean" in message and "'pick_nut_m12'" in message
    assert "insert_peg_rect" not in message and len(message) < 200


# ---------------------------------------------------------------------- predicates
def context(n: int = 3, **values) -> dict[str, np.ndarray]:
    """A hand-built context of ``n`` environments with two object slots, all zero by default."""
    ctx = {
        "ee_pos": np.zeros((n, 3)),
        "obj_to_ee": np.full((n, 2, 3), 0.5),
        "grasped": np.zeros((n, 2)),
        "engaged": np.zeros((n, 2)),
        "obj_bottom_z": np.zeros((n, 2)),
        "obj_height": np.full((n, 2), 0.01),
        "obj_tilt": np.zeros((n, 2)),
        "obj_to_fix": np.full((n, 2, 3), 0.5),
        "grip_closed": np.zeros(n),
    }
    ctx.update({k: np.asarray(v, dtype=float) for k, v in values.items()})
    return ctx


def test_expression_evaluates_per_environment():
    expr = parse("engaged(0) and not grasped(0)")
    ctx = context(
        engaged=[[1, 0], [1, 1], [0, 1]],
        grasped=[[0, 0], [1, 0], [0, 0]],
    )
    np.testing.assert_array_equal(expr(ctx), [True, False, False])
    # Slot 1 is read from its own column.
    np.testing.assert_array_equal(parse("engaged(1)")(ctx), [False, True, True])
    assert expr.objects == {0}


def test_predicate_arguments_are_passed_on():
    ctx = context(obj_bottom_z=[[0.02, 0], [0.035, 0], [0.05, 0]])  # part height 1 cm
    np.testing.assert_array_equal(parse("lifted(0, 3)")(ctx), [False, True, True])
    np.testing.assert_array_equal(parse("lifted(0, 4)")(ctx), [False, False, True])
    np.testing.assert_array_equal(parse("not lifted(0, 4)")(ctx), [True, True, False])


def test_unknown_predicate_lists_known_ones():
    with pytest.raises(PredicateError) as err:
        parse("flying(0)")
    message = str(err.value)
    assert "flying" in message
    for name in PREDICATES:
        assert name in message


@pytest.mark.parametrize(
    "text", ["grasped", "grasped()", "grasped(x)", "engaged(0) or near(0)", "seated(0)"]
)
def test_malformed_expression_is_a_predicate_error(text):
    with pytest.raises(PredicateError):
        parse(text)


def test_terms_may_be_joined_across_lines():
    # A multi-line TOML string breaks the line at "and"; "not" took any whitespace already.
    assert parse("grasped(0) and\n  not\tupright(0)").terms == (
        (False, "grasped", (0.0,)),
        (True, "upright", (0.0,)),
    )


# ---------------------------------------------------------------------- stages
def test_stage_index_is_one_past_the_furthest_done_stage():
    task = get_task("pickplace_nut_m12")
    names = [s.name for s in task.stages]
    assert names == ["approach", "grasp", "lift", "approach", "place"]
    near_nut = np.zeros(3)  # grip point on the nut
    far = np.full(3, 0.5)
    ctx = context(
        4,
        obj_to_ee=[[near_nut, far], [near_nut, far], [far, far], [far, far]],
        grasped=[[0, 0], [1, 0], [1, 0], [0, 0]],
        obj_bottom_z=[[0, 0], [0, 0], [0.05, 0], [0, 0]],
        engaged=[[0, 0], [0, 0], [0, 0], [1, 0]],
    )
    # env 0: only near -> stage 1 (grasp); env 1: near and grasped -> 2 (lift);
    # env 2: grasped and lifted, though no longer "near" -> 3 (approach the bolt);
    # env 3: engaged (the last stage) -> clipped to the last stage, 4.
    np.testing.assert_array_equal(task.stage_index(ctx), [1, 2, 3, 4])
    # A nut held tipped on its side is not grasped for the task: env 1 falls back to grasp, env 2
    # (no longer near the nut) to the start.
    ctx["obj_tilt"][:, 0] = np.radians(80)
    np.testing.assert_array_equal(task.stage_index(ctx), [1, 1, 0, 4])
    nothing = context(2)
    np.testing.assert_array_equal(task.stage_index(nothing), [0, 0])


# ---------------------------------------------------------------------- packaged suite
def test_all_packaged_tasks_load(monkeypatch):
    monkeypatch.delenv(spec_module.TASKS_DIR_ENV, raising=False)
    tasks = all_tasks()
    assert len(tasks) == 56
    for name, task in tasks.items():
        assert task.id == name
        assert 1 <= len(task.stages) <= 8, name
        assert task.command and task.max_steps > 0
        assert 1 <= len(task.objects) <= 2
    table_i = {name for name, task in tasks.items() if task.table_i}
    for nut in ("nut_m12", "nut_m16"):
        for skill in ("pick", "place", "screw", "pickplace", "pickplacescrew"):
            assert f"{skill}_{nut}" in table_i
    for peg in ("peg_round", "peg_rect"):
        assert f"insert_{peg}" in table_i
        assert f"pickplaceinsert_{peg}" in table_i
    assert "pickplace2_nuts" in table_i
    assert "reach_nut_m12" not in table_i


INSERT_STARTS = """\
task = "insert_peg_round"
[[start]]
name = "2.6 mm off the axis"
objects = [{ x = 0.5526 }]
[[start]]
name = "higher, hand turned"
ee = { yaw = 0.3 }
objects = [{ z = [0.065, 0.07] }]
"""


def test_a_starts_file_changes_only_what_it_names(tmp_path):
    insert = get_task("insert_peg_round")
    path = tmp_path / "starts.toml"
    path.write_text(INSERT_STARTS)
    (off_name, off), (high_name, high) = spec_module.load_starts(path, insert)
    assert (off_name, high_name) == ("2.6 mm off the axis", "higher, hand turned")
    peg, own = off.init.objects[0], insert.init.objects[0]
    assert (peg.x.low, peg.x.high) == (0.5526, 0.5526)
    assert (peg.mode, peg.y, peg.z, peg.hold) == (own.mode, own.y, own.z, own.hold)
    assert off.init.ee_yaw == insert.init.ee_yaw
    assert (high.init.ee_yaw.low, high.init.objects[0].z.low) == (0.3, 0.065)
    assert (off.id, off.stages, off.success) == (insert.id, insert.stages, insert.success)

    env = make_batch_env(off, num_envs=4, seed=0)
    try:
        env.reset()
        grip = env.context()["ee_pos"]  # the peg starts in the fingers, 2.6 mm off the hole
    finally:
        env.close()
    np.testing.assert_allclose(grip[:, 0], 0.5526, atol=1e-3)


def test_a_start_that_changes_the_hold_keeps_the_symmetric_yaw(tmp_path):
    # place_nut_m12's nut is turned by its symmetries; a starts file or a training start that
    # names other fields of it leaves that as the task has it.
    place = get_task("place_nut_m12")
    path = tmp_path / "starts.toml"
    path.write_text('[[start]]\nname = "deep"\nobjects = [{ hold = -0.01 }]\n')
    ((_, deep),) = spec_module.load_starts(path, place)
    assert place.init.objects[0].symmetric_yaw and deep.init.objects[0].symmetric_yaw
    assert all(start.init.objects[0].symmetric_yaw for start in place.training_starts)
    # A training start named after place takes its start, turn included.
    carry = get_task("carry_nut_m12")
    assert not carry.init.objects[0].symmetric_yaw
    assert [s.init.objects[0].symmetric_yaw for s in carry.training_starts] == [True]


def test_a_start_keeps_the_hole_a_held_peg_starts_in(tmp_path, parts):
    # The peg is held with its bottom in the second of two holes, turned as that hole is: a
    # start that changed the hand's yaw alone lost that hole, so its check was made against the
    # first one and a peg turned off the bore was let through.
    text = """
[[task]]
id = "extract_from_the_second_hole"
family = "peghole"
command = "Lift the held rectangular peg out of the second hole"
skills = ["Remove"]
actions = ["lift"]
objects = ["peg_rect_16mm"]
fixtures = [{ part = "hole_rect_16mm", xy = [0.45, -0.10] },
            { part = "hole_rect_16mm", xy = [0.55, 0.12], yaw = 0.6 }]
object_fixture = [0]
max_steps = 30
success = "removed(0, 0.02) and grasped(0)"
stages = [{ name = "lift", done = "removed(0, 0.02) and grasped(0)" }]
[task.init]
ee = { yaw = [0.57, 0.63] }
objects = [{ mode = "gripper", fixture = 1, x = 0.55, y = 0.12, z = [0.034, 0.038] }]
"""
    (spec,) = load_task_file(write(tmp_path, text), parts)
    assert spec.init.objects[0].fixture == 1
    path = tmp_path / "starts.toml"
    path.write_text('[[start]]\nname = "turned off"\nee = { yaw = [-0.03, 0.03] }\n')
    with pytest.raises(TaskFileError, match="wider than its bore"):
        spec_module.load_starts(path, spec)
    path.write_text('[[start]]\nname = "higher"\nobjects = [{ z = [0.036, 0.038] }]\n')
    ((_, higher),) = spec_module.load_starts(path, spec)
    assert higher.init.objects[0].fixture == 1


@pytest.mark.parametrize(
    ("text", "field", "problem"),
    [
        ('task = "pick_nut_m12"\n[[start]]\nname = "a"\n', "task", "not 'insert_peg_round'"),
        ('[[start]]\nname = "a"\nobjects = [{ x = "far" }]\n', "objects[0].x", "expected"),
        ('[[start]]\nname = "a"\nobjects = [{}, {}]\n', "objects", r"has 1 object\(s\)"),
        ('[[start]]\nname = "a"\nspeed = 2\n', "speed", "unknown field"),
        ('[[start]]\nname = "a"\nee = { yaw = [nan, 0.1] }\n', "ee.yaw", r"got \[nan, 0.1\]"),
        ("[[start]]\nobjects = []\n", "name", "missing"),
        ('task = "insert_peg_round"\n', "start", "one or more"),
    ],
)
def test_a_malformed_starts_file_names_the_field(tmp_path, text, field, problem):
    path = tmp_path / "starts.toml"
    path.write_text(text)
    with pytest.raises(TaskFileError, match=problem) as err:
        spec_module.load_starts(path, get_task("insert_peg_round"))
    assert field in str(err.value) and "starts.toml" in str(err.value)


# ---------------------------------------------------------------------- what a user may write
# Each group below was accepted (or failed with a traceback, or blamed the wrong file or field)
# before the loaders checked it. A case: an edit to VALID, the field the error names, a word of
# the problem.
def _refused(path: Path, load) -> TaskFileError:
    """The error ``load()`` raises, checked to name ``path``."""
    with pytest.raises(TaskFileError) as err:
        load()
    assert err.value.path == str(path) and str(path) in str(err.value)
    return err.value


NAMES = {
    # An experiment wrote its cell directory at runs/<id>: this one outside the run directory.
    "escaping": ('id = "my_pick"', 'id = "../../../escaped"'),
    "a_path": ('id = "my_pick"', 'id = "tasks/my_pick"'),
    "empty": ('id = "my_pick"', 'id = ""'),
    "upper_case": ('id = "my_pick"', 'id = "My_Pick"'),
    "spaces": ('id = "my_pick"', 'id = "my pick"'),
    "too_long": ('id = "my_pick"', f'id = "{"a" * 65}"'),
}


@pytest.mark.parametrize("case", list(NAMES))
def test_a_task_id_must_be_a_plain_name(tmp_path, parts, case):
    old, new = NAMES[case]
    path = write(tmp_path, VALID.replace(old, new, 1))
    err = _refused(path, lambda: load_task_file(path, parts))
    assert err.where == "task[0].id"
    assert "lower-case letters, digits and underscores" in err.problem


def test_a_part_name_must_be_a_plain_name(tmp_path):
    path = tmp_path / "parts.toml"
    path.write_text(NUT.replace("[nut.my_nut]", '[nut."../my nut"]'))
    err = _refused(path, lambda: load_parts(path))
    assert err.where == "nut" and "'../my nut'" in err.problem


BOLT = "[bolt.my_bolt]\nthread_diameter = 0.012\npitch = 0.00175\nshank_length = 0.005\n"
PEG = '[peg.my_peg]\nshape = "round"\ndiameter = 0.004\nlength = 0.05\n'
HOLE = '[hole.my_hole]\nshape = "round"\ndiameter = 0.004\nclearance = 0.0005\nhole_depth = 0.02\n'
# (the valid table, an edit to it, the field named, a word of the problem)
BAD_PARTS = {
    "string_height": (NUT, ("height = 0.01", 'height = "0.0108"'), "height", "expected a number"),
    "string_thread": (
        NUT,
        ("thread_diameter = 0.012", 'thread_diameter = "M12"'),
        "thread_diameter",
        "expected a number",
    ),
    "bool_height": (NUT, ("height = 0.01", "height = true"), "height", "got bool"),
    "huge_height": (NUT, ("height = 0.01", "height = 1e300"), "height", "0 < height < 0.5"),
    "negative_clearance": (
        NUT,
        ("pitch = 0.00175", "pitch = 0.00175\nbore_clearance = -0.01"),
        "bore_clearance",
        "0 < bore_clearance",
    ),
    "thin_wall": (NUT, ("across_flats = 0.02", "across_flats = 0.014"), "across_flats", "wall"),
    "colour_above_one": (
        NUT,
        ("pitch = 0.00175", "pitch = 0.00175\nrgba = [2, 0, 0, 1]"),
        "rgba",
        "each 0 to 1",
    ),
    "string_head": (
        BOLT,
        ("shank_length = 0.005", 'shank_length = 0.005\nhead_diameter = "big"'),
        "head_diameter",
        "expected a number",
    ),
    "negative_head": (
        BOLT,
        ("shank_length = 0.005", "shank_length = 0.005\nhead_diameter = -0.026"),
        "head_diameter",
        "0 < head_diameter",
    ),
    "negative_thread": (
        BOLT,
        ("thread_diameter = 0.012", "thread_diameter = -0.012"),
        "thread_diameter",
        "0 < thread_diameter",
    ),
    "unknown_shape": (PEG, ('shape = "round"', 'shape = "square"'), "shape", "'square'"),
    "missing_shape": (PEG, ('shape = "round"\n', ""), "shape", "missing"),
    "width_of_a_round_peg": (
        PEG,
        ("length = 0.05", "length = 0.05\nwidth = 0.01"),
        "width",
        "a round part has diameter",
    ),
    "rect_without_depth": (
        PEG,
        ('shape = "round"\ndiameter = 0.004', 'shape = "rect"\nwidth = 0.016'),
        "depth",
        "0 < depth",
    ),
    "two_segments": (
        HOLE,
        ("hole_depth = 0.02", "hole_depth = 0.02\nsegments = 2"),
        "segments",
        "from 3 to",
    ),
    "fractional_segments": (
        HOLE,
        ("hole_depth = 0.02", "hole_depth = 0.02\nsegments = 12.5"),
        "segments",
        "expected an integer",
    ),
}


@pytest.mark.parametrize("case", list(BAD_PARTS))
def test_a_bad_part_field_names_the_file_and_the_field(tmp_path, case):
    table, (old, new), field, problem = BAD_PARTS[case]
    assert old in table
    path = tmp_path / "parts.toml"
    path.write_text(table.replace(old, new, 1))
    err = _refused(path, lambda: load_parts(path))
    kind, name = table.split("]")[0].strip("[").split(".")
    assert err.where == f"{kind}.{name}.{field}"
    assert problem in err.problem
    path.write_text(table)
    assert name in load_parts(path)  # the unedited table loads


def test_a_user_part_cannot_redefine_a_packaged_one(monkeypatch, tmp_path):
    # It silently replaced nut_m12 in every packaged task, and a bad one was blamed on
    # nutbolt.toml, while a repeated task id was already refused.
    path = tmp_path / "parts.toml"
    path.write_text(NUT.replace("my_nut", "nut_m12"))
    monkeypatch.setenv(spec_module.TASKS_DIR_ENV, str(tmp_path))
    spec_module._registry.cache_clear()
    try:
        err = _refused(path, all_tasks)
    finally:
        spec_module._registry.cache_clear()
    assert err.where == "nut.nut_m12" and str(PARTS_FILE) in err.problem


BAD_PREDICATES = {
    "nan": ("near(0, nan)", "dist must be a finite number, got nan"),
    "inf": ("near(0, 1e999)", "dist must be a finite number, got inf"),
    "negative_angle": ("upright(0, -5)", "degrees must be 0 or more"),
    "fractional_slot": ("near(0.9, 0.015)", "object slot must be a whole number"),
    "negative_slot": ("grasped(-1)", "object slot must be a whole number"),
    "nan_slot": ("grasped(nan)", "i must be a finite number"),
    # Deeper than the hole: loaded as a success no episode could reach.
    "fraction_past_the_hole": ("inserted(0, 1.5)", "fraction must be at most 1, got 1.5"),
}


@pytest.mark.parametrize("case", list(BAD_PREDICATES))
def test_a_predicate_argument_must_be_finite_a_slot_whole_and_a_threshold_not_negative(
    tmp_path, parts, case
):
    text, problem = BAD_PREDICATES[case]
    with pytest.raises(PredicateError, match=problem):
        parse(text)
    path = write(tmp_path, VALID.replace('done = "grasped(0)"', f'done = "{text}"', 1))
    err = _refused(path, lambda: load_task_file(path, parts))
    assert err.where == "task 'my_pick'.stages[1].done" and problem in err.problem


def test_an_offset_may_be_negative():
    assert parse("displaced(0, 0.0, -0.07, 0.015)").terms[0][2] == (0.0, 0.0, -0.07, 0.015)


BAD_STARTS = {
    "part_far_off": (("x = [0.45, 0.58]", "x = 5.0"), "init.objects[0].x", "workspace in x"),
    "hand_far_off": (("x = [0.4, 0.5]", "x = 1e300"), "init.ee.x", "from 0.25 to 0.75 m"),
    "hand_below_the_table": (("z = [0.15, 0.22]", "z = [-0.1, 0.2]"), "init.ee.z", "in z"),
    "hand_turned_too_far": (
        ("z = [0.15, 0.22] }", "z = [0.15, 0.22], yaw = 4.0 }"),
        "init.ee.yaw",
        "yaw limits",
    ),
    "part_at_the_robot_base": (  # y left out reads 0, x left out 0 too: under the arm's base
        ("x = [0.45, 0.58], y = [-0.14, -0.02]", "y = 0.0"),
        "init.objects[0].x",
        "nothing (0 by default)",
    ),
    "part_yaw": (("y = [-0.14, -0.02] }", "y = [-0.14, -0.02], yaw = 1e300 }"), "[0].yaw", "turn"),
    "unused_field": (
        ("y = [-0.14, -0.02] }", "y = [-0.14, -0.02], z = 0.3 }"),
        "init.objects[0].z",
        "does not use z",
    ),
    "fixture_off_the_table": (("xy = [0.55, 0.12]", "xy = [5.0, 0.12]"), "fixtures[0].xy", "x"),
    "too_many_turns": (
        (
            '{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }',
            '{ mode = "bolt", turns = 9 }',
        ),
        "init.objects[0].turns",
        "bolt_m12's thread",
    ),
    "fixture_index": (
        ("y = [-0.14, -0.02] }", "y = [-0.14, -0.02], fixture = 3 }"),
        "init.objects[0].fixture",
        "1 fixture(s)",
    ),
}


@pytest.mark.parametrize("case", list(BAD_STARTS))
def test_a_start_outside_what_the_scene_has_names_the_field(tmp_path, parts, case):
    # x = 5 or 1e300 loaded; the simulation went unstable and 0% success read as measured.
    (old, new), field, problem = BAD_STARTS[case]
    assert old in VALID
    path = write(tmp_path, VALID.replace(old, new, 1))
    err = _refused(path, lambda: load_task_file(path, parts))
    assert field in err.where and problem in err.problem


@pytest.mark.parametrize(
    ("text", "field", "problem"),
    [
        ('[[start]]\nname = "a"\nobjects = [{ x = 5.0 }]\n', "objects[0].x", "workspace"),
        ('[[start]]\nname = "a"\nee = { z = 1e300 }\n', "ee.z", "workspace"),
        # The hand starts where the held peg is: the loader read this and it changed nothing.
        ('[[start]]\nname = "a"\nee = { x = 0.5 }\n', "ee.x", "at the held part's x, y and z"),
        ('[[start]]\nname = "a"\nobjects = [{ yaw = 0.1 }]\n', "objects[0].yaw", "does not use"),
        ('[[start]]\nname = ""\n', "start[0].name", "expected some text"),
        ('[[start]]\nname = "a"\n[[start]]\nname = "a"\n', "start[1].name", "earlier start"),
    ],
)
def test_a_starts_file_start_must_be_in_reach_and_named_once(tmp_path, text, field, problem):
    path = tmp_path / "starts.toml"
    path.write_text(text)
    err = _refused(path, lambda: spec_module.load_starts(path, get_task("insert_peg_round")))
    assert field in err.where and problem in err.problem


BAD_TASK_FIELDS = {
    "unknown_kind": (('kind = "basic"', 'kind = "weird"'), "kind", "'basic', 'complex'"),
    "empty_command": (
        ('command = "Pick up the M12 nut"', 'command = "  "'),
        "command",
        "expected some text",
    ),
    "no_actions": (('actions = ["approach", "grasp"]', "actions = []"), "actions", "one or more"),
    "empty_action": (
        ('actions = ["approach", "grasp"]', 'actions = ["approach", ""]'),
        "actions",
        "one or more action names",
    ),
    "stage_not_an_action": (
        ('actions = ["approach", "grasp"]', 'actions = ["fly"]'),
        "stages[0].name",
        "not one of the task's actions",
    ),
    "stages_out_of_order": (
        ('actions = ["approach", "grasp"]', 'actions = ["grasp", "approach"]'),
        "stages[1].name",
        "out of order",
    ),
    "empty_stage_name": (
        ('{ name = "grasp"', '{ name = ""'),
        "stages[1].name",
        "expected some text",
    ),
}


@pytest.mark.parametrize("case", list(BAD_TASK_FIELDS))
def test_a_task_kind_command_and_actions_are_checked(tmp_path, parts, case):
    (old, new), field, problem = BAD_TASK_FIELDS[case]
    assert old in VALID
    path = write(tmp_path, VALID.replace(old, new, 1))
    err = _refused(path, lambda: load_task_file(path, parts))
    assert err.where == f"task 'my_pick'.{field}" and problem in err.problem


def test_actions_without_a_stage_and_carry_stages_still_load(tmp_path, parts):
    # What the packaged tasks do: removenut's grasp has no stage, pickplace2_nuts carries.
    text = VALID.replace(
        'actions = ["approach", "grasp"]', 'actions = ["approach", "lift", "grasp"]'
    )
    text = text.replace('{ name = "approach"', '{ name = "carry"')
    (task,) = load_task_file(write(tmp_path, text), parts)
    assert [s.name for s in task.stages] == ["carry", "grasp"]


def test_two_parts_that_can_start_in_one_place_are_refused(tmp_path, parts):
    text = (
        VALID.replace('objects = ["nut_m12"]', 'objects = ["nut_m12", "nut_m16"]')
        .replace(
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]',
            'fixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }, '
            '{ part = "bolt_m16", xy = [0.55, -0.25] }]',
        )
        .replace(
            '  { mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] },\n',
            '  { mode = "table", x = [0.45, 0.5], y = [-0.14, -0.02] },\n'
            '  { mode = "table", x = [0.52, 0.58], y = [-0.1, -0.02] },\n',
        )
    )
    with pytest.raises(TaskFileError, match=r"objects\[1\].*nut_m16 can start inside nut_m12"):
        load_task_file(write(tmp_path, text), parts)
    load_task_file(write(tmp_path, text.replace("x = [0.52, 0.58]", "x = [0.54, 0.58]")), parts)


def test_a_rectangular_peg_in_its_hole_starts_only_at_yaws_it_fits(tmp_path):
    # Turned 90 degrees it started 2.25 mm inside the hole's walls and read as engaged; turned
    # 0.5 rad the walls snapped it back to another yaw than the one asked for.
    path = tmp_path / "starts.toml"
    spec = get_task("grasp_peg_rect_hole")
    path.write_text('[[start]]\nname = "a"\nobjects = [{ yaw = [-0.05, 0.05] }]\n')
    spec_module.load_starts(path, spec)  # a few degrees: inside the clearance
    path.write_text('[[start]]\nname = "a"\nobjects = [{ yaw = [0.0, 1.5708] }]\n')
    err = _refused(path, lambda: spec_module.load_starts(path, spec))
    assert "objects[0].yaw" in err.where and "wider than its bore" in err.problem
    # Held in the hole by the closed fingers, the peg is turned as the hand is.
    path.write_text('[[start]]\nname = "a"\nee = { yaw = [1.2, 1.5] }\n')
    err = _refused(path, lambda: spec_module.load_starts(path, get_task("extract_peg_rect")))
    assert "ee.yaw" in err.where and "wider than its bore" in err.problem


def test_a_start_that_puts_the_part_in_the_hand_drops_the_tasks_own_hand_position(tmp_path):
    # pick_nut_m12's start sets the hand's x, y and z; a start holding the nut instead was
    # refused for an ee position it never wrote.
    path = tmp_path / "starts.toml"
    path.write_text(
        '[[start]]\nname = "held"\n'
        'objects = [{ mode = "gripper", x = [0.5, 0.5], y = [0.0, 0.0], z = [0.1, 0.1] }]\n'
    )
    ((_, held),) = spec_module.load_starts(path, get_task("pick_nut_m12"))
    assert held.init.objects[0].mode == "gripper"


def test_a_peg_in_a_turned_hole_is_checked_against_the_hole_not_the_table(tmp_path, parts):
    # A start's yaw in a hole is measured from the hole: aligned with a hole turned 90 degrees
    # it was refused, and turned into the walls it was let through.
    head = (
        '[[task]]\nid = "turned_hole"\nfamily = "peghole"\nkind = "basic"\n'
        'command = "Grasp the peg in the turned hole"\nskills = ["Grasp"]\n'
        'actions = ["grasp"]\nobjects = ["peg_rect_16mm"]\n'
        'fixtures = [{ part = "hole_rect_16mm", xy = [0.55, 0.12], yaw = 1.5708 }]\n'
        'max_steps = 20\nsuccess = "grasped(0)"\n'
        'stages = [{ name = "grasp", done = "grasped(0)" }]\n'
    )
    start = '[task.init]\nobjects = [{ mode = "hole", depth = [0.01, 0.01], yaw = YAW }]\n'
    load_task_file(write(tmp_path, head + start.replace("YAW", "0.0")), parts)
    with pytest.raises(TaskFileError, match="wider than its bore"):
        load_task_file(write(tmp_path, head + start.replace("YAW", "1.5708")), parts)


def test_a_tasks_fingerprint_follows_what_its_episodes_are_not_how_they_are_written() -> None:
    spec = get_task("pickplaceinsert_peg_rect")
    # Pinned: a field added to a spec with a default, or a refactoring, must not refuse every
    # recorded run's resume and held-out measurement as if its task had changed.
    assert spec.fingerprint == "384da51e10e62d3f835986de447db04dbc72ae0484b226405be81722f85a4c20"
    place = spec.stages[4]
    respaced = dataclasses.replace(
        place, done=parse(place.done.source.replace(", ", ",").replace(" and ", "  and "))
    )
    defaults = dataclasses.replace(
        spec.stages[5], done=parse("inserted(0, 0.5, 0.1)")
    )  # yaw_tol written out
    same = [
        dataclasses.replace(spec, stages=(*spec.stages[:4], respaced, defaults)),
        dataclasses.replace(
            spec, objects=(dataclasses.replace(spec.objects[0], rgba=(1.0, 0.0, 0.0, 1.0)),)
        ),
        dataclasses.replace(spec, command="Put the green peg in", tags=("mine",)),
    ]
    assert {s.fingerprint for s in same} == {spec.fingerprint}
    deeper = dataclasses.replace(spec.stages[5], done=parse("inserted(0, 0.6)"))
    other = [
        dataclasses.replace(spec, stages=(*spec.stages[:5], deeper)),
        dataclasses.replace(spec, max_steps=spec.max_steps + 1),
        dataclasses.replace(spec, init=dataclasses.replace(spec.init, ee_yaw=Range(0.0, 0.1))),
    ]
    assert spec.fingerprint not in {s.fingerprint for s in other}
