"""Training metrics: which episodes a row's success rate, return and length count."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from itskill.curves import CurveError, read_curve
from itskill.rl.logger import (
    LoggerConfig,
    MetricsCallback,
    MetricsWriter,
    drop_rows_after,
    read_metrics,
)


def test_episodes_from_a_training_start_are_left_out_of_the_success_rate(tmp_path: Path) -> None:
    env = SimpleNamespace(num_envs=3, last_components={"reach": np.ones(3)})
    callback = MetricsCallback(
        env, tmp_path, total_steps=10, config=LoggerConfig(progress=False, tensorboard=False)
    )
    callback._on_training_start()
    # Env 0 ends a failed episode from the task's own start; env 1 a successful one; env 2 a
    # successful episode that began with the part already in the fingers (a training start).
    callback.locals = {
        "rewards": np.array([10.0, 30.0, 90.0]),  # what the learner sees: rescaled
        "dones": np.array([True, True, True]),
        "infos": [  # each ending episode's return as the reward function summed it
            {"is_success": False, "episode_return": 1.0},
            {"is_success": True, "episode_return": 3.0},
            {"is_success": True, "training_start": True, "episode_return": 9.0},
        ],
    }
    callback._on_step()
    callback.num_timesteps = 3
    row = callback.flush()
    callback.close()
    assert row["episodes"] == 2
    assert row["success_rate"] == 0.5
    assert row["ep_return"] == 2.0  # the reward function's own scale
    assert row["reach"] == 1.0  # reward components still average over every step
    assert read_metrics(tmp_path)[-1]["success_rate"] == 0.5


def test_resume_truncation_drops_a_row_cut_short_by_a_crash(tmp_path: Path) -> None:
    # A line half-written when the disk filled made every later resume fail to parse it.
    writer = MetricsWriter(tmp_path)
    for step in (64, 128, 192):
        writer.write({"step": step, "wall_s": 0.1 * step, "success_rate": 0.5})
    with open(writer.jsonl_path, "a") as fh:
        fh.write('{"step": 256, "wall')
    with open(writer.jsonl_path, "ab") as fh:
        fh.write(b'\n{"step": 320\xff\xfe}')  # and a damaged byte: a UnicodeDecodeError before
    with open(writer.csv_path, "a") as fh:
        fh.write("256,2")
    MetricsWriter(tmp_path).truncate_after(128)
    assert [r["step"] for r in read_metrics(tmp_path)] == [64, 128]
    lines = writer.csv_path.read_text().splitlines()
    assert [line.split(",")[0] for line in lines[1:]] == ["64", "128"]
    assert not list(tmp_path.glob(".*.tmp"))  # rewritten through a temporary file


def test_resume_rebuilds_an_emptied_csv_from_the_jsonl_rows(tmp_path: Path) -> None:
    # A full disk or a user's mistake left metrics.csv empty; metrics.jsonl still has the rows.
    writer = MetricsWriter(tmp_path)
    for step in (64, 128, 192):
        writer.write({"step": step, "wall_s": 0.5, "success_rate": 0.25, "reach": 1.5})
    writer.csv_path.write_text("")
    resumed = MetricsWriter(tmp_path)
    resumed.truncate_after(128)
    resumed.write({"step": 192, "wall_s": 0.5, "success_rate": 0.75, "reach": 2.0})
    lines = writer.csv_path.read_text().splitlines()
    header = lines[0].split(",")
    assert header[0] == "step" and header[-1] == "reach"
    assert [line.split(",")[0] for line in lines[1:]] == ["64", "128", "192"]
    assert lines[1].split(",")[header.index("success_rate")] == "0.25"
    assert lines[3].split(",")[header.index("reach")] == "2"


def test_a_run_started_again_gets_the_header_of_its_own_reward(tmp_path: Path) -> None:
    # A killed run with another reward left rows but no checkpoint; the new run starts over.
    old = MetricsWriter(tmp_path)
    old.write({"step": 64, "wall_s": 0.5, "success_rate": 0.0, "foo": 1.0})
    fresh = MetricsWriter(tmp_path)
    fresh.truncate_after(-1)
    fresh.write({"step": 64, "wall_s": 0.5, "success_rate": 0.5, "reach": 2.0})
    header, *rows = fresh.csv_path.read_text().splitlines()
    assert header.split(",")[-1] == "reach" and "foo" not in header
    assert len(rows) == 1


def test_a_resumed_run_writes_under_a_header_an_editor_saved_with_a_byte_order_mark(
    tmp_path: Path,
) -> None:
    # The first column was read as "\ufeffstep": every row resumed after it lost its step.
    writer = MetricsWriter(tmp_path)
    writer.write({"step": 64, "wall_s": 1.0, "success_rate": 0.5})
    writer.csv_path.write_bytes(b"\xef\xbb\xbf" + writer.csv_path.read_bytes())
    MetricsWriter(tmp_path).write({"step": 128, "wall_s": 2.0, "success_rate": 0.75})
    assert [r.split(",")[0] for r in writer.csv_path.read_text("utf-8-sig").splitlines()[1:]] == [
        "64",
        "128",
    ]


def test_rows_dropped_on_resume_keep_a_damaged_byte_for_the_reports_to_name(tmp_path) -> None:
    # Resuming over a damaged byte stopped with a traceback; read with replacement, the rewrite
    # then turned the byte into U+FFFD for good and the reports could no longer name it.
    path = tmp_path / "eval.csv"
    path.write_bytes(b"env_steps,wall_s,success\n64,1,0.\xff\n128,2,0.5\n192,3,0.6\n")
    assert drop_rows_after(path, 128) == 2
    assert path.read_bytes() == b"env_steps,wall_s,success\r\n64,1,0.\xff\r\n128,2,0.5\r\n"
    with pytest.raises(CurveError, match=r"not UTF-8 text \(byte 33\)"):
        read_curve(tmp_path, 192)


def test_resume_drops_a_row_with_a_damaged_byte_rather_than_keeping_it_altered(tmp_path: Path):
    # Read with the byte replaced, the row was kept with a new column name ("re\ufffdch"),
    # which the rebuilt metrics.csv then carried beside "reach".
    writer = MetricsWriter(tmp_path)
    for step in (64, 128):
        writer.write({"step": step, "wall_s": 0.5, "success_rate": 0.25, "reach": 1.5})
    damaged = writer.jsonl_path.read_bytes().replace(b'"reach"', b'"re\xffch"', 1)
    writer.jsonl_path.write_bytes(damaged)
    writer.csv_path.write_text("")
    MetricsWriter(tmp_path).truncate_after(128)
    assert [r["step"] for r in read_metrics(tmp_path)] == [128]
    assert writer.csv_path.read_text().splitlines()[0].split(",")[-1] == "reach"
