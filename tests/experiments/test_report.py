"""The experiment report: every section, from a run directory with known curves."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from itskill.cli import app
from itskill.experiments.config import EvalSettings, ExperimentConfig, ReportSettings
from itskill.experiments.document import Document, to_markdown
from itskill.experiments.provenance import Sessions, machine_facts
from itskill.experiments.report import ReportError, experiment_report, header_section
from itskill.experiments.runner import Cell, read_run_config
from itskill.files import write_json
from itskill.transfer import train_transfer

TASK = "pickplace_nut_m12"
# env-steps 200..1000; ITN reaches 80% at 400 in every seed; No_Transfer at 800, 800 and never.
ITN = [0.5, 0.8, 0.9, 0.9, 0.95]
SCRATCH = {
    0: [0.1, 0.3, 0.6, 0.8, 0.9],
    1: [0.2, 0.4, 0.6, 0.85, 0.9],
    2: [0.1, 0.2, 0.3, 0.5, 0.7],
}


def write_cell(run: Path, cell: Cell, success: list[float]) -> None:
    out = cell.dir(run)
    out.mkdir(parents=True, exist_ok=True)
    # Subtasks finished: ITN gets 2 of pick-and-place's 5 stages at 200 env-steps, No_Transfer 1.
    stages = [min(1.0, s + 0.2 if cell.method == "itn" else s + 0.1) for s in success]
    rows = [
        f"{200 * (i + 1)},{20.0 * (i + 1)},{s},0,1,100,{st:.2f}"
        for i, (s, st) in enumerate(zip(success, stages, strict=True))
    ]
    (out / "eval.csv").write_text(
        "env_steps,wall_s,success,ci_low,ci_high,mean_length,stages_done\n" + "\n".join(rows) + "\n"
    )
    result = {"task": cell.task, "method": cell.method, "seed": cell.seed, "num_timesteps": 1000}
    write_json(out / "result.json", {**result, "final_success": success[-1]})


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("run")
    config = ExperimentConfig(
        name="synthetic",
        tasks=(TASK,),
        methods=("itn", "no_transfer"),
        seeds=(0, 1, 2, 3),
        steps=1000,
        eval=EvalSettings(every=200, episodes=10),
        reward={TASK: "expert"},
        sources={TASK: "auto"},
        report=ReportSettings(paper_gain={TASK: 0.7222}),
    )
    write_json(run / "config.json", config.to_dict())
    write_json(run / "sources.json", {TASK: ["place_nut_m12", "reach_nut_m12", "pick_nut_m12"]})
    (run / "experiment.toml").write_text('name = "synthetic"\n')
    sessions = Sessions(run / "provenance.json")
    sessions.start()
    sessions.finish(status="complete")
    # The ITN cells hold a real (barely trained) ITN checkpoint for the attention figure and video.
    home = tmp_path_factory.mktemp("home")
    mp = pytest.MonkeyPatch()
    mp.setenv("ITSKILL_HOME", str(home))
    try:
        train_transfer(
            TASK, "itn", seed=0, steps=32, algo="a2c", out=Cell(TASK, "itn", 0).dir(run),
            num_envs=2, n_threads=1, progress=False,
        )  # fmt: skip
    finally:
        mp.undo()
    meta = (Cell(TASK, "itn", 0).dir(run) / "checkpoint.json").read_text()
    for seed in range(3):
        write_cell(run, Cell(TASK, "itn", seed), ITN)
        write_cell(run, Cell(TASK, "no_transfer", seed), SCRATCH[seed])
        for method in ("itn", "no_transfer"):
            (Cell(TASK, method, seed).dir(run) / "checkpoint.json").write_text(meta)
    return run


def test_report_has_every_section_with_the_known_numbers(run, tmp_path):
    files = experiment_report(run, tmp_path / "report", video=False)
    md = files.markdown.read_text()
    for section in (
        "# Experiment report: synthetic",
        "## Provenance",
        "### Configuration",
        "## Task pickplace_nut_m12",
        "Learning curves (Fig. 7)",
        "Success at fractions of the budget (Table II)",
        "Time to 80% success and time efficiency",
        "Attention over one episode (Fig. 8)",
        "### Subtasks finished",
        "## Runs not finished",
    ):
        assert section in md, section
    assert "Source skills: place_nut_m12, reach_nut_m12, pick_nut_m12" in md
    assert re.search(r"The ITN policy of seed \d, the one with the highest final success\.", md)
    # Table II at 20% of the budget (200 env-steps): ITN 50% in every seed.
    # Seeds that agree have no spread to estimate an interval from: said, not shown as ± 0.
    assert "| ITN | 3 | 50.0% (all 3 seeds) |" in md
    # Best evaluation: No_Transfer peaks at 90%, 90% and 70%: mean 83.3%, t-interval ± 28.7,
    # whose upper end a success rate cannot reach.
    assert "| 83.3% [54.6%, 100.0%] |" in md and "best evaluation" in md
    # Subtasks finished at 200 env-steps: 0.7 for ITN in every seed.
    assert "| ITN | 3 | 70.0% (all 3 seeds) |" in md
    assert (tmp_path / "report" / "figures" / f"stages_{TASK}.png").is_file()
    # ITN: 400 env-steps in every seed; No_Transfer: 800, 800 and censored at 1000.
    assert "| ITN | 400 (all 3 seeds) | 0.7 (all 3 seeds) | ≥ 53.8% [" in md
    assert "≥ 867 [" in md and "(1/3 never reached)" in md
    # No_Transfer has a censored seed, so 53.8% [38.6%, 69.1%] is a lower bound: not a
    # shortfall, though its interval lies below the paper's 72.22%.
    assert "≥ 53.8% [38.6%, 69.1%]" in md
    assert "72.22%" in md and "only as a lower bound: the true gain may reach it" in md
    assert "pickplace_nut_m12/itn/seed_3: not started" in md
    assert (tmp_path / "report" / "figures" / f"curves_{TASK}.png").stat().st_size > 10_000
    assert (tmp_path / "report" / "figures" / f"attention_{TASK}.png").is_file()
    html = files.html.read_text()
    assert html.count("data:image/png;base64,") == 3
    assert "<table>" in html and "Fig. 8" in html
    assert not files.notes


def test_report_shows_the_settings_runs_trained_with_and_where_they_differ(run, tmp_path):
    import shutil

    mixed = tmp_path / "mixed"
    shutil.copytree(run, mixed)
    meta_path = Cell(TASK, "no_transfer", 1).dir(mixed) / "checkpoint.json"
    meta = json.loads(meta_path.read_text())
    meta["hyperparams"]["a2c"]["learning_rate"] = 3e-5
    meta_path.write_text(json.dumps(meta))
    # The transfer settings as each cell's transfer.json records them (ITN seed 0's alone has
    # one in the shared run), those its method uses: PST's keep is not ITN's.
    record = json.loads((Cell(TASK, "itn", 0).dir(mixed) / "transfer.json").read_text())
    record["config"]["prior_weight"] = 0.25
    del record["config"]["residual"]  # recorded before the residual: trained without it
    write_json(Cell(TASK, "itn", 1).dir(mixed) / "transfer.json", record)
    same = experiment_report(run, tmp_path / "same", video=False).markdown.read_text()
    assert "### Training settings" in same
    assert "| algorithm | a2c |" in same and "| n_steps | 8 |" in same
    assert "| learning_rate | 0.0007 |" in same
    # Only ITN's runs have them: named, so they are not read as No_Transfer's.
    assert "| attention: weight of the analyzer's prior | 0.5 (ITN) |" in same
    assert "| source-action residual | on (ITN) |" in same
    assert "| fusion: hidden widths | none (ITN) |" in same
    assert "PST: sources kept" not in same
    md = experiment_report(mixed, tmp_path / "report", video=False).markdown.read_text()
    assert (
        "| learning_rate | 0.0007 (ITN seed 0, ITN seed 1, ITN seed 2, No_Transfer seed 0, "
        "No_Transfer seed 2); 3e-05 (No_Transfer seed 1) |" in md
    )
    assert (
        "| attention: weight of the analyzer's prior | 0.5 (ITN seed 0); 0.25 (ITN seed 1) |" in md
    )
    assert "| source-action residual | on (ITN seed 0); off (ITN seed 1) |" in md


def test_every_transfer_setting_a_method_uses_has_a_label_in_the_report():
    from itskill.experiments.report import _TRANSFER_SETTING_LABELS
    from itskill.transfer import METHODS

    assert {name for m in METHODS.values() for name in m.settings} <= set(_TRANSFER_SETTING_LABELS)


@pytest.mark.slow  # software rendering: about 0.1-0.4 s per frame
def test_report_films_the_best_methods_final_policy(run, tmp_path):
    files = experiment_report(run, tmp_path / "report")
    md, html = files.markdown.read_text(), files.html.read_text()
    assert "Rollout of the best method's final policy" in md
    if files.notes:  # no OpenGL here: the report says so instead of failing
        assert any("no video" in n for n in files.notes) and "No video" in md
    else:
        video = tmp_path / "report" / "videos" / f"{TASK}_itn_seed0.mp4"
        assert video.stat().st_size > 0 and "<video controls" in html


def test_a_run_committed_without_its_policies_still_gets_a_report(run, tmp_path):
    # results/ keeps curves and results, not checkpoints: the video is left out, with a note.
    import shutil

    kept = tmp_path / "kept"
    shutil.copytree(run, kept)
    for meta in kept.glob("cells/*/*/*/checkpoint.json"):
        meta.unlink()
    files = experiment_report(kept, tmp_path / "report")
    assert "Success at fractions of the budget (Table II)" in files.markdown.read_text()
    assert any("no video" in n and "checkpoint.json" in n for n in files.notes)


@pytest.mark.parametrize(
    ("recorded_by", "said"),
    [
        (("itn", "no_transfer"), "every 200 env-steps, each seed on episodes of its own."),
        ((), "the same episodes for every seed (runs from before each seed had its own"),
        (("itn",), "the same episodes for 3 of the runs (runs from before each seed had its own"),
    ],
)
def test_a_report_says_whether_its_seeds_had_evaluation_episodes_of_their_own(
    run, tmp_path, recorded_by, said
):
    """Runs from before 2026-12-06, 15:25 UTC, recorded no evaluation seed: every seed used
    seed 0's episodes."""
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    for path in copy.glob("cells/*/*/seed_*/checkpoint.json"):
        meta = json.loads(path.read_text())
        meta["evaluation"] = {"every": 200, "episodes": 10}
        if path.parent.parent.name in recorded_by:
            meta["evaluation"]["seed"] = 20_000 + int(path.parent.name.removeprefix("seed_"))
        path.write_text(json.dumps(meta))
    md = " ".join(experiment_report(copy, video=False).markdown.read_text().split())
    assert said in md


def test_a_run_of_a_task_not_defined_here_still_gets_a_report(run, tmp_path):
    # A run made on another machine with its own task file: the report raised UnknownTaskError.
    import shutil

    kept = tmp_path / "kept"
    shutil.copytree(run, kept)
    # Every record names the task as that machine did, the cells' results too.
    for path in [kept / "config.json", kept / "sources.json", *kept.glob("cells/**/result.json")]:
        path.write_text(path.read_text().replace(TASK, "elsewhere_task"))
    (kept / "cells" / TASK).rename(kept / "cells" / "elsewhere_task")
    files = experiment_report(kept, tmp_path / "report")
    text = files.markdown.read_text()
    assert "Success at fractions of the budget (Table II)" in text
    assert "No video: the task is not defined here" in text
    assert (tmp_path / "report" / "figures" / "stages_elsewhere_task.png").is_file()


def test_a_report_written_elsewhere_can_be_written_again_from_its_own_directory(run, tmp_path):
    # The directory committed to results/: the report and the run's small files, no weights.
    out = tmp_path / "results"
    first = experiment_report(run, out, video=False).markdown.read_text()
    itn = Cell(TASK, "itn", 0).dir(out)
    assert sorted(p.name for p in itn.iterdir()) == [
        "attention.json", "checkpoint.json", "eval.csv", "metrics.csv", "result.json",
        "transfer.json",
    ]  # fmt: skip
    assert not list(out.glob("cells/**/*.safetensors")) and not list(out.glob("cells/**/*.zip"))
    again = experiment_report(out, video=False)
    second = again.markdown.read_text()
    assert not again.notes
    for section in ("Attention over one episode (Fig. 8)", "### Training settings"):
        assert section in second

    def body(md: str, run_dir: Path) -> list[str]:  # the header names the directory and time
        md = md.replace(str(run_dir.resolve()), "RUN")
        return [line for line in md.splitlines() if not line.startswith("- report written:")]

    assert body(second, out) == body(first, run)


def test_a_reports_copy_gets_its_report_with_a_note_for_the_video(run, tmp_path):
    # The copy's cells keep checkpoint.json but not the weights: `report COPY` failed on them
    # unless --no-video was given.
    out = tmp_path / "results"
    experiment_report(run, out, video=False)
    files = experiment_report(out)
    md = files.markdown.read_text()
    assert "Success at fractions of the budget (Table II)" in md
    assert "No video: the policy is not in the run directory" in md
    assert any(n.startswith("no video:") and str(out) in n for n in files.notes)


def snapshot(directory: Path) -> dict[str, bytes | None]:
    """Every file's bytes and every directory (None) under ``directory``, by relative path."""
    return {
        str(p.relative_to(directory)): p.read_bytes() if p.is_file() else None
        for p in directory.rglob("*")
    }


def another_run(run: Path, where: Path) -> Path:
    """A copy of ``run`` recorded as another run: its first session is another command's."""
    import shutil

    shutil.copytree(run, where)
    provenance = json.loads((where / "provenance.json").read_text())
    provenance["sessions"][0].update(
        command="itskill experiment run other.toml", started="2020-01-01T00:00:00+00:00"
    )
    write_json(where / "provenance.json", provenance)
    return where


def test_report_out_refuses_a_directory_of_another_run_or_the_users_files(run, tmp_path):
    # `report RUN --out OTHER` overwrote OTHER's records with RUN's and copied RUN's cells in.
    import shutil

    other_run = another_run(run, tmp_path / "other_run")
    other_copy = tmp_path / "other_copy"
    experiment_report(other_run, other_copy, video=False)
    clone = tmp_path / "clone"  # the same run's directory: weights beside the cells' records
    shutil.copytree(run, clone)
    own = tmp_path / "own"
    own.mkdir()
    (own / "config.json").write_text('{"mine": true}\n')
    (own / "report.md").write_text("my notes\n")
    for out, what in [
        (other_run, "another experiment run"),
        (other_copy, "another experiment run"),
        (clone, "an experiment run directory"),
        (own, "files the report writes (report.md, config.json)"),
    ]:
        before = snapshot(out)
        with pytest.raises(ReportError, match="which the report would overwrite") as err:
            experiment_report(run, out, video=False)
        assert str(err.value).startswith(f"{out}: holds {what}")
        assert snapshot(out) == before, out


def test_report_out_writes_the_same_runs_report_again(run, tmp_path):
    # Regenerating the report of a run into its results folder, beside the user's own notes.
    out = tmp_path / "results"
    out.mkdir()
    (out / "README.md").write_text("notes\n")
    first = experiment_report(run, out, video=False)
    first.markdown.write_text("stale\n")
    again = experiment_report(run, out, video=False)
    assert "# Experiment report: synthetic" in again.markdown.read_text()
    assert (out / "README.md").read_text() == "notes\n"
    assert (out / "config.json").read_bytes() == (run / "config.json").read_bytes()
    # A copy taken while the run's first session was going: its record of that session ends
    # differently, it starts the same.
    provenance = json.loads((run / "provenance.json").read_text())
    provenance["sessions"][0].update(finished=None, wall_s=None, status=None)
    write_json(out / "provenance.json", provenance)
    experiment_report(run, out, video=False)
    assert (out / "provenance.json").read_bytes() == (run / "provenance.json").read_bytes()
    # And the copy reported from itself, into itself.
    assert not experiment_report(out, video=False).notes


def test_a_report_cut_short_into_a_new_out_can_be_written_again(run, tmp_path, monkeypatch):
    # Interrupted after its figures (Ctrl-C in the video): out held figures/ but no record of
    # the run, so every later report into it was refused as overwriting files of another.
    from itskill.experiments import report

    out = tmp_path / "results"

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(report, "write_document", interrupted)
        with pytest.raises(KeyboardInterrupt):
            experiment_report(run, out, video=False)
    assert (out / "figures").is_dir() and not (out / "report.md").exists()
    assert "# Experiment report" in experiment_report(run, out, video=False).markdown.read_text()


def test_a_damaged_result_is_not_counted_and_says_how_to_finish_it(run, tmp_path):
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    (Cell(TASK, "no_transfer", 2).dir(damaged) / "result.json").write_text("")
    md = experiment_report(damaged, tmp_path / "report", video=False).markdown.read_text()
    assert "5 of 8 runs finished" in md
    assert "no_transfer/seed_2: its result.json cannot be read" in md and "--resume" in md


def test_a_damaged_curve_is_noted_for_its_cell_and_the_rest_is_reported(run, tmp_path):
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    eval_csv = Cell(TASK, "no_transfer", 2).dir(damaged) / "eval.csv"
    eval_csv.write_bytes(eval_csv.read_bytes() + b"\xff\xfe\n")
    files = experiment_report(damaged, tmp_path / "report", video=False)
    md = files.markdown.read_text()
    assert "Success at fractions of the budget (Table II)" in md
    # Left out of every figure: the header and the note say which finished seed is missing.
    assert "5 of 8 runs finished and counted (1 more not counted: see Notes)" in md
    assert any(
        n.startswith(f"{TASK}/no_transfer/seed_2: finished, but not counted in any figure:")
        and str(eval_csv) in n
        and "not UTF-8 text" in n
        for n in files.notes
    )


def test_a_checkpoint_record_of_another_shape_is_in_progress_not_a_traceback(run, tmp_path):
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    cell = Cell(TASK, "no_transfer", 2).dir(damaged)
    (cell / "result.json").unlink()
    (cell / "checkpoint.json").write_text("[1, 2]")
    md = experiment_report(damaged, tmp_path / "report", video=False).markdown.read_text()
    assert "no_transfer/seed_2: in progress (its checkpoint.json cannot be read)" in md


def test_runs_recorded_without_subtask_progress_still_get_a_report(run, tmp_path):
    import shutil

    old = tmp_path / "old"
    shutil.copytree(run, old)
    eval_csv = Cell(TASK, "no_transfer", 1).dir(old) / "eval.csv"
    lines = eval_csv.read_text().splitlines()
    eval_csv.write_text("\n".join(line.rsplit(",", 1)[0] for line in lines) + "\n")
    files = experiment_report(old, tmp_path / "report", video=False)
    md = files.markdown.read_text()
    assert "Success at fractions of the budget (Table II)" in md
    assert "### Subtasks finished" not in md
    assert any("no subtask progress" in n and "stages_done" in n for n in files.notes)


def test_report_refuses_a_directory_that_is_not_a_run(tmp_path):
    with pytest.raises(ReportError, match="not an experiment run directory"):
        experiment_report(tmp_path)


def test_config_json_round_trips_for_the_report(run):
    assert read_run_config(run).report.paper_gain == {TASK: 0.7222}


def test_the_papers_gain_is_judged_by_the_interval_against_no_transfer():
    import numpy as np

    from itskill.experiments.analysis import Threshold
    from itskill.experiments.report import _gain_explanation

    def reached(*steps: float) -> Threshold:
        values = np.asarray(steps, float)
        return Threshold(values, values / 10, np.ones(len(values), bool), 1000.0)

    # ITN 400 env-steps on average, No_Transfer 800: 50% [24%, 76%]. The table's baseline may
    # be another method; the paper's figure is against No_Transfer.
    thresholds = {
        "itn": reached(300, 400, 500),
        "pst": reached(390, 400, 410),
        "no_transfer": reached(700, 800, 900),
    }
    text = _gain_explanation(0.8, thresholds, 0.7222)
    assert "measured here: 50.0% [" in text
    assert "is consistent with it: the paper's figure lies inside the interval" in text
    assert "beats it: the whole interval lies above it" in _gain_explanation(0.8, thresholds, 0.2)
    below = _gain_explanation(0.8, thresholds, 0.9)
    assert "falls short of it: the whole interval lies below it" in below
    no_interval = "cannot be compared with it: one seed, or seeds that all agree, give no interval"
    one = {"itn": reached(400), "no_transfer": reached(700, 900)}
    assert no_interval in _gain_explanation(0.8, one, 0.7222)
    # Times fall on evaluation steps, so seeds often agree exactly: that is not certainty.
    agreeing = {"itn": reached(400, 400, 400), "no_transfer": reached(800, 800, 800)}
    text = _gain_explanation(0.8, agreeing, 0.7222)
    assert "50.0% (the seeds agree: no spread" in text and no_interval in text


def test_a_gain_neither_method_reached_is_explained_not_computed():
    import numpy as np

    from itskill.curves import Curve
    from itskill.experiments.analysis import time_to_threshold
    from itskill.experiments.report import _gain_explanation

    never = Curve(np.array([100.0, 200.0]), np.zeros(2), np.array([1.0, 2.0]), 200.0)
    thresholds = {m: time_to_threshold([never, never], 0.8) for m in ("itn", "no_transfer")}
    text = _gain_explanation(0.8, thresholds, 0.7222)
    assert "72.22%" in text and "neither reached 80% in any seed within the budget" in text


def test_a_cell_stopped_before_its_first_evaluation_is_a_note_not_a_traceback(run, tmp_path):
    # An eval.csv with its header alone was read as an empty curve: `itskill report` stopped
    # with a traceback ("zero-size array").
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    eval_csv = Cell(TASK, "no_transfer", 2).dir(damaged) / "eval.csv"
    eval_csv.write_text(eval_csv.read_text().splitlines()[0] + "\n")
    result = CliRunner().invoke(app, ["report", str(damaged), "--no-video"])
    assert result.exit_code == 0, result.output
    assert f"{eval_csv}: no evaluations" in " ".join(result.output.split())
    assert "5 of 8 runs finished and counted" in (damaged / "report.md").read_text()


EXPERIMENT = """
name = "synthetic"
tasks = ["pickplace_nut_m12"]
methods = ["itn", "no_transfer"]
steps = 1000
[eval]
every = 200
episodes = 10
"""


def test_experiment_run_reports_as_itskill_report_does(run, tmp_path, monkeypatch):
    # Its report's notes were not printed, and a run it could not report on was a traceback.
    import shutil

    from itskill.experiments import runner

    kept = tmp_path / "kept"
    shutil.copytree(run, kept)
    for meta in kept.glob("cells/*/*/*/checkpoint.json"):
        meta.unlink()  # no policy to film: the report says so in a note
    experiment = tmp_path / "synthetic.toml"
    experiment.write_text(EXPERIMENT)

    def ran(run_dir: Path):  # the cells are trained already: what the report sees matters
        monkeypatch.setattr(runner, "run_experiment", lambda *args: runner.RunSummary(run_dir))
        args = ["experiment", "run", str(experiment), "--out", str(tmp_path / "out")]
        return CliRunner().invoke(app, args)

    reported = ran(kept)
    assert reported.exit_code == 0, reported.output
    assert "note: no video" in " ".join(reported.output.split())
    # Rich folds the paths anywhere, even inside a name.
    assert f"report:{kept / 'report.md'}" in "".join(reported.output.split())
    refused = ran(tmp_path / "nothing")
    assert refused.exit_code == 2, refused.output
    assert "error: " in refused.output and "not an experiment run directory" in refused.output
    assert "Traceback" not in refused.output


def _bare_run(tmp_path: Path, **report) -> Path:
    """A run directory with its records and no cells: what the report reads before the cells."""
    run = tmp_path / "bare"
    run.mkdir()
    config = ExperimentConfig(
        name="bare",
        tasks=(TASK,),
        methods=("no_transfer",),
        seeds=(0,),
        steps=1000,
        eval=EvalSettings(every=200, episodes=10),
        reward={TASK: "expert"},
        sources={TASK: "auto"},
    ).to_dict()
    config["report"].update(report)
    write_json(run / "config.json", config)
    (run / "experiment.toml").write_text('name = "bare"\n')
    return run


def test_an_experiment_copy_that_is_not_utf8_is_a_report_error(tmp_path):
    # UnicodeDecodeError traceback, after a report --out had already copied the run's files.
    run = _bare_run(tmp_path)
    (run / "experiment.toml").write_bytes(b'name = "caf\xe9"\n')
    out = tmp_path / "out"
    with pytest.raises(ReportError, match=r"experiment\.toml: not UTF-8 text"):
        experiment_report(run, out, video=False)
    assert not out.exists()
    result = CliRunner().invoke(app, ["report", str(run), "--no-video"])
    assert result.exit_code == 2, result.output
    assert "not UTF-8 text" in result.output and "Traceback" not in result.output


def test_an_empty_out_is_refused_rather_than_taken_for_the_current_directory(tmp_path):
    run = _bare_run(tmp_path)
    result = CliRunner().invoke(app, ["report", str(run), "--no-video", "--out", ""])
    assert result.exit_code == 2 and "name a directory for the report" in result.output


@pytest.mark.parametrize(
    ("file", "text", "problem"),
    [
        ("provenance.json", '{"sessions": 5}', "sessions: expected a list, got 5"),
        ("provenance.json", "[]", "expected a JSON object, got []"),
        ("provenance.json", '{"sessions": [{"command": 5}]}', "sessions[0].command: expected"),
        ("sources.json", "[1]", "expected an object of task -> list of source skill names"),
    ],
)
def test_an_edited_run_record_is_named_before_anything_is_written(tmp_path, file, text, problem):
    # Well-formed JSON of another shape was a TypeError or KeyError traceback deep in the
    # report, after --out had been filled with a copy of the run.
    run = _bare_run(tmp_path)
    (run / file).write_text(text)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["report", str(run), "--no-video", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert problem in " ".join(result.output.split()) and "Traceback" not in result.output
    assert not out.exists()


@pytest.mark.parametrize(
    ("report", "where"),
    [
        ({"threshold": "x"}, "report.threshold"),
        ({"threshold": 0}, "report.threshold"),
        ({"fractions": [0.5, "x"]}, "report.fractions"),
        ({"grid_points": 1.5}, "report.grid_points"),
        ({"paper_gain": {TASK: "high"}}, "report.paper_gain"),
    ],
)
def test_an_edited_config_json_is_a_report_error_not_a_format_traceback(tmp_path, report, where):
    # report.threshold = "x" failed deep in the report: "Unknown format code '%' for str".
    run = _bare_run(tmp_path, **report)
    with pytest.raises(ReportError, match=rf"config.json: {where}\S*: expected .*was it edited\?"):
        experiment_report(run, video=False)
    result = CliRunner().invoke(app, ["report", str(run), "--no-video"])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output


def test_a_learn_report_of_dfs_says_it_has_no_attention_weights_rather_than_failing(tmp_path):
    # Its attention was traced like ITN's: "attention trace of ... failed: ValueError" in the
    # notes and "No attention figure: ValueError ..." in the report, as if the run were broken.
    from itskill.experiments.report import learn_report

    learn_dir = tmp_path / "learn"
    train_transfer(
        TASK, "dfs", "pick_nut_m12,place_nut_m12", steps=16, algo="a2c",
        out=learn_dir / "transfer", num_envs=2, eval_every=8, eval_episodes=2, n_threads=1,
        progress=False,
    )  # fmt: skip
    (learn_dir / "reward").mkdir()
    (learn_dir / "reward" / "best_reward.py").write_text("def reward(obs):\n    return 0.0\n")
    summary = {
        "command": "Pick up the nut and place it on the bolt",
        "budget": "test",
        "plan": {"task": TASK, "objects": ["nut", "bolt"], "subtasks": ["pick", "place"],
                 "actions": ["approach", "grasp", "lift", "approach", "place"]},
        "reward": {"iterations": 1, "samples": 1, "llm": "offline", "best_success": 0.0,
                   "run_dir": "reward", "best_path": "reward/best_reward.py"},
        "transfer": {"run_dir": "transfer", "policy_dir": "transfer/best", "method": "dfs",
                     "algo": "a2c", "steps": 16, "wall_s": 1.0, "final_success": 0.0,
                     "sources": ["pick_nut_m12", "place_nut_m12"], "contribution": None},
        "evaluation": {"success_rate": 0.0, "episodes": 4, "ci_low": 0.0, "ci_high": 0.49},
        "video": False,
    }  # fmt: skip
    files = learn_report(learn_dir, summary)
    text = " ".join(files.markdown.read_text().split())
    assert "DFS has no attention weights" in text
    assert "No attention figure" not in text
    assert not any("attention" in note for note in files.notes), files.notes
    assert not (learn_dir / "figures" / f"attention_{TASK}.png").exists()


def _baseline_run(tmp_path: Path, meta: str | None = None, **changes) -> Path:
    """A run of No_Transfer alone with twice the synthetic run's budget; its seed 2, which never
    reached 80% within 1000 env-steps there, reaches it at 1400. ``meta``: its cells'
    checkpoint.json."""
    base = tmp_path / "baseline"
    settings = dict(
        name="longer",
        tasks=(TASK,),
        methods=("no_transfer",),
        seeds=(0, 1, 2),
        steps=2000,
        eval=EvalSettings(every=200, episodes=10),
        reward={TASK: "expert"},
    )
    write_json(base / "config.json", ExperimentConfig(**{**settings, **changes}).to_dict())
    for seed in range(3):
        cell = Cell(TASK, "no_transfer", seed)
        write_cell(base, cell, SCRATCH[seed] + [0.75, 0.8, 0.9, 0.9, 0.9])
        if meta is not None:
            (cell.dir(base) / "checkpoint.json").write_text(meta)
    return base


def test_a_baseline_run_with_a_longer_budget_measures_the_gain_the_budget_cut_off(run, tmp_path):
    files = experiment_report(
        run, tmp_path / "report", video=False, baseline_run=_baseline_run(tmp_path)
    )
    md = files.markdown.read_text()
    # No_Transfer: 800, 800 and 1400 (censored at 1000 in the run itself): a mean of 1000, and
    # ITN's 400 is 60% fewer, measured rather than a lower bound of 53.8%.
    assert "| No_Transfer | 1,000 [139, 1,861] | 1.7 [0.2, 3.1] | — | — |" in md
    assert "| ITN | 400 (all 3 seeds) | 0.7 (all 3 seeds) | 60.0% [25.6%, 94.4%] |" in md
    assert "≥ 53.8%" not in md
    assert (
        f"The No_Transfer runs are those of the experiment run longer ({tmp_path / 'baseline'}) "
        "(seeds 0, 1, 2), 3 finished, trained the same way for 2,000 env-steps" in md
    )
    assert "6 of 8 runs finished" not in md and "3 of 4 runs finished" in md
    # Table II stays at fractions of the run's own budget: No_Transfer's 90%, 90% and 70% at
    # 1000 env-steps, not the 90% all three reach by 2000.
    assert "| No_Transfer | 3 | 13.3% [0.0%, 27.7%] |" in md
    assert "| 83.3% [54.6%, 100.0%] | 90.0% (all 3 seeds) |" in md
    # This run's own No_Transfer cells are not read: its seed 3 is not listed as not started.
    assert "no_transfer/seed_3" not in md and "itn/seed_3: not started" in md


def test_held_out_policies_of_a_longer_baseline_run_say_their_budget(run, tmp_path):
    # They sat beside this run's policies at half their training under one caption.
    base = _baseline_run(tmp_path, meta='{"num_timesteps": 2000}')
    for seed in range(3):
        held = {"num_timesteps": 2000, "success": 0.5, "episodes": 10}
        write_json(Cell(TASK, "no_transfer", seed).dir(base) / "held_out.json", held)
    md = experiment_report(run, tmp_path / "report", video=False, baseline_run=base)
    assert "| No_Transfer (trained 2,000 env-steps) | final | 3 |" in md.markdown.read_text()


def test_a_run_of_itn_alone_gets_its_gain_over_a_baseline_run(run, tmp_path):
    import shutil

    alone = tmp_path / "itn_alone"
    shutil.copytree(run, alone)
    shutil.rmtree(alone / "cells" / TASK / "no_transfer")
    config = read_run_config(run)
    write_json(alone / "config.json", {**config.to_dict(), "methods": ["itn"]})
    files = experiment_report(alone, video=False, baseline_run=_baseline_run(tmp_path))
    md = files.markdown.read_text()
    assert not any(note.startswith("no gains") for note in files.notes)
    assert "1 task(s) × 1 method(s) × 4 seed(s)" in md and "3 of 4 runs finished" in md
    assert "| ITN | 400 (all 3 seeds) | 0.7 (all 3 seeds) | 60.0% [25.6%, 94.4%] |" in md
    assert "72.22%" in md and "measured here: 60.0% [25.6%, 94.4%]" in md
    # Without the baseline run the report says where the gains went.
    alone_report = experiment_report(alone, tmp_path / "no_baseline", video=False)
    assert any(
        note.startswith("no gains: the baseline, No_Transfer, has no runs in this experiment")
        for note in alone_report.notes
    )


@pytest.mark.parametrize(
    ("changes", "problem"),
    [
        ({"algo": "ppo"}, "trained with algo ppo, this run with a2c"),
        ({"eval": EvalSettings(every=200, episodes=50)}, "trained with eval"),
        ({"steps": 800}, "a budget of 800 env-steps, less than this run's 1,000"),
        ({"methods": ("itn",)}, "it has no no_transfer runs of every task of this run"),
        ({"reward": {TASK: "/elsewhere/reward.py"}}, "trained with another reward"),
    ],
)
def test_a_baseline_run_trained_otherwise_is_refused_before_anything_is_written(
    run, tmp_path, changes, problem
):
    with pytest.raises(ReportError, match=problem):
        experiment_report(
            run, tmp_path / "report", video=False, baseline_run=_baseline_run(tmp_path, **changes)
        )
    # Refused before the run's files were copied there.
    assert not (tmp_path / "report").exists()


REWARD = """import numpy as np

def compute_reward(ctx):
    return np.zeros(len(ctx["ee_pos"])), {}
"""


def _with_file_reward(run_dir: Path, code: str | None, recorded: str | None = None) -> None:
    """Make ``run_dir`` a run of a reward file: kept as the run's copy holding ``code`` (None:
    a run from before copies were kept), its cells' checkpoints recording ``recorded`` code."""
    config = json.loads((run_dir / "config.json").read_text())
    write_json(run_dir / "config.json", {**config, "reward": {TASK: "/gone/reward.py"}})
    if code is not None:
        (run_dir / "rewards").mkdir(exist_ok=True)
        (run_dir / "rewards" / f"{TASK}.py").write_text(code)
    for meta in run_dir.glob("cells/*/*/*/checkpoint.json"):
        meta.unlink()
    if recorded is not None:
        sha = hashlib.sha256(recorded.encode()).hexdigest()
        for cell in run_dir.glob("cells/*/*/seed_*"):
            write_json(cell / "checkpoint.json", {"reward": {"kind": "file", "sha256": sha}})


@pytest.mark.parametrize(
    ("mine", "theirs", "problem"),
    [
        ((REWARD, None), (REWARD, None), None),
        ((REWARD, None), (REWARD + "# tuned\n", None), "the reward files' code differs"),
        # A baseline run from before the copies: its checkpoints' sha256 tells.
        ((REWARD, None), (None, REWARD), None),
        ((REWARD, None), (None, REWARD + "# tuned\n"), "the reward files' code differs"),
        ((REWARD, None), (None, None), "keep(s) no copy of the reward file"),
    ],
)
def test_a_baseline_run_of_a_reward_file_is_compared_by_its_code(
    run, tmp_path, mine, theirs, problem
):
    mine_dir = tmp_path / "mine"
    shutil.copytree(run, mine_dir)
    _with_file_reward(mine_dir, *mine)
    base = _baseline_run(tmp_path)
    _with_file_reward(base, *theirs)
    if problem is None:
        md = experiment_report(mine_dir, video=False, baseline_run=base).markdown.read_text()
        assert "| ITN | 400 (all 3 seeds) | 0.7 (all 3 seeds) | 60.0% [25.6%, 94.4%] |" in md
    else:
        with pytest.raises(ReportError, match=re.escape(problem)):
            experiment_report(mine_dir, video=False, baseline_run=base)


def test_a_baseline_run_of_another_version_of_the_expert_reward_is_refused(run, tmp_path):
    # Expert and expert compared equal, however the reward's terms or stages had changed.
    def recorded(sha: str) -> str:
        meta = json.loads((Cell(TASK, "itn", 0).dir(run) / "checkpoint.json").read_text())
        return json.dumps({**meta, "reward": {"kind": "expert", "sha256": sha}})

    mine = tmp_path / "mine"
    shutil.copytree(run, mine)
    for path in mine.glob("cells/*/*/seed_*/checkpoint.json"):
        path.write_text(recorded("a" * 64))
    with pytest.raises(ReportError, match="another version of the expert reward"):
        experiment_report(
            mine, video=False, baseline_run=_baseline_run(tmp_path, recorded("b" * 64))
        )
    same = _baseline_run(tmp_path / "same", recorded("a" * 64))
    assert experiment_report(mine, tmp_path / "report", video=False, baseline_run=same)


def test_a_baseline_run_whose_seeds_shared_their_episodes_is_said(run, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    for path in copy.glob("cells/*/*/seed_*/checkpoint.json"):
        meta = json.loads(path.read_text())
        seed = int(path.parent.name.removeprefix("seed_"))
        meta["evaluation"] = {"every": 200, "episodes": 10, "seed": 20_000 + seed}
        path.write_text(json.dumps(meta))
    old = json.loads(path.read_text())
    old["evaluation"] = {"every": 200, "episodes": 10}
    base = _baseline_run(tmp_path, meta=json.dumps(old))
    md = " ".join(experiment_report(copy, video=False, baseline_run=base).markdown.read_text()
                  .split())  # fmt: skip
    # ITN's three seeds have their own; the baseline run's three shared seed 0's.
    assert "the same episodes for 3 of the runs (runs from before each seed had its own" in md


def _meta(run: Path, **a2c) -> str:
    meta = json.loads((Cell(TASK, "itn", 0).dir(run) / "checkpoint.json").read_text())
    meta["hyperparams"]["a2c"].update(a2c)
    return json.dumps(meta)


def test_a_baseline_run_with_other_recorded_settings_is_refused(run, tmp_path):
    # A task's own learning rate changed between the runs: only the settings table showed it.
    base = _baseline_run(tmp_path, meta=_meta(run, learning_rate=1e-5))
    with pytest.raises(ReportError, match=r"other settings \(a2c.learning_rate: 0.0007 -> 1e-05"):
        experiment_report(run, tmp_path / "report", video=False, baseline_run=base)


def test_a_baseline_run_recorded_before_a_setting_was_added_is_compared_as_it_trained(
    run, tmp_path
):
    # Its checkpoints lack rms_prop_tf_like, which every run before the setting trained without:
    # "rms_prop_tf_like False there, None here" refused it.
    meta = json.loads(_meta(run))
    del meta["hyperparams"]["a2c"]["rms_prop_tf_like"]
    experiment_report(run, tmp_path / "report", video=False,
                      baseline_run=_baseline_run(tmp_path, meta=json.dumps(meta)))  # fmt: skip
    # The other way round: this run trained with TensorFlow's RMSprop, the baseline recorded
    # before the setting (without it) with PyTorch's. Passed, the filled-in value one-sided.
    mine = json.loads(_meta(run, rms_prop_tf_like=True))
    swapped = tmp_path / "swapped"
    shutil.copytree(run, swapped)
    (Cell(TASK, "itn", 0).dir(swapped) / "checkpoint.json").write_text(json.dumps(mine))
    with pytest.raises(ReportError, match=r"a2c.rms_prop_tf_like: False -> True: the baseline"):
        base = _baseline_run(tmp_path / "c", meta=json.dumps(meta))
        experiment_report(swapped, tmp_path / "swapped_report", video=False, baseline_run=base)
    # Another action noise is another network's exploration: refused.
    meta["hyperparams"]["policy"]["log_std_init"] = -1.0  # the task's table says -2.0
    base = _baseline_run(tmp_path / "b", meta=json.dumps(meta))
    with pytest.raises(ReportError, match=r"policy.log_std_init: -2.0 -> -1.0"):
        experiment_report(run, tmp_path / "again", video=False, baseline_run=base)


def test_a_baseline_runs_schedule_and_unfinished_runs_are_said(run, tmp_path):
    base = _baseline_run(tmp_path, meta=_meta(run), seeds=(0, 1, 2, 3))
    md = experiment_report(run, tmp_path / "report", video=False, baseline_run=base)
    text = " ".join(md.markdown.read_text().split())
    assert json.loads(_meta(run))["hyperparams"]["a2c"]["lr_schedule"] == "linear"
    assert (
        "at 1,000 env-steps it is still at 50% of its start, where this run's has reached zero"
        in text
    )
    assert "baseline run: pickplace_nut_m12/no_transfer/seed_3: not started" in text


def test_the_provenance_lists_each_machine_the_sessions_ran_on(tmp_path):
    # A run resumed on another machine was attributed to that one alone, its wall times too.
    here = machine_facts()
    there = {**here, "cpu_count": 16, "cpu_model": "Other CPU", "torch": "0.0"}
    session = {"command": "itskill experiment run x.toml", "started": "2026-12-07T00:00:00",
               "finished": None, "wall_s": 60.0}  # fmt: skip
    path = tmp_path / "provenance.json"
    path.write_text(json.dumps({"sessions": [{**session, "machine": m}
                                             for m in (here, there, here)]}))  # fmt: skip
    doc = Document("run")
    header_section(doc, Sessions(path), {})
    text = to_markdown(doc, tmp_path)
    assert "sessions 1, 3 ran on machine: " in text
    assert "session 2 ran on machine: 16 × Other CPU" in text and "torch 0.0" in text
    doc = Document("run")
    path.write_text(json.dumps({"sessions": [{**session, "machine": here}]}))
    header_section(doc, Sessions(path), {})
    assert f"- machine: {here['cpu_count']} × " in to_markdown(doc, tmp_path)
