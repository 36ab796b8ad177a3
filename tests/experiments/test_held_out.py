"""The held-out check: each finished cell's final or best policy on episodes no run saw, once."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from itskill.cli import app
from itskill.experiments.config import EvalSettings, ExperimentConfig
from itskill.experiments.held_out import HELD_OUT_FILE, measure_held_out
from itskill.experiments.report import ReportError, experiment_report
from itskill.experiments.runner import Cell, ExperimentRunError, run_experiment
from itskill.files import write_json
from itskill.rl.checkpoint import as_policy
from itskill.tasks import get_task
from itskill.tasks.evaluate import HELD_OUT_SEED, evaluate

TASK = "pickplace_nut_m12"


@pytest.fixture
def run(tmp_path: Path) -> Path:
    """A finished run of No_Transfer, two seeds of a few hundred env-steps."""
    config = ExperimentConfig(
        name="tiny", tasks=(TASK,), methods=("no_transfer",), seeds=(0, 1), steps=128,
        eval=EvalSettings(every=128, episodes=2), algo="a2c", num_envs=2,
    )  # fmt: skip
    run_dir = tmp_path / "run"
    summary = run_experiment(config, run_dir, "local", 1)
    assert not summary.failed
    return run_dir


def test_final_policies_are_measured_on_held_out_episodes_once(run: Path) -> None:
    heard = []
    summary = measure_held_out(run, 3, workers=1, on_cell=lambda c, r, e: heard.append((c, e)))
    cells = [Cell(TASK, "no_transfer", s) for s in (0, 1)]
    assert sorted(summary.measured, key=lambda c: c.seed) == cells and not summary.failed
    assert sorted(c.seed for c, e in heard if e is None) == [0, 1]
    for cell in cells:
        record = json.loads((cell.dir(run) / HELD_OUT_FILE).read_text())
        again = evaluate(get_task(TASK), as_policy(cell.dir(run)), 3, HELD_OUT_SEED, 25)
        assert record["success"] == again.success_rate and record["episodes"] == 3
        assert record["outcomes"] == [int(o) for o in again.outcomes]
        assert record["seed"] == HELD_OUT_SEED and record["num_timesteps"] >= 128
    # Measured once; another episode count, or a cell trained on since, is measured again.
    assert [c.seed for c in measure_held_out(run, 3, workers=1).skipped] == [0, 1]
    path = cells[1].dir(run) / HELD_OUT_FILE
    write_json(path, {**json.loads(path.read_text()), "num_timesteps": 64})
    again = measure_held_out(run, 3, workers=1)
    assert again.measured == [cells[1]] and again.skipped == [cells[0]]
    assert [c.seed for c in measure_held_out(run, 4, workers=1).measured] == [0, 1]


def test_best_policies_are_measured_beside_the_final_ones(run: Path) -> None:
    summary = measure_held_out(run, 2, workers=1, policy="best")
    cells = [Cell(TASK, "no_transfer", s) for s in (0, 1)]
    assert sorted(summary.measured, key=lambda c: c.seed) == cells and not summary.failed
    for cell in cells:
        best = cell.dir(run) / "best"
        record = json.loads((best / HELD_OUT_FILE).read_text())
        again = evaluate(get_task(TASK), as_policy(best), 2, HELD_OUT_SEED, 25)
        assert record["policy"] == "best" and record["success"] == again.success_rate
        assert (
            record["num_timesteps"]
            == json.loads((best / "checkpoint.json").read_text())["num_timesteps"]
        )
        assert not (cell.dir(run) / HELD_OUT_FILE).exists()  # the final policy is not measured
    # A cell that kept no best policy fails by name; the final policies are another check.
    shutil.rmtree(cells[1].dir(run) / "best")
    again = measure_held_out(run, 3, workers=1, policy="best")
    assert again.measured == [cells[0]] and "no best policy kept" in again.failed[cells[1]]
    assert [c.seed for c in measure_held_out(run, 3, workers=1).measured] == [0, 1]
    with pytest.raises(ValueError, match="unknown policy 'worst'; expected one of final, best"):
        measure_held_out(run, 3, policy="worst")


def test_a_cell_without_its_weights_fails_by_name_and_the_others_are_measured(
    run: Path, tmp_path: Path
) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    (Cell(TASK, "no_transfer", 1).dir(copy) / "checkpoint.json").unlink()
    result = CliRunner().invoke(app, ["experiment", "held-out", str(copy), "--episodes", "2"])
    assert result.exit_code == 1
    assert "no_transfer/seed_1: failed:" in result.output
    assert "1 cells measured, 0 already measured, 1 failed" in result.output
    assert (Cell(TASK, "no_transfer", 0).dir(copy) / HELD_OUT_FILE).is_file()


def test_a_cell_without_a_readable_result_is_counted_as_not_finished(run: Path) -> None:
    # It said "0 cells measured, 0 already measured, 0 failed", as if there were nothing to do.
    (Cell(TASK, "no_transfer", 1).dir(run) / "result.json").write_text("{")
    result = CliRunner().invoke(app, ["experiment", "held-out", str(run), "--episodes", "2"])
    assert result.exit_code == 0, result.output
    flat = " ".join(result.output.split())
    assert "1 cells measured, 0 already measured, 0 failed, 1 not finished" in flat
    assert f"--resume--out{run}`finishesthem" in "".join(flat.split())  # wrapped anywhere
    assert not (Cell(TASK, "no_transfer", 1).dir(run) / HELD_OUT_FILE).exists()


def test_a_policy_trained_on_an_earlier_definition_of_its_task_is_not_measured(
    run: Path,
) -> None:
    # Its figure would have been of another task: other stages to see, another success.
    meta_path = Cell(TASK, "no_transfer", 1).dir(run) / "checkpoint.json"
    meta = json.loads(meta_path.read_text())
    write_json(meta_path, {**meta, "task_sha256": "0" * 64})
    summary = measure_held_out(run, 2, workers=1)
    assert summary.measured == [Cell(TASK, "no_transfer", 0)]
    assert "as the task was then" in summary.failed[Cell(TASK, "no_transfer", 1)]
    del meta["task_sha256"]  # a checkpoint from before the fingerprint: measured as it is
    write_json(meta_path, meta)
    assert measure_held_out(run, 2, workers=1).measured == [Cell(TASK, "no_transfer", 1)]


def test_a_directory_that_is_not_a_run_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ExperimentRunError, match="not an experiment run directory"):
        measure_held_out(tmp_path, 2)
    result = CliRunner().invoke(app, ["experiment", "held-out", str(tmp_path)])
    assert result.exit_code == 2 and "not an experiment run directory" in result.output


def test_the_report_sets_held_out_success_beside_the_evaluation_of_each_policy(
    run: Path, tmp_path: Path
) -> None:
    # Each seed: its best policy chosen by an evaluation of 90%, its last evaluation 75%.
    for seed, held in enumerate((0.5, 0.25)):
        cell = Cell(TASK, "no_transfer", seed).dir(run)
        steps = json.loads((cell / "result.json").read_text())["num_timesteps"]
        rows = (cell / "eval.csv").read_text().splitlines()
        (cell / "eval.csv").write_text("\n".join([*rows[:-1], _with_success(rows[-1], 0.75)]))
        write_json(cell / HELD_OUT_FILE, {"success": held, "episodes": 200,
                                          "num_timesteps": steps})  # fmt: skip
        best = cell / "best"
        meta = json.loads((best / "checkpoint.json").read_text())
        meta["selection"]["success"] = 0.9
        write_json(best / "checkpoint.json", meta)
        write_json(best / HELD_OUT_FILE, {"success": 0.0, "episodes": 200,
                                          "num_timesteps": meta["num_timesteps"]})  # fmt: skip
    md = experiment_report(run, tmp_path / "report", video=False).markdown.read_text()
    assert "### Policies on held-out episodes" in md
    # Final: held out 50% and 25% (mean 37.5%); last evaluation 75% twice: 37.5 points higher.
    assert "| No_Transfer | final | 2 | 37.5% [" in md and "| 75.0% (all 2 seeds) | +37.5 [" in md
    # Best: held out 0% twice against the 90% that chose it (its record's: a resumed run may
    # have evaluated again at its env-steps).
    assert "| No_Transfer | best | 2 | 0.0% (all 2 seeds) | 90.0% (all 2 seeds) | +90.0 (all" in md
    assert "on 200 episodes no run trains or evaluates on" in md
    # Copied with the report, which can be written again from its copy.
    copy = tmp_path / "report"
    assert (Cell(TASK, "no_transfer", 0).dir(copy) / HELD_OUT_FILE).is_file()
    assert (Cell(TASK, "no_transfer", 0).dir(copy) / "best" / HELD_OUT_FILE).is_file()
    again = experiment_report(copy, copy, video=False).markdown.read_text()
    assert "| No_Transfer | best | 2 | 0.0% (all 2 seeds) | 90.0% (all 2 seeds) |" in again
    # A measurement of another best policy (chosen since) is left out, not shown as this one's.
    stale = Cell(TASK, "no_transfer", 1).dir(run) / "best" / HELD_OUT_FILE
    write_json(stale, {**json.loads(stale.read_text()), "num_timesteps": 1})
    md = experiment_report(run, tmp_path / "stale", video=False).markdown.read_text()
    assert "| No_Transfer | best | 1 | 0.0% | 90.0% | +90.0 |" in md
    # A run directory, its best policy's weights included, is no report's copy to overwrite.
    with pytest.raises(ReportError, match="its cells hold weights or logs"):
        experiment_report(copy, run, video=False)


def test_the_command_measures_best_policies_by_name(run: Path) -> None:
    from itskill.cli.experiment import PolicyChoice
    from itskill.experiments.held_out import POLICY_DIRS

    assert [c.value for c in PolicyChoice] == list(POLICY_DIRS)
    result = CliRunner().invoke(
        app, ["experiment", "held-out", str(run), "--episodes", "2", "--policy", "best"]
    )
    assert result.exit_code == 0, result.output
    assert "no_transfer/seed_0 (best): " in result.output and "2 cells measured" in result.output
    assert (Cell(TASK, "no_transfer", 0).dir(run) / "best" / HELD_OUT_FILE).is_file()
    assert not (Cell(TASK, "no_transfer", 0).dir(run) / HELD_OUT_FILE).exists()


def _with_success(row: str, success: float) -> str:
    fields = row.split(",")
    fields[2] = str(success)
    return ",".join(fields)
