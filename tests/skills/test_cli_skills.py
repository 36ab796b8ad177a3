from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from skill_helpers import measured
from typer.testing import CliRunner

from itskill.cli import app
from itskill.skills.store import SHIPPED_LIBRARY

runner = CliRunner()


def shipped(task: str) -> Path:
    """The shipped policy of ``task``: `skills add` loads the checkpoint it is given."""
    return SHIPPED_LIBRARY / task / "policy.safetensors"


@pytest.fixture
def checkpoint() -> Path:
    """A trained policy of reach_nut_m12."""
    return shipped("reach_nut_m12")


def add(checkpoint, task: str, *extra: str):
    args = ["skills", "add", "--task", task, "--checkpoint", str(checkpoint), "--json", *extra]
    return runner.invoke(app, args)


def test_add_takes_the_budget_algorithm_and_seed_the_run_recorded(home):
    # They were left blank unless given as options, though the run's checkpoint.json has them.
    result = add(shipped("pick_nut_m12"), "pick_nut_m12", "--name", "mine")
    assert result.exit_code == 0, result.output
    added = json.loads(result.stdout)
    assert (added["train_steps"], added["train_wall_s"]) == (250_000, 278.25)
    assert (added["algo"], added["seed"]) == ("ppo", 0)
    given = json.loads(add(shipped("pick_nut_m12"), "pick_nut_m12", "--name", "given",
                           "--steps", "7", "--seed", "3").stdout)  # fmt: skip
    # A budget given takes no wall time of the run's: that belongs to another budget.
    assert (given["train_steps"], given["train_wall_s"], given["seed"]) == (7, None, 3)
    plain = runner.invoke(app, ["skills", "add", "--task", "pick_nut_m12", "--checkpoint",
                                str(shipped("pick_nut_m12")), "--name", "plain"])  # fmt: skip
    assert plain.exit_code == 0 and "its success is unknown" in " ".join(plain.output.split())


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        # A null evaluation step falls back to the run's end; a damaged record gives nothing.
        ({"selection": {"env_steps": None, "wall_s": None}}, (250_000, None, 0)),
        ({"selection": [1, 2]}, (250_000, None, 0)),
        ({"selection": {"env_steps": "250k", "wall_s": -1}}, (250_000, None, 0)),
    ],
)
def test_add_takes_from_a_damaged_run_record_only_what_is_well_formed(
    home, tmp_path, edit, expected
):
    # An AttributeError traceback, or an error blaming --steps or --wall-s the user never gave.
    import shutil

    run = tmp_path / "run"
    shutil.copytree(shipped("pick_nut_m12").parent, run)
    meta = json.loads((run / "checkpoint.json").read_text())
    (run / "checkpoint.json").write_text(json.dumps({**meta, **edit}))
    result = add(run / "policy.safetensors", "pick_nut_m12", "--name", "bent")
    assert result.exit_code == 0, result.output
    added = json.loads(result.stdout)
    assert (added["train_steps"], added["train_wall_s"], added["seed"]) == expected


def test_add_list_search_show_remove(home):
    result = add(
        shipped("insert_peg_round"), "insert_peg_round", "--success", "0.9", "--steps", "1000"
    )
    assert result.exit_code == 0, result.output
    added = json.loads(result.stdout)
    assert added["description"] == "Insert the round peg into the round hole"
    assert added["actions"] == ["insert"] and added["train_steps"] == 1000
    pick = add(shipped("pick_nut_m12"), "pick_nut_m12", "--name", "pick", "--actions", "a, b")
    assert pick.exit_code == 0

    listed = json.loads(runner.invoke(app, ["skills", "list", "--json"]).stdout)
    assert [(s["id"], s["name"]) for s in listed] == [(1, "insert_peg_round"), (2, "pick")]
    assert listed[1]["actions"] == ["a", "b"]
    markdown = runner.invoke(app, ["skills", "list", "--markdown"]).stdout.splitlines()
    assert markdown[2].startswith("| insert_peg_round | `insert_peg_round` | insert | 90.0% |")
    assert "| 1,000 |" in markdown[2]
    assert markdown[3].startswith("| pick | `pick_nut_m12` | a → b |")

    result = runner.invoke(
        app, ["skills", "search", "insert the peg in the hole", "-k", "1", "--json"]
    )
    assert result.exit_code == 0, result.output
    hits = json.loads(result.stdout)
    assert len(hits) == 1 and hits[0]["name"] == "insert_peg_round" and hits[0]["score"] > 0.5

    shown = json.loads(runner.invoke(app, ["skills", "show", "pick", "--json"]).stdout)
    assert shown["checkpoint_exists"] is True

    assert runner.invoke(app, ["skills", "remove", "1", "--json"]).exit_code == 0
    assert len(json.loads(runner.invoke(app, ["skills", "list", "--json"]).stdout)) == 1
    table = runner.invoke(app, ["skills", "list"])
    assert table.exit_code == 0 and "pick" in table.stdout


def test_add_stores_a_checkpoint_of_the_library_relative_to_it_and_refuses_a_taken_name(home):
    # Stored as an absolute path, the skill broke when the skill space moved; a taken name (the
    # task's, by default) gave no hint.
    mine = home / "library" / "mine"
    shutil.copytree(shipped("reach_nut_m12").parent, mine)
    first = add(mine, "reach_nut_m12")
    assert first.exit_code == 0, first.output
    assert json.loads(first.stdout)["checkpoint"] == "mine/policy.safetensors"
    again = add(shipped("reach_nut_m12"), "reach_nut_m12")
    message = " ".join(again.output.split())
    assert again.exit_code == 2 and "a skill named 'reach_nut_m12' already exists" in message
    assert "without --name a skill takes its task's name" in message
    named = add(shipped("reach_nut_m12"), "reach_nut_m12", "--name", "reach_nut_m12")
    assert named.exit_code == 2 and "without --name" not in " ".join(named.output.split())


def test_unknown_skill_exits_2_with_close_names(home):
    assert add(shipped("pick_nut_m12"), "pick_nut_m12").exit_code == 0
    result = runner.invoke(app, ["skills", "show", "pick_nut_m16"])
    assert result.exit_code == 2
    assert "unknown skill" in result.output and "pick_nut_m12" in result.output


@pytest.mark.parametrize("command", [["show"], ["remove", "--json"]])
def test_a_serial_number_past_sqlites_integers_is_an_unknown_skill(home, command):
    # OverflowError: Python int too large to convert to SQLite INTEGER, exit 1.
    result = runner.invoke(app, ["skills", command[0], "9" * 23, *command[1:]])
    assert result.exit_code == 2, result.output
    assert f"unknown skill '{'9' * 23}'" in result.output and result.stdout == ""


def test_add_of_a_checkpoint_path_too_long_to_use_is_a_one_line_error(home, tmp_path):
    too_long = tmp_path / ("a" * 300) / "policy.safetensors"
    result = add(too_long, "reach_nut_m12")
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: cannot use {str(too_long)[:40]}")
    assert "characters): File name too long" in result.output
    assert len(result.output.splitlines()) == 1 and "a" * 300 not in result.output


def test_list_refuses_json_and_markdown_together(home):
    # It printed JSON, silently ignoring --markdown.
    result = runner.invoke(app, ["skills", "list", "--json", "--markdown"])
    assert result.exit_code == 2 and result.stdout == ""
    assert "give--jsonor--markdown,notboth" in _flat(result.output)
    assert not home.exists()  # refused before the skill space was opened


def test_add_needs_existing_checkpoint_and_known_task(home, tmp_path, checkpoint):
    missing = runner.invoke(
        app, ["skills", "add", "--task", "pick_nut_m12", "--checkpoint", str(tmp_path / "no.zip")]
    )
    assert missing.exit_code == 2 and "doesnotexist" in _flat(missing.output)
    assert "--checkpoint" in _flat(missing.output)
    assert not home.exists()  # refused before the skill space was made
    assert add(checkpoint, "no_such_task").exit_code == 2


def test_add_refuses_weights_under_another_name_than_policy_safetensors(home, tmp_path):
    # Every reader loads the policy.safetensors beside the file: the skill recorded one file and
    # ran another.
    run_dir = tmp_path / "run"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", run_dir)
    (run_dir / "policy.safetensors").rename(run_dir / "weights_v2.safetensors")
    result = add(run_dir / "weights_v2.safetensors", "reach_nut_m12")
    assert result.exit_code == 2
    assert "--checkpoint" in _flat(result.output) and "policy.safetensors" in result.output
    assert not home.exists()


def test_add_takes_a_run_directory_and_refuses_weights_without_their_metadata(home, tmp_path):
    run_dir = SHIPPED_LIBRARY / "reach_nut_m12"  # laid out as a training run's kept policy
    result = add(run_dir, "reach_nut_m12")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["checkpoint"] == str(run_dir.resolve() / "policy.safetensors")
    lone = tmp_path / "lone" / "policy.safetensors"
    lone.parent.mkdir()
    lone.write_bytes((run_dir / "policy.safetensors").read_bytes())
    result = add(lone, "reach_nut_m12", "--name", "lone")
    assert result.exit_code == 2
    assert "--checkpoint" in _flat(result.output) and "checkpoint.json" in _flat(result.output)


def _flat(output: str) -> str:
    """``output`` without the error box's borders and line breaks (it wraps anywhere)."""
    return "".join(output.replace("│", "").split())


def test_add_refuses_a_checkpoint_that_does_not_load(home, tmp_path, checkpoint):
    # Both were added, and failed only at the skill's first use.
    not_zip = tmp_path / "policy.zip"
    not_zip.write_bytes(b"not a real policy")
    result = add(not_zip, "reach_nut_m12")
    assert result.exit_code == 2
    assert "--checkpoint" in _flat(result.output) and "notaStable-Baselines3" in _flat(
        result.output
    )
    truncated = tmp_path / "run" / "policy.safetensors"
    truncated.parent.mkdir()
    (truncated.parent / "checkpoint.json").write_bytes(
        (checkpoint.parent / "checkpoint.json").read_bytes()
    )
    truncated.write_bytes(checkpoint.read_bytes()[:1000])
    result = add(truncated, "reach_nut_m12")
    assert result.exit_code == 2 and "corruptpolicyweights" in _flat(result.output)
    assert json.loads(runner.invoke(app, ["skills", "list", "--json"]).stdout) == []


def test_add_refuses_a_policy_trained_on_another_task(home, checkpoint):
    # A reach policy registered as an insert skill would be retrieved and chained as one.
    result = add(checkpoint, "insert_peg_round")
    assert result.exit_code == 2
    assert "trainedontask'reach_nut_m12',not'insert_peg_round'" in _flat(result.output)
    assert json.loads(runner.invoke(app, ["skills", "list", "--json"]).stdout) == []


def test_add_refuses_a_skill_without_actions(home, checkpoint):
    # Accepted before, and the analyzer then failed with a traceback on the skill as a source.
    result = add(checkpoint, "reach_nut_m12", "--actions", " , ,")
    assert result.exit_code == 2
    assert "--actions" in _flat(result.output) and "needsatleastoneaction" in _flat(result.output)
    assert not home.exists()  # refused before the skill space was opened (which creates it)


def test_install_from_a_file_or_a_missing_directory_is_a_one_line_error(home, tmp_path):
    a_file = tmp_path / "afile"
    a_file.write_text("not a library")
    for library in (a_file, tmp_path / "missing"):
        result = runner.invoke(app, ["skills", "install", str(library)])
        assert result.exit_code == 2, result.output
        assert str(library) in _flat(result.output) and "Traceback" not in result.output


def test_names_queries_and_messages_are_printed_as_given_not_as_markup(home, checkpoint):
    # "[/v2]" closed a tag that was never opened (a traceback after the skill was added);
    # "[bold]" vanished from the name it styled.
    for number, name in enumerate(("pick[/v2]", "[bold]loud"), start=1):
        result = runner.invoke(app, ["skills", "add", "--task", "reach_nut_m12", "--name", name,
                                     "--checkpoint", str(checkpoint)])  # fmt: skip
        assert result.exit_code == 0, result.output
        assert f"added skill {number}: {name} (reach_nut_m12)" in result.output
    listed = runner.invoke(app, ["skills", "list"])
    assert listed.exit_code == 0, listed.output
    assert "pick[/v2]" in listed.output and "[bold]loud" in listed.output
    shown = runner.invoke(app, ["skills", "show", "pick[/v2]"])
    assert shown.exit_code == 0 and "pick[/v2]" in shown.output
    found = runner.invoke(app, ["skills", "search", "insert [/peg]", "-k", "1"])
    assert found.exit_code == 0 and "'insert [/peg]'" in found.output
    removed = runner.invoke(app, ["skills", "remove", "pick[/v2]"])
    assert removed.exit_code == 0 and "removed skill 1: pick[/v2]" in removed.output


def test_add_refuses_an_interval_whose_low_is_above_its_high(home, checkpoint):
    result = add(
        checkpoint, "reach_nut_m12", "--success", "0.5", "--ci-low", "0.9", "--ci-high", "0.1"
    )
    assert result.exit_code == 2 and "--ci-low" in _flat(result.output)
    assert "low0.9isabovehigh0.1" in _flat(result.output)


@pytest.mark.parametrize(
    ("options", "option", "problem"),
    [
        (["--wall-s", "inf"], "--wall-s", "infisnotafinitenumberofseconds"),
        (
            ["--success", "0.1", "--ci-low", "0.9", "--ci-high", "0.99"],
            "--success",
            "0.1isoutsideitsowninterval[0.9,0.99]",
        ),
    ],
)
def test_add_refuses_measurements_no_run_gives(home, checkpoint, options, option, problem):
    # `--wall-s inf` was stored and `skills show --json` printed Infinity, which is not JSON.
    result = add(checkpoint, "reach_nut_m12", *options)
    assert result.exit_code == 2 and result.stdout == ""
    assert f"Invalidvaluefor{option}:{problem}" in _flat(result.output)
    assert not home.exists()  # refused before the skill space was opened


@pytest.mark.parametrize("name", ["", "  ", " pick"])
def test_add_refuses_a_name_that_sources_could_not_name(home, checkpoint, name):
    # "  " was added as skill 50, which no --sources list could then name.
    result = add(checkpoint, "reach_nut_m12", "--name", name)
    assert result.exit_code == 2
    assert "Invalid value for --name" in result.output
    assert not home.exists()  # refused before the skill space was opened


@pytest.mark.parametrize(
    ("field", "value", "problem"),
    [
        ("actions", "approach", "actions: a skill needs at least one action"),
        ("success", 5, "success: 5.0 is not a rate in [0, 1]"),
        ("success_ci", [0.9, 0.1], "success_ci: low 0.9 is above high 0.1"),
    ],
)
def test_install_refuses_a_manifest_field_of_the_wrong_type_or_range(
    home, tmp_path, field, value, problem
):
    # Each was installed: "approach" as eight one-letter actions, 5 as a success of 500%.
    lib = tmp_path / "lib"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", lib / "reach_nut_m12")
    manifest = json.loads((SHIPPED_LIBRARY / "manifest.json").read_text())
    entry = next(e for e in manifest["skills"] if e["name"] == "reach_nut_m12")
    (lib / "manifest.json").write_text(json.dumps({"skills": [{**entry, field: value}]}))
    result = runner.invoke(app, ["skills", "install", str(lib)])
    assert result.exit_code == 2 and result.stdout == ""
    where = f"{lib / 'manifest.json'}: skills[0] (skill 'reach_nut_m12'): {problem}"
    assert " ".join(result.stderr.split()).startswith(f"error: {where}")
    assert not home.exists()  # not even the skill space was created


def test_install_refuses_a_repeated_name_and_says_which_it_skipped(home, tmp_path):
    # The second entry was dropped without a word, as was every name the space already had.
    lib = tmp_path / "lib"
    shutil.copytree(SHIPPED_LIBRARY / "reach_nut_m12", lib / "reach_nut_m12")
    manifest = json.loads((SHIPPED_LIBRARY / "manifest.json").read_text())
    entry = next(e for e in manifest["skills"] if e["name"] == "reach_nut_m12")
    (lib / "manifest.json").write_text(
        json.dumps({"skills": [entry, {**entry, "description": "x"}]})
    )
    twice = runner.invoke(app, ["skills", "install", str(lib)])
    assert twice.exit_code == 2 and "skills[1]: name 'reach_nut_m12' is taken by skills[0]" in (
        " ".join(twice.stderr.split())
    )
    (lib / "manifest.json").write_text(json.dumps({"skills": [entry]}))
    assert "installed 1 skill(s)" in runner.invoke(app, ["skills", "install", str(lib)]).output
    again = runner.invoke(app, ["skills", "install", str(lib)])
    skipped = "skipped 1 whose name the skill space has: reach_nut_m12"
    assert again.exit_code == 0 and skipped in " ".join(again.output.split())


@pytest.mark.parametrize("query", ["", "   "])
def test_search_refuses_a_blank_query(home, query):
    # It printed the skills closest to the embedding of nothing, and exited 0.
    result = runner.invoke(app, ["skills", "search", query])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("error: the query is empty")


def test_search_refuses_to_exclude_an_unknown_task(home):
    # The typo excluded nothing, and pick_nut_m12's skill came first.
    args = ["skills", "search", "pick nut", "--exclude-task", "pick_nut_m21"]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("error: unknown task 'pick_nut_m21'")
    assert "pick_nut_m12" in result.stderr


def test_corrupt_database_names_path(home):
    home.mkdir()
    (home / "skills.sqlite").write_bytes(b"garbage" * 1000)
    result = runner.invoke(app, ["skills", "list"])
    assert result.exit_code == 2
    assert str(home / "skills.sqlite") in " ".join(result.output.split())


def test_a_database_damaged_below_its_header_exits_2_naming_its_path(home, checkpoint):
    assert add(checkpoint, "reach_nut_m12").exit_code == 0
    path = home / "skills.sqlite"
    data = path.read_bytes()
    path.write_bytes(data[:4096] + b"\xff" * (len(data) - 4096))  # the header page stays
    result = runner.invoke(app, ["skills", "list"])
    assert result.exit_code == 2, result.output
    assert f"{path}: not a readable itskill skill database" in " ".join(result.output.split())


def test_pretrain_reports_the_seeds_it_tried(home, tmp_path, monkeypatch):
    # No run reaches --min-success (the held-out measure is stubbed): both seeds train, the
    # better is reported, not added. A task named twice trains once (twice, it trained into
    # one folder at once and failed).
    monkeypatch.setattr("itskill.skills.pretrain.measure_skill", measured("seed1", 0.5))
    args = ["skills", "pretrain", "--tasks", "reach_nut_m12,reach_nut_m12", "--steps", "512"]
    args += ["--seeds", "2"]
    args += ["--eval-every", "256", "--episodes", "4", "--min-success", "0.9", "--workers", "1"]
    args += ["--runs", str(tmp_path / "runs"), "--library", str(tmp_path / "library")]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert result.output.count("reach_nut_m12: success") == 1
    assert "not learned, not added" in result.output
    assert result.output.count("not kept: seed") == 1
    assert sorted(p.name for p in (tmp_path / "runs" / "reach_nut_m12").iterdir()) == [
        "seed0",
        "seed1",
    ]


def _pretrain_failing_with(error: Exception, tmp_path, monkeypatch):
    def failing(*args, **kwargs):
        raise error

    monkeypatch.setattr("itskill.skills.pretrain.measure_skill", failing)
    args = ["skills", "pretrain", "--tasks", "reach_nut_m12", "--steps", "256", "--seeds", "1"]
    args += ["--eval-every", "0", "--workers", "1", "--runs", str(tmp_path / "runs")]
    return runner.invoke(app, [*args, "--library", str(tmp_path / "library")])


def test_pretrain_exits_non_zero_when_a_skill_fails(home, tmp_path, monkeypatch):
    # The failure was printed and the command exited 0, so a script went on as if all was well.
    result = _pretrain_failing_with(RuntimeError("the evaluation broke"), tmp_path, monkeypatch)
    assert result.exit_code == 1, result.output
    assert "reach_nut_m12: failed: RuntimeError: the evaluation broke" in result.output
    assert "1skill(s)failed:reach_nut_m12" in _flat(result.output)
    assert "thesamecommandtriesreach_nut_m12again" in _flat(result.output)


def test_pretrain_says_a_run_of_other_settings_is_not_mended_by_running_again(
    home, tmp_path, monkeypatch
):
    # "the same command tries them again" fails it again, every time.
    from itskill.rl.train import ResumeMismatchError

    mismatch = ResumeMismatchError("runs/reach_nut_m12/seed0: holds a run trained with ppo")
    result = _pretrain_failing_with(mismatch, tmp_path, monkeypatch)
    assert result.exit_code == 1, result.output
    flat = _flat(result.output)
    assert "reach_nut_m12:theirrundirectoriesunder--runsholdrunsofothersettings" in flat
    assert "movethoseasideorgiveanother--runsdirectory" in flat and "triesreach" not in flat


@pytest.mark.parametrize(
    ("option", "message"),
    [
        # It started the worker pool, whose job died with a KeyboardInterrupt traceback.
        (["--algo", "foo"], "Invalidvaluefor--algo:algomustbeoneofa2c,ppo,got'foo'"),
        # 2 (or 50 for "50%") trained every seed of every skill and could never add one.
        (["--min-success", "2"], "Invalidvaluefor'--min-success'"),
        # Told on stdout, without "error:", by the executor once the skill space was open.
        (["--workers", "0"], "Invalidvaluefor'--workers'"),
        # Found out by the last seed's run, after the others trained.
        (["--seed", "4294967295", "--seeds", "2"], "Invalidvaluefor--seed/--seeds:seeds"),
        # Typer reads an empty path as ".": the manifest and skills went into the current folder.
        (["--library", ""], "Invalidvaluefor'--library':nameadirectoryofitsown"),
    ],
)
def test_pretrain_refuses_bad_settings_before_training(home, tmp_path, option, message):
    args = ["skills", "pretrain", "--tasks", "reach_nut_m12", *option]
    result = runner.invoke(app, [*args, "--runs", str(tmp_path / "runs")])
    assert result.exit_code == 2
    assert message in _flat(result.output)
    assert not (tmp_path / "runs").exists()


def test_pretrain_reports_an_unknown_executor_as_an_error(home, tmp_path):
    # It was printed on stdout without "error:", after the skill space had been created.
    args = ["skills", "pretrain", "--tasks", "reach_nut_m12", "--executor", "foo"]
    result = runner.invoke(app, [*args, "--runs", str(tmp_path / "runs")])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("error: unknown executor 'foo'")
    assert not (tmp_path / "runs").exists() and not home.exists()


def test_pretrain_takes_a_comma_separated_task_list(home, tmp_path):
    args = ["skills", "pretrain", "--tasks", "reach_nut_m12, no_such_task", "--steps", "256"]
    result = runner.invoke(app, [*args, "--runs", str(tmp_path / "runs")])
    assert result.exit_code == 2
    assert "unknown task 'no_such_task'" in result.output
    assert not (tmp_path / "runs").exists() and not home.exists()  # nor the skill space


@pytest.mark.parametrize("tasks", ["", ",", " "])
def test_pretrain_refuses_a_task_list_that_names_no_task(home, tmp_path, tasks):
    # It trained every basic task, hours of it, as if --tasks had not been given.
    result = runner.invoke(app, ["skills", "pretrain", "--tasks", tasks, "--runs", str(tmp_path)])
    assert result.exit_code == 2
    assert "Invalidvaluefor--tasks" in _flat(result.output) and "namesnotask" in _flat(
        result.output
    )
    assert list(tmp_path.iterdir()) == []


def test_a_refined_skill_must_beat_its_start_at_a_p_value_above_zero(home):
    result = runner.invoke(app, ["skills", "pretrain", "--refine", "--replace-p", "0"])
    assert result.exit_code == 2
    assert "Invalidvaluefor--replace-p:replace_pmustbeabove0" in _flat(result.output)


def test_replace_p_without_refine_is_refused(home):
    # Without --refine a new skill replaces the library's on its success alone: a p-value given
    # there would be silently ignored.
    result = runner.invoke(app, ["skills", "pretrain", "--replace-p", "0.01"])
    assert result.exit_code == 2 and "add --refine" in " ".join(result.output.split())


def test_refining_reports_the_runs_own_budget_and_keeps_a_skill_it_does_not_beat(home, tmp_path):
    # The shipped reach succeeds in every held-out episode: nothing can beat it.
    library = tmp_path / "library"
    args = ["skills", "pretrain", "--tasks", "reach_nut_m12", "--refine", "--steps", "256"]
    args += ["--seeds", "1", "--eval-every", "256", "--episodes", "4"]
    args += ["--runs", str(tmp_path / "runs"), "--library", str(library)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())  # the console wraps long lines
    shipped = 100_352  # the shipped skill's budget, in the manifest
    assert f"after 1,024 env-steps more ({shipped + 1024:,} in all)" in output
    same = "the library's skill on the same episodes (100.0%; 0 won, 0 lost, p = 1)"
    assert f"not clearly better than {same}, not replaced" in output
    assert not (library / "reach_nut_m12").exists()


def test_a_damaged_shipped_library_is_a_warning_and_the_users_skills_still_list(
    home, tmp_path, monkeypatch, checkpoint
):
    assert add(checkpoint, "reach_nut_m12", "--name", "mine").exit_code == 0
    library = tmp_path / "damaged"
    library.mkdir()
    (library / "manifest.json").write_text('{"skills": [')
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", library)
    result = runner.invoke(app, ["skills", "list", "--json"])
    assert result.exit_code == 0, result.output
    assert [s["name"] for s in json.loads(result.stdout)] == ["mine"]
    warning = " ".join(result.stderr.split())
    assert warning.startswith("warning: the shipped skill library is damaged")
    assert "manifest.json: not valid JSON" in warning and "reinstall itskill" in warning
