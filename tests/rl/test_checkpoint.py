"""Checkpoint writes: Ctrl-C waits for a checkpoint being written, then acts as it would have."""

from __future__ import annotations

import os
import signal
import time

import pytest

from itskill.rl.checkpoint import interrupts_deferred


def _ctrl_c_during_block(done: list[str], sig: int = signal.SIGINT) -> list[str]:
    with interrupts_deferred():
        os.kill(os.getpid(), sig)
        time.sleep(0.05)  # a signal is handled between bytecodes: it would have struck here
        done.append("the whole block ran")
    done.append("after the block")
    return done


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_stop_during_a_checkpoint_is_raised_once_it_is_written(sig: int) -> None:
    # Set here as the itskill command sets them (a test run started in the background
    # inherits SIGINT ignored).
    previous = signal.signal(sig, signal.default_int_handler)
    try:
        done: list[str] = []
        with pytest.raises(KeyboardInterrupt):
            _ctrl_c_during_block(done, sig)
        assert done == ["the whole block ran"]  # raised as the block ended, not inside it
        assert signal.getsignal(sig) is signal.default_int_handler  # put back
    finally:
        signal.signal(sig, previous)


def test_a_process_ignoring_ctrl_c_still_ignores_it_after_a_checkpoint() -> None:
    # A worker that already saved on its first Ctrl-C ignores the second one.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        assert _ctrl_c_during_block([]) == ["the whole block ran", "after the block"]
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_an_export_cut_short_leaves_the_old_policy_whole(tmp_path, monkeypatch) -> None:
    # Pretraining exports over the library's skill in place: a copy cut short (disk full,
    # kill) left truncated weights that every transfer retrieving the skill then failed on.
    import shutil

    from itskill.rl import checkpoint
    from itskill.skills.store import SHIPPED_LIBRARY

    target = tmp_path / "pick_nut_m12"
    checkpoint.export_policy(SHIPPED_LIBRARY / "pick_nut_m12", target)
    before = {p.name: p.read_bytes() for p in target.iterdir()}

    def cut_short(src, dst):
        with open(src, "rb") as fh, open(dst, "wb") as out:
            out.write(fh.read(100))
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(shutil, "copyfile", cut_short)
    with pytest.raises(OSError, match="No space"):
        checkpoint.export_policy(SHIPPED_LIBRARY / "place_nut_m12", target)
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    checkpoint.load_policy(target)  # still loads


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("num_timesteps", "abc", 'num_timesteps: expected an integer of 0 or more, got "abc"'),
        ("num_timesteps", -5, "num_timesteps: expected an integer of 0 or more, got -5"),
        ("seed", True, "seed: expected an integer of 0 or more, got true"),
        ("reward", None, "reward: expected an object, got null"),
        ("policy", [256, 256], "policy: expected an object, got [256, 256]"),
        ("task", 12, "task: expected a string, got 12"),
        (
            "evaluation",
            {"every": 64},
            "evaluation: expected an object of two whole numbers of 1 or more, every and "
            'episodes, got {"every": 64}',
        ),
    ],
)
def test_a_resume_from_metadata_of_the_wrong_type_names_the_field(
    tmp_path, field: str, value: object, expected: str
) -> None:
    # A hand-edited checkpoint.json with a field of the wrong type resumed into a traceback
    # (int() of "abc", .get on None) instead of a message naming the field.
    import json
    import shutil

    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.skills.store import SHIPPED_LIBRARY

    run = tmp_path / "run"
    shutil.copytree(SHIPPED_LIBRARY / "pick_nut_m12", run)
    meta = json.loads((run / "checkpoint.json").read_text())
    (run / "checkpoint.json").write_text(json.dumps({**meta, field: value}))
    args = ["train", "pick_nut_m12", "--steps", "256", "--num-envs", "2", "--out", str(run)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    message = f"{run / 'checkpoint.json'}: corrupt metadata: {expected}"
    assert "".join(message.split()) in "".join(result.output.split())  # rich wraps long lines
    assert "Traceback" not in result.output


@pytest.mark.parametrize(
    ("policy_class", "expected"),
    [
        ("planted.Policy", "policy class 'planted.Policy' is not one of itskill's; not imported"),
        ("itskill.rl.checkpoint.CheckpointError", "is not a policy class"),
        ("itskill.transfer.itn.ITNPolicy", "corrupt policy description: missing field"),
    ],
)
def test_a_checkpoint_loads_only_itskills_policy_classes(
    tmp_path, monkeypatch, policy_class: str, expected: str
) -> None:
    # The class a checkpoint names is imported to build it: a downloaded skill could name a
    # module of its own beside it, and the current directory is on the import path.
    import json
    import shutil
    import sys

    from itskill.rl.checkpoint import CheckpointError, load_policy
    from itskill.skills.store import SHIPPED_LIBRARY

    (tmp_path / "planted.py").write_text("open(__file__ + '.ran', 'w').close()\nPolicy = object\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    skill = tmp_path / "skill"
    shutil.copytree(SHIPPED_LIBRARY / "pick_nut_m12", skill)
    meta = json.loads((skill / "checkpoint.json").read_text())
    (skill / "checkpoint.json").write_text(json.dumps({**meta, "policy_class": policy_class}))
    with pytest.raises(CheckpointError, match=expected.replace("(", r"\(")):
        load_policy(skill)
    assert not (tmp_path / "planted.py.ran").exists() and "planted" not in sys.modules


def test_a_run_holding_its_trainings_below_it_points_at_them(tmp_path) -> None:
    # `itskill eval --policy` on a learn run or an experiment said "train into it first".
    from itskill.rl.checkpoint import read_meta
    from itskill.tasks.evaluate import CheckpointError

    with pytest.raises(CheckpointError, match=r"train into it first"):
        read_meta(tmp_path)
    for cell in ("cells/t/itn/seed_0", "cells/t/itn/seed_1"):
        (tmp_path / cell).mkdir(parents=True)
        (tmp_path / cell / "checkpoint.json").write_text("{}")
    below = r"below it \(cells/t/itn/seed_0, cells/t/itn/seed_1\)"
    with pytest.raises(CheckpointError, match=below):
        read_meta(tmp_path)
