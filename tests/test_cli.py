import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from itskill.cli import app
from itskill.sim import GL_BACKEND
from itskill.tasks import all_tasks, get_task
from itskill.tasks.spec import TASKS_DIR_ENV

runner = CliRunner()


def flat(text: str) -> str:
    """Output with line wrapping undone, so assertions do not depend on terminal width."""
    return " ".join(text.split())


def unspaced(text: str) -> str:
    """Text without any whitespace: rich folds a long path anywhere, even inside a name."""
    return "".join(text.split())


def test_tasks_list_json_has_every_task():
    result = runner.invoke(app, ["tasks", "list", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert [t["id"] for t in data] == list(all_tasks())
    assert {"pick_nut_m12", "insert_peg_rect"} <= {t["id"] for t in data if t["table_i"]}


def test_tasks_list_table_and_markdown():
    table = runner.invoke(app, ["tasks", "list"])
    assert table.exit_code == 0
    assert "pick_nut_m12" in table.stdout
    markdown = runner.invoke(app, ["tasks", "list", "--markdown"])
    lines = markdown.stdout.strip().splitlines()
    assert lines[0].startswith("| id |")
    assert len(lines) == 2 + len(all_tasks())


def test_tasks_list_refuses_json_and_markdown_together():
    # It printed JSON, silently ignoring --markdown.
    result = runner.invoke(app, ["tasks", "list", "--json", "--markdown"])
    assert result.exit_code == 2 and result.stdout == ""
    assert "give --json or --markdown, not both" in flat(result.output)


def test_tasks_show_json_is_complete():
    result = runner.invoke(app, ["tasks", "show", "screw_nut_m12", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["command"] == "Screw the M12 nut onto the bottom of the bolt"
    assert data["objects"][0]["pitch"] == pytest.approx(0.00175)
    assert data["fixtures"][0]["part"]["kind"] == "bolt"
    # Only what the bolt mode reads: where on the thread the nut starts, on which bolt.
    assert data["init"]["objects"][0] == {"mode": "bolt", "fixture": 0, "turns": [1.5, 2.5]}
    assert data["success"] == "seated(0, 0.00175)"
    assert data["max_steps"] > 0 and data["stages"] and data["script"]


def test_tasks_show_json_reports_holds_and_written_out_training_starts():
    result = runner.invoke(app, ["tasks", "show", "place_nut_m12", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["init"]["objects"][0]["hold"] == pytest.approx([-0.011, 0.003])
    (start,) = data["training_starts"]
    assert "task" not in start and start["share"] == pytest.approx(0.3)
    assert start["init"]["objects"][0]["hold"] == pytest.approx([-0.011, -0.008])


def test_tasks_show_table():
    result = runner.invoke(app, ["tasks", "show", "pick_nut_m12"])
    assert result.exit_code == 0
    text = flat(result.stdout)
    assert "Pick up the M12 nut" in text and "lifted(0, 3)" in text
    assert "15% from lift_nut_m12's start" in text


@pytest.mark.parametrize(
    "args",
    [
        ["tasks", "show", "pick_the_moon"],
        ["eval", "pick_the_moon", "--episodes", "1"],
        ["render", "pick_the_moon", "--out", "x.mp4"],
    ],
)
def test_unknown_task_lists_known_ones(args):
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    text = flat(result.output)
    assert "unknown task 'pick_the_moon'" in text
    assert "pick_nut_m12" in text and "insert_peg_round" in text
    assert "Traceback" not in text


def test_malformed_task_file_names_file_and_field(tmp_path, monkeypatch):
    bad = tmp_path / "broken.toml"
    bad.write_text('[[task]]\nid = "broken"\nfamily = "nutbolt"\nmax_stepz = 10\n')
    monkeypatch.setenv(TASKS_DIR_ENV, str(tmp_path))
    result = runner.invoke(app, ["tasks", "list"])
    assert result.exit_code == 2
    text = flat(result.output)
    assert str(bad) in text
    assert "task 'broken'.max_stepz" in text and "unknown field" in text
    assert "Traceback" not in text


def my_pick_task(command: str) -> str:
    """A task file of one task, my_pick, without a script, commanded by ``command``."""
    return (
        '[[task]]\nid = "my_pick"\nfamily = "nutbolt"\nkind = "basic"\n'
        f'command = "{command}"\nskills = ["Pick"]\nactions = ["approach", "grasp"]\n'
        'objects = ["nut_m12"]\nfixtures = [{ part = "bolt_m12", xy = [0.55, 0.12] }]\n'
        'max_steps = 60\nsuccess = "grasped(0)"\n'
        'stages = [{ name = "approach", done = "near(0, 0.02)" }]\n'
        "[task.init]\nee = { x = [0.4, 0.5], y = [-0.08, 0.08], z = [0.15, 0.22] }\n"
        'objects = [{ mode = "table", x = [0.45, 0.58], y = [-0.14, -0.02] }]\n'
    )


def test_a_task_file_s_text_is_shown_as_written(tmp_path, monkeypatch):
    # Rich read it as markup: "[b]" vanished from the command, "[/b]" ended in a traceback.
    (tmp_path / "mine.toml").write_text(my_pick_task("Pick up the [b]M12[/b] nut"))
    monkeypatch.setenv(TASKS_DIR_ENV, str(tmp_path))
    for args in (["tasks", "show", "my_pick"], ["tasks", "list"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        assert "[b]M12[/b]" in unspaced(result.output)


def test_scripted_eval_of_a_task_without_a_script_is_a_clear_error(tmp_path, monkeypatch):
    (tmp_path / "mine.toml").write_text(my_pick_task("Pick up the M12 nut"))
    monkeypatch.setenv(TASKS_DIR_ENV, str(tmp_path))
    result = runner.invoke(app, ["eval", "my_pick", "--episodes", "2"])
    assert result.exit_code == 2
    assert "task 'my_pick' has no script" in flat(result.output)


def test_eval_missing_checkpoint_is_a_clear_error(tmp_path):
    missing = tmp_path / "nothing_here.zip"
    result = runner.invoke(app, ["eval", "pick_nut_m12", "--policy", str(missing)])
    assert result.exit_code == 2
    text = flat(result.output)
    assert str(missing) in text and "no such file or directory (expected" in text
    assert "a training run directory, skill:NAME" in text


def test_eval_corrupt_checkpoint_is_a_clear_error(tmp_path):
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"not a zip archive")
    result = runner.invoke(app, ["eval", "pick_nut_m12", "--policy", str(corrupt)])
    assert result.exit_code == 2
    assert str(corrupt) in flat(result.output)


def test_eval_takes_a_skill_of_the_skill_space_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    args = ["eval", "reach_nut_m12", "--policy", "skill:reach_nut_m12", "--episodes", "4"]
    result = runner.invoke(app, [*args, "--num-envs", "4", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["episodes"] == 4 and data["successes"] >= 3  # shipped at 99.8%
    assert "reach_nut_m12" in data["policy"]
    # The line names the skill as typed, then where it loaded from (only the path, before).
    shown = runner.invoke(app, [*args, "--num-envs", "4"])
    assert flat(shown.output).startswith(
        f"reach_nut_m12 with skill:reach_nut_m12 ({data['policy']})"
    )
    unknown = runner.invoke(app, ["eval", "reach_nut_m12", "--policy", "skill:reach_nut_m13"])
    assert unknown.exit_code == 2
    text = flat(unknown.output)
    assert "unknown skill 'reach_nut_m13'" in text and "reach_nut_m12" in text
    # A skill whose Stable-Baselines3 .zip is loaded as that file, not its directory; damaged
    # after it was added (`skills add` refuses a file that does not load).
    from itskill.skills import open_skill_space
    from itskill.skills.store import Skill

    corrupt = tmp_path / "my_reach.zip"
    corrupt.write_bytes(b"not a zip archive")
    add = ["skills", "add", "--task", "reach_nut_m12", "--name", "my_reach"]
    refused = runner.invoke(app, [*add, "--checkpoint", str(corrupt)])
    assert refused.exit_code == 2 and "not a Stable-Baselines3 checkpoint" in flat(refused.output)
    with open_skill_space() as space:
        space.add(Skill("my_reach", "reach_nut_m12", "reach", ("approach",), str(corrupt)))
    zipped = runner.invoke(app, ["eval", "reach_nut_m12", "--policy", "skill:my_reach"])
    assert zipped.exit_code == 2
    assert "not a Stable-Baselines3 checkpoint" in flat(zipped.output)


def test_eval_takes_a_checkpoint_file_as_the_skill_space_lists_it(tmp_path, monkeypatch):
    # `skills show` gives RUN/policy.safetensors as a skill's checkpoint; --policy refused it
    # as "not a Stable-Baselines3 checkpoint (not a zip archive)".
    from itskill.skills.store import SHIPPED_LIBRARY

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    run = tmp_path / "run"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", run)
    args = ["eval", "reach_nut_m12", "--policy", str(run / "policy.safetensors"),
            "--episodes", "2", "--num-envs", "2", "--json"]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["successes"] >= 1  # shipped at 99.8%


def test_eval_of_a_skill_whose_checkpoint_was_deleted_says_so(tmp_path, monkeypatch):
    from itskill.skills import open_skill_space
    from itskill.skills.store import SHIPPED_LIBRARY, Skill

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    run = tmp_path / "r2"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", run)
    with open_skill_space() as space:
        checkpoint = str(run / "policy.safetensors")
        space.add(Skill("r2", "reach_nut_m12", "reach", ("approach",), checkpoint))
    shutil.rmtree(run)
    result = runner.invoke(app, ["eval", "reach_nut_m12", "--policy", "skill:r2"])
    assert result.exit_code == 2
    assert f"skill:r2: the checkpoint of skill 'r2' is missing: no file {checkpoint}" in flat(
        result.output
    )


def test_an_empty_policy_is_a_usage_error_not_the_current_directory(tmp_path, monkeypatch):
    # Read as ".", it failed on "checkpoint.json: missing" (a variable that expanded to nothing).
    monkeypatch.chdir(tmp_path)
    for args in (["eval", "reach_nut_m12"], ["render", "reach_nut_m12", "--out", "v.mp4"]):
        result = runner.invoke(app, [*args, "--policy", ""])
        assert result.exit_code == 2, result.output
        assert "a policy is required" in flat(result.output)
        assert "checkpoint.json" not in result.output


def test_scripted_names_the_controller_even_beside_a_folder_of_that_name(tmp_path, monkeypatch):
    # The folder was taken for a training run: "scripted/checkpoint.json: missing".
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scripted").mkdir()
    result = runner.invoke(app, ["eval", "reach_nut_m12", "--episodes", "1", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["policy"] == "scripted"


def test_the_commands_name_the_scripted_controller_as_the_evaluators_do():
    """The commands keep their own copy of the name, so that they load PyTorch only to run."""
    from itskill.cli.common import SCRIPTED
    from itskill.tasks.evaluate import SCRIPTED as EVALUATORS

    assert SCRIPTED == EVALUATORS


def test_eval_scripted_json():
    args = ["eval", "reach_nut_m12", "--episodes", "3", "--num-envs", "2", "--json"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["episodes"] == 3 and data["policy"] == "scripted"
    assert 0.0 <= data["ci_low"] <= data["success_rate"] <= data["ci_high"] <= 1.0
    assert sum(data["stage_steps"]) == pytest.approx(data["mean_length"])
    text = runner.invoke(app, args[:-1])
    stage = get_task("reach_nut_m12").stages[0].name
    assert f"steps per episode in each subtask: 0.{stage} " in text.stdout


@pytest.mark.skipif(GL_BACKEND is None, reason="no EGL or OSMesa library installed")
def test_render_writes_a_video(tmp_path):
    out = tmp_path / "reach.mp4"
    result = runner.invoke(app, ["render", "reach_nut_m12", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 1000


def test_eval_from_other_starts_finds_where_a_skill_stops_working(tmp_path):
    # The shipped insert skill was trained with the peg within 1 mm of the hole's axis.
    import itskill.skills

    skill = Path(itskill.skills.__file__).parent / "library" / "insert_peg_round"
    starts = tmp_path / "starts.toml"
    starts.write_text('[[start]]\nname = "3.5 mm off"\nobjects = [{ x = 0.5535, y = 0.12 }]\n')
    args = ["eval", "insert_peg_round", "--policy", str(skill), "--episodes", "8",
            "--num-envs", "8", "--starts", str(starts)]  # fmt: skip
    result = runner.invoke(app, [*args, "--json"])
    assert result.exit_code == 0, result.output
    own, off = json.loads(result.stdout)
    assert (own["start"], off["start"]) == ("the task's own start", "3.5 mm off")
    assert own["successes"] >= 5 and off["successes"] == 0
    table = runner.invoke(app, args)
    assert "3.5 mm off" in table.stdout and "0/8 = 0%" in table.stdout


def test_a_start_the_arm_cannot_reach_is_refused_by_name(tmp_path):
    # Within the controller's workspace box, but out of the arm's reach: the hand settled
    # wherever the inverse kinematics stopped and the episodes went on from there.
    starts = tmp_path / "starts.toml"
    starts.write_text(
        '[[start]]\nname = "far corner"\n'
        "ee = { x = [0.4, 0.75], y = [-0.35, 0.0], z = [0.15, 0.45] }\n"
    )
    result = runner.invoke(app, ["eval", "reach_nut_m12", "--starts", str(starts)])
    assert result.exit_code == 2, result.output
    assert (
        f"{starts}: start 'far corner': reach_nut_m12's start: the arm cannot reach the "
        "hand position (0.75, -0.35, 0.15) m" in flat(result.output)
    )
    assert "Traceback" not in result.output
    # Refused before the task's own start was evaluated (100 episodes, minutes for some skills).
    assert "the task's own start" not in result.output


@pytest.mark.parametrize(
    ("method", "message"),
    # An unknown method was offered no_transfer, which was then refused: the choices are the
    # methods with sources.
    [("foo", "got 'foo'"), ("no_transfer", "got 'no_transfer'")],
)
def test_reward_search_on_a_network_without_sources_is_refused(tmp_path, method, message):
    out = tmp_path / "run"
    args = ["reward", "generate", "pickplace_nut_m12", "--transfer", method, "--out", str(out)]
    result = runner.invoke(app, args)
    flat = " ".join(result.output.replace("│", "").split())
    assert result.exit_code == 2 and message in flat
    assert "expected one of itn, nia, dfs, pst," in flat and "leave --transfer out" in flat
    assert not (out / "config.json").exists()


def test_reward_search_on_a_network_refuses_another_run_before_building_into_it(tmp_path):
    # The network (its transfer.json, the analyzer's reply cache) was built into the directory
    # before the search found it held another kind of run.
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.json").write_text('{"tasks": ["pick_nut_m12"]}')
    args = ["reward", "generate", "pickplace_nut_m12", "--transfer", "itn", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "holds another kind of run" in flat(result.output)
    assert [p.name for p in out.iterdir()] == ["config.json"]


def test_a_bad_reward_search_flag_is_named(tmp_path):
    # The settings reader called it "overrides": "overrides: executor: expected one of ...".
    out = tmp_path / "run"
    args = ["reward", "generate", "reach_nut_m12", "--executor", "foo", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "Invalid value for --executor: expected one of" in flat(result.output)
    assert "overrides" not in result.output and not out.exists()


def test_sigterm_stops_training_as_ctrl_c_does(tmp_path):
    # A batch scheduler or `kill` sends SIGTERM: it ended the process on the spot and lost the
    # training since the last checkpoint (50k env-steps apart by default).
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    itskill = str(Path(sys.executable).with_name("itskill"))
    proc = subprocess.Popen(
        [itskill, "train", "reach_nut_m12", "--steps", "1000000", "--num-envs", "2",
         "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not (out / "tb").is_dir():  # made as the first update starts
            assert proc.poll() is None and time.monotonic() < deadline, "training did not start"
            time.sleep(0.2)
        time.sleep(2.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    meta = json.loads((out / "checkpoint.json").read_text())
    assert 0 < meta["num_timesteps"] < 50_000  # before the first periodic checkpoint: the stop's


def test_unusable_paths_and_damaged_run_files_are_one_line_errors(tmp_path, monkeypatch):
    # Each ended in a traceback: FileExistsError, or the ValueError of a damaged JSON file.
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    a_file = tmp_path / "afile"
    a_file.write_text("not a directory")
    damaged = tmp_path / "learn_run"
    damaged.mkdir()
    (damaged / "learn.json").write_text('{"command": "pick up the nut", ')
    cases = [
        (["train", "reach_nut_m12", "--steps", "64", "--num-envs", "2", "--out", str(a_file)],
         f"{a_file}: a file, not a directory"),
        (["learn", "pick up the nut", "--out", str(damaged), "--resume"], "not valid JSON"),
        (["render", "pick_nut_m12", "--policy", "scripted", "--out", str(tmp_path / "v.txt")],
         "must be a .mp4 file"),
    ]  # fmt: skip
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        assert message in " ".join(result.output.split()), result.output
        assert "Traceback" not in result.output
    monkeypatch.setenv("ITSKILL_HOME", str(a_file))
    result = runner.invoke(app, ["skills", "list"])
    assert result.exit_code == 2 and f"cannot use {a_file}" in " ".join(result.output.split())


def test_out_of_range_numbers_and_the_current_directory_are_refused_before_any_work(
    tmp_path, monkeypatch
):
    # A negative seed ended in NumPy's traceback, a huge episode count in an OverflowError, and
    # an empty --out wrote the run among the user's files; /proc/x cannot be created.
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    cases = [
        (["eval", "reach_nut_m12", "--seed", "-1"], "--seed"),
        (["train", "reach_nut_m12", "--seed", str(2**32)], "--seed"),
        (["transfer", "train", "pick_nut_m12", "--seed", "-3"], "--seed"),
        (["eval", "reach_nut_m12", "--episodes", "9" * 23], "--episodes"),
        (["eval", "reach_nut_m12", "--num-envs", "5000"], "--num-envs"),
        # A mistyped budget trained on for ever at an undecayed learning rate.
        (["train", "reach_nut_m12", "--steps", "1" + "0" * 12], "--steps"),
        (["transfer", "train", "pick_nut_m12", "--steps", "1" + "0" * 12], "--steps"),
        (["skills", "pretrain", "--tasks", "reach_nut_m12", "--steps", "1" + "0" * 12], "--steps"),
        (["train", "reach_nut_m12", "--algo", "sac"], "expected one of a2c, ppo"),
        (["transfer", "train", "pick_nut_m12", "--algo", "sac"], "expected one of a2c, ppo"),
        (["train", "reach_nut_m12", "--out", ""], "not the current one"),
        (["transfer", "train", "pick_nut_m12", "--out", "."], "not the current one"),
        (["train", "reach_nut_m12", "--steps", "64", "--out", "/proc/x"], "cannot use /proc/x"),
    ]
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert message in flat(result.output), result.output
        assert "Traceback" not in result.output
    assert list(tmp_path.iterdir()) == []  # nothing written, not even the skill space


def test_paths_too_long_to_use_are_one_line_errors_naming_them_cut_short(tmp_path, monkeypatch):
    # OSError: [Errno 36] File name too long, as a traceback.
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    too_long = str(tmp_path / ("a" * 300))
    for args in (
        ["eval", "reach_nut_m12", "--policy", too_long],
        ["train", "reach_nut_m12", "--steps", "64", "--out", too_long],
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert result.output.startswith(f"error: cannot use {too_long[:40]}"), result.output
        assert "characters): File name too long" in result.output
        assert len(result.output.splitlines()) == 1 and "a" * 300 not in result.output


def test_a_skill_number_past_sqlites_integers_is_an_unknown_skill(tmp_path, monkeypatch):
    # OverflowError: Python int too large to convert to SQLite INTEGER, exit 1.
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    result = runner.invoke(app, ["eval", "reach_nut_m12", "--policy", "skill:" + "9" * 20])
    assert result.exit_code == 2, result.output
    assert f"unknown skill '{'9' * 20}'" in result.output


def test_eval_of_a_policy_on_another_task_runs_with_a_note(tmp_path, monkeypatch):
    from itskill.skills.store import SHIPPED_LIBRARY

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    reach = SHIPPED_LIBRARY / "reach_nut_m12"
    args = ["eval", "pick_nut_m12", "--policy", str(reach), "--episodes", "2", "--num-envs", "2"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert f"note: {reach} was trained on reach_nut_m12; evaluated on pick_nut_m12" in flat(
        result.output
    )
    same = runner.invoke(app, ["eval", "reach_nut_m12", *args[2:]])
    assert same.exit_code == 0 and "note:" not in same.output
    # Its checkpoint file, as `itskill skills show` lists it, gets the same note.
    weights = reach / "policy.safetensors"
    by_file = runner.invoke(app, ["eval", "pick_nut_m12", "--policy", str(weights), *args[4:]])
    assert by_file.exit_code == 0, by_file.output
    assert f"note: {weights} was trained on reach_nut_m12" in flat(by_file.output)
    # So does the skill of that checkpoint (it printed no note).
    by_skill = runner.invoke(
        app, ["eval", "pick_nut_m12", "--policy", "skill:reach_nut_m12", *args[4:]]
    )
    assert by_skill.exit_code == 0, by_skill.output
    assert "note: skill:reach_nut_m12 was trained on reach_nut_m12; evaluated on pick_nut_m12" in (
        flat(by_skill.output)
    )


def test_eval_of_a_policy_on_a_changed_version_of_its_task_runs_with_a_note(tmp_path, monkeypatch):
    import shutil

    from itskill.skills.store import SHIPPED_LIBRARY

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    copy = tmp_path / "reach"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", copy)
    meta = json.loads((copy / "checkpoint.json").read_text())
    (copy / "checkpoint.json").write_text(json.dumps({**meta, "task_sha256": "0" * 64}))
    args = ["eval", "reach_nut_m12", "--policy", str(copy), "--episodes", "2", "--num-envs", "2"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "trained on reach_nut_m12 as its task file defined it then" in flat(result.output)


def test_plan_of_a_task_id_needs_no_model_but_refuses_a_mistyped_one(monkeypatch):
    monkeypatch.delenv("ITSKILL_LLM_MODEL", raising=False)
    ok = runner.invoke(app, ["plan", "pick_nut_m12"])
    assert ok.exit_code == 0 and "planned from the task file" in ok.output
    bad = runner.invoke(app, ["plan", "pick_nut_m12", "--llm", "foo"])
    assert bad.exit_code == 2, bad.output  # was planned, the flag ignored
    assert "unknown language model 'foo'" in flat(bad.output)


def test_user_text_is_printed_as_typed_not_as_emoji(tmp_path, monkeypatch):
    # "skill:x:" printed as "skill❌" (rich reads :x: as an emoji code).
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    result = runner.invoke(app, ["eval", "reach_nut_m12", "--policy", "skill:x"])
    assert result.exit_code == 2
    assert "skill:x: unknown skill 'x'" in result.output and "❌" not in result.output


def test_nohup_keeps_a_command_running_past_a_closed_terminal():
    # The command makes SIGTERM and SIGHUP stop it as Ctrl-C does, except a signal it was
    # started with ignored: `nohup` ignores SIGHUP so that the run outlives the terminal.
    import signal

    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGHUP, signal.SIGTERM)}
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        assert runner.invoke(app, ["tasks", "list", "--json"]).exit_code == 0
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is signal.default_int_handler
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def test_file_names_in_error_messages_are_printed_as_typed(tmp_path, monkeypatch):
    # Rich read the brackets as markup: "error: reward.py: ..." named a file that does not exist.
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    reward = tmp_path / "reward[v2].py"
    reward.write_text("x = 1\n")
    hyperparams = tmp_path / "hp[old].toml"
    hyperparams.write_text("foo = [\n")
    out = tmp_path / "run"
    train = ["train", "pick_nut_m12", "--steps", "64", "--num-envs", "2", "--out", str(out)]
    cases = [
        (["--reward", str(reward)], f"error: {reward}: defines no function compute_reward(ctx)"),
        (["--hyperparams", str(hyperparams)], f"error: {hyperparams}: TOML syntax"),
    ]
    for args, message in cases:
        result = runner.invoke(app, [*train, *args])
        assert result.exit_code == 2, result.output
        assert message in flat(result.output)
        assert "Traceback" not in result.output


def test_paths_and_start_names_with_brackets_are_printed_as_typed(tmp_path, monkeypatch):
    # "with run[b]x" printed as "with runx", the start "[red]nudged" lost its name.
    from itskill.skills.store import SHIPPED_LIBRARY

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    policy = tmp_path / "run[b]x"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", policy)
    eval_args = ["eval", "reach_nut_m12", "--policy", str(policy), "--episodes", "1",
                 "--num-envs", "1"]  # fmt: skip
    result = runner.invoke(app, eval_args)
    assert result.exit_code == 0, result.output
    assert unspaced(f"reach_nut_m12 with {policy}: success") in unspaced(result.output)
    starts = tmp_path / "starts.toml"
    starts.write_text('[[start]]\nname = "[red]nudged"\nobjects = [{ x = 0.5, y = -0.05 }]\n')
    table = runner.invoke(app, [*eval_args, "--starts", str(starts)])
    assert table.exit_code == 0, table.output
    assert "[red]nudged: " in table.output and "│ [red]nudged" in table.output
    out = tmp_path / "demo[/b]"
    demo_args = ["demo", "--task", "reach_nut_m12", "--episodes", "1", "--out", str(out)]
    demo = runner.invoke(app, demo_args)
    assert demo.exit_code == 0, demo.output
    assert unspaced(f"summary: {out}/reach_nut_m12_eval.json") in unspaced(demo.output)


@pytest.mark.skipif(GL_BACKEND is None, reason="no EGL or OSMesa library installed")
def test_render_prints_the_video_path_as_typed(tmp_path):
    # '[/b]' ended in a MarkupError traceback after the video was written.
    out = tmp_path / "a[/b]c.mp4"
    result = runner.invoke(app, ["render", "reach_nut_m12", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert unspaced(f"wrote {out} (") in unspaced(result.output) and out.is_file()


def test_importing_the_cli_loads_no_torch():
    # `itskill --help` and every command that trains nothing waited 3.4 s for PyTorch and
    # Stable-Baselines3, imported for the bound of --seed alone.
    import subprocess
    import sys

    code = "import itskill.cli, sys; print('torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


def test_user_errors_names_each_class_where_it_is_defined():
    # The classes are looked up by module and name: one moved or renamed would silently stop
    # being caught, and its message would become a traceback again.
    import importlib

    from itskill.cli.common import USER_ERRORS

    for module, name in USER_ERRORS:
        cls = getattr(importlib.import_module(module), name)
        assert issubclass(cls, Exception) and cls.__module__ == module, (module, name)


def _user_error_examples() -> list[Exception]:
    """An error of each kind the user can act on, as the commands raise them."""
    from itskill.curves import CurveError
    from itskill.executors import ExecutorError
    from itskill.experiments.config import ExperimentConfigError
    from itskill.experiments.learn import BudgetError, LearnError
    from itskill.experiments.report import ReportError
    from itskill.experiments.runner import ExperimentRunError
    from itskill.files import CorruptFileError
    from itskill.llm import LLMError
    from itskill.llm.prompts import PromptError
    from itskill.reward.config import SearchConfigError
    from itskill.reward.plan import PlanError
    from itskill.reward.search import RewardSearchError
    from itskill.rl.config import HyperparamError
    from itskill.rl.demos import DemoError
    from itskill.rl.train import ResumeMismatchError, RewardLoadError
    from itskill.skills import SkillSpaceError
    from itskill.tasks.evaluate import CheckpointError
    from itskill.tasks.render import RenderError
    from itskill.tasks.scripted import ScriptError
    from itskill.tasks.spec import TaskFileError, UnknownTaskError
    from itskill.transfer import AnalyzerError, SourceError, TransferConfigError
    from itskill.transfer.sources import IncompatibleSourceError

    return [
        AnalyzerError("the reply's matrix has 2 rows; the target has 5 stages"),
        BudgetError("learn.toml", "tiny.transfer.steps", "missing (required)"),
        CheckpointError("runs/x", "no checkpoint.json"),
        CorruptFileError("runs/x/learn.json", "not valid JSON"),
        CurveError("runs/x/eval.csv", "no evaluations"),
        DemoError("task 'x' has no script to demonstrate it; train without demos"),
        ExecutorError("ray is not installed"),
        ExperimentConfigError("exp.toml", "steps", "missing (required)"),
        ExperimentRunError("runs/x already holds an experiment run; pass --resume"),
        HyperparamError("hp.toml", "ppo.n_steps", "expected int"),
        IncompatibleSourceError("source 0 observes 12 values; the target 14"),
        LearnError("runs/x was run with another command"),
        LLMError("openai:x at http://localhost/v1 rejected the request"),
        PlanError("the plan names no task"),
        PromptError("analyze.txt: no {segments} slot"),
        RenderError("no OpenGL backend"),
        ReportError("runs/x: not an experiment run directory"),
        ResumeMismatchError("runs/x was trained with a2c, not ppo"),
        RewardLoadError("reward.py", "no compute_reward(ctx)"),
        RewardSearchError("runs/reward/x: not a reward search run"),
        ScriptError("step 2: unknown action"),
        SearchConfigError("search.toml", "samples", "must be positive"),
        SkillSpaceError("skills.sqlite was written by a newer itskill"),
        SourceError("no source skills for 'x'"),
        TaskFileError("tasks/x.toml", "stages", "missing (required)"),
        TransferConfigError("transfer.toml", "k", "must be positive"),
        UnknownTaskError("pick_nut_m99", ["pick_nut_m12"]),
    ]


def _raised_in_a_command(err: Exception):
    """What a user sees of ``err`` raised by a command inside :func:`user_errors`."""
    import typer

    from itskill.cli.common import user_errors

    command = typer.Typer()

    @command.command()
    def fail() -> None:
        with user_errors():
            raise err

    return runner.invoke(command, [])


@pytest.mark.parametrize("err", _user_error_examples(), ids=lambda err: type(err).__name__)
def test_every_error_the_user_can_act_on_is_one_line_and_exit_2(err):
    # Each command caught its own list of these, and the lists had drifted apart: a broken
    # prompt file was one line in `itskill plan` and a traceback in `itskill learn`.
    result = _raised_in_a_command(err)
    assert result.exit_code == 2, result.output
    assert flat(result.output) == flat(f"error: {err}")


def test_an_error_that_is_not_the_users_keeps_its_traceback():
    result = _raised_in_a_command(ValueError("a bug"))
    assert result.exit_code == 1 and isinstance(result.exception, ValueError)


def test_render_refuses_to_overwrite_a_video_unless_forced(tmp_path):
    # A mistyped --out replaced another video without a word.
    out = tmp_path / "kept.mp4"
    out.write_bytes(b"another run's film")
    result = runner.invoke(app, ["render", "reach_nut_m12", "--out", str(out)])
    assert result.exit_code == 2
    assert "exists; pass --force to overwrite it" in flat(result.output)
    assert out.read_bytes() == b"another run's film"


def test_render_refuses_a_folder_or_another_suffix_before_offering_force(tmp_path):
    # It said "exists; pass --force", and with --force that the video must be a .mp4 file.
    for out in (tmp_path, tmp_path / "film.avi"):
        result = runner.invoke(app, ["render", "reach_nut_m12", "--out", str(out)])
        assert result.exit_code == 2
        assert "mustbea.mp4filepath" in unspaced(result.output.replace("│", ""))


@pytest.mark.parametrize("name", ["reach_nut_m12.mp4", "reach_nut_m12_eval.json"])
def test_demo_refuses_to_overwrite_its_files_unless_forced(tmp_path, name):
    # It replaced them without a word, after the rollouts.
    (tmp_path / name).write_text("mine")
    args = ["demo", "--task", "reach_nut_m12", "--episodes", "1", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "exists; pass --force to overwrite it" in flat(result.output)
    assert (tmp_path / name).read_text() == "mine"
    forced = runner.invoke(app, [*args, "--force"])
    assert forced.exit_code == 0, forced.output
    assert json.loads((tmp_path / "reach_nut_m12_eval.json").read_text())["episodes"] == 1


def test_an_upper_case_task_id_gets_the_ids_it_is_near():
    result = runner.invoke(app, ["tasks", "show", "PICK_NUT_M12"])
    assert result.exit_code == 2
    assert "did you mean 'pick_nut_m12'" in flat(result.output)


def test_render_with_a_policy_it_cannot_load_leaves_no_folders(tmp_path):
    out = tmp_path / "new" / "sub" / "x.mp4"
    missing = tmp_path / "no_such_run"
    result = runner.invoke(
        app, ["render", "pick_nut_m12", "--policy", str(missing), "--out", str(out)]
    )
    assert result.exit_code == 2, result.output
    assert not (tmp_path / "new").exists()


def test_a_mujoco_gl_setting_it_drops_is_one_warning_line(tmp_path: Path) -> None:
    # The warning came as Python prints it, path and source line included, because the command
    # modules import the simulator (which checks MUJOCO_GL) before the commands' own warning
    # format was set.
    import os
    import subprocess
    import sys

    env = {**os.environ, "MUJOCO_GL": "bogus", "ITSKILL_HOME": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, "-m", "itskill", "tasks", "list"],
        capture_output=True, text=True, env=env, timeout=120, check=True,
    )  # fmt: skip
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: MUJOCO_GL='bogus' is ignored"), lines
