"""The runner trains every cell once: a rerun skips finished cells, a partial cell resumes."""

from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import pytest
from rich.console import Console

from itskill.experiments.config import load_experiment
from itskill.experiments.report import experiment_report
from itskill.experiments.runner import (
    RESULT_FILE,
    Cell,
    ExperimentRunError,
    cells,
    finished_result,
    load_cell_results,
    run_experiment,
)
from itskill.files import directory_lock
from itskill.transfer import train_transfer

TOY = """
name = "toy"
tasks = ["pickplace_nut_m12"]
methods = ["itn", "no_transfer"]
seeds = 2
algo = "a2c"
steps = 256
num_envs = 2
[eval]
every = 128
episodes = 2
"""


@pytest.fixture
def toy(tmp_path: Path):
    path = tmp_path / "toy.toml"
    path.write_text(TOY)
    return load_experiment(path), path


def quiet() -> Console:
    return Console(quiet=True)


def test_runs_every_cell_then_skips_them_all_on_rerun(toy, tmp_path):
    config, path = toy
    run = tmp_path / "run"
    summary = run_experiment(
        config, run, "local", 2, resume=False, source_file=path, console=quiet()
    )
    assert not summary.failed, summary.failed
    assert sorted(c.name for c in summary.finished) == sorted(c.name for c in cells(config))
    results = load_cell_results(run)
    assert len(results) == 4
    for cell, result in results.items():
        assert result["num_timesteps"] >= 256 and result["resumed_from"] == 0
        header = (cell.dir(run) / "eval.csv").read_text().splitlines()[0].split(",")
        assert {"success", "stages_done"} <= set(header)
    assert (run / "experiment.toml").read_text() == TOY
    sources = json.loads((run / "sources.json").read_text())["pickplace_nut_m12"]
    assert sources and all(isinstance(s, str) for s in sources)
    itn = json.loads((Cell("pickplace_nut_m12", "itn", 0).dir(run) / "transfer.json").read_text())
    assert [s["name"] for s in itn["sources"]] == sources

    stamps = {
        c: (
            (c.dir(run) / RESULT_FILE).stat().st_mtime_ns,
            (c.dir(run) / "model.zip").stat().st_mtime_ns,
        )
        for c in results
    }
    with pytest.raises(ExperimentRunError, match="--resume"):
        run_experiment(config, run, "local", 1, console=quiet())
    again = run_experiment(config, run, "local", 1, resume=True, console=quiet())
    assert again.finished == [] and len(again.skipped) == 4
    for c, stamp in stamps.items():
        assert stamp == (
            (c.dir(run) / RESULT_FILE).stat().st_mtime_ns,
            (c.dir(run) / "model.zip").stat().st_mtime_ns,
        )
    # The rerun ran nothing, so it records no session of its own.
    provenance = json.loads((run / "provenance.json").read_text())
    assert [s["status"] for s in provenance["sessions"]] == ["complete"]


def test_jobs_can_be_sent_to_worker_processes(toy, tmp_path):
    """Local workers are spawned and Ray pickles its tasks: a job must pickle."""
    from itskill.experiments.runner import CellSettings, run_cell

    settings = CellSettings("a2c", 256, 2, "expert", ("pick_nut_m12",), "offline", 128, 2, 0.8, "c")
    job = (run_cell, Cell("pickplace_nut_m12", "itn", 0), settings, tmp_path)
    assert pickle.loads(pickle.dumps(job))[1:3] == job[1:3]


def test_partial_cell_resumes_from_its_checkpoint(toy, tmp_path):
    config, _ = toy
    config = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run = tmp_path / "run"
    cell = Cell("pickplace_nut_m12", "no_transfer", 0)
    # A killed cell: a checkpoint half-way and no result.json.
    train_transfer(
        cell.task, cell.method, seed=0, steps=128, algo="a2c", out=cell.dir(run), num_envs=2,
        eval_every=128, eval_episodes=2, n_threads=1, progress=False,
    )  # fmt: skip
    # Cells without config.json are no run to resume, nor a directory a new run may fill.
    with pytest.raises(ExperimentRunError, match="not an experiment run directory"):
        run_experiment(config, run, "local", 1, resume=True, console=quiet())
    with pytest.raises(ExperimentRunError, match=r"holds cells .* new or empty directory"):
        run_experiment(config, run, "local", 1, console=quiet())
    (run / "config.json").write_text(json.dumps(config.to_dict()))  # the run's record
    summary = run_experiment(config, run, "local", 1, resume=True, console=quiet())
    assert summary.resumed == [cell] and summary.finished == [cell]
    result = json.loads((cell.dir(run) / RESULT_FILE).read_text())
    assert result["resumed_from"] == 128 and result["num_timesteps"] >= 256
    assert result["best"]["env_steps"] in (128, result["num_timesteps"])


def test_resume_finishes_again_a_cell_whose_result_was_damaged(toy, tmp_path, capsys):
    config, _ = toy
    config = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run = tmp_path / ":rocket:"  # printed as named, not as an emoji
    run_experiment(config, run, "local", 1)
    assert ":rocket:" in capsys.readouterr().err.replace("\n", "")
    result = Cell("pickplace_nut_m12", "no_transfer", 0).dir(run) / RESULT_FILE
    before = json.loads(result.read_text())
    result.write_text("")
    assert load_cell_results(run) == {}
    summary = run_experiment(config, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.finished] == ["pickplace_nut_m12/no_transfer/seed_0"]
    after = json.loads(result.read_text())
    assert after["num_timesteps"] == before["num_timesteps"]
    assert after["final_success"] == before["final_success"]


def test_resume_refuses_other_training_settings(toy, tmp_path):
    config, _ = toy
    run = tmp_path / "run"
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run_experiment(small, run, "local", 1, console=quiet())
    longer = type(config)(**{**small.__dict__, "steps": 512})
    with pytest.raises(ExperimentRunError, match="steps=256"):
        run_experiment(longer, run, "local", 1, resume=True, console=quiet())


def test_cells_train_with_the_files_hyperparams_and_a_resume_keeps_them(toy, tmp_path):
    """A file that names its hyper-parameters trains the same way after the packaged ones
    change; a resume that names others is refused, and one that names the same goes on."""
    config, _ = toy
    pinned = {"pickplace_nut_m12": {"learning_rate": 3e-4, "policy": {"log_std_init": -1.5}}}
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,),
                            "hyperparams": pinned})  # fmt: skip
    run = tmp_path / "run"
    run_experiment(small, run, "local", 1, console=quiet())
    meta = json.loads((Cell("pickplace_nut_m12", "no_transfer", 0).dir(run) / "checkpoint.json")
                      .read_text())  # fmt: skip
    assert meta["hyperparams"]["a2c"]["learning_rate"] == 3e-4
    assert meta["hyperparams"]["policy"]["log_std_init"] == -1.5
    assert json.loads((run / "config.json").read_text())["hyperparams"] == pinned
    packaged = type(config)(**{**small.__dict__, "hyperparams": {}})
    with pytest.raises(ExperimentRunError, match="hyperparams="):
        run_experiment(packaged, run, "local", 1, resume=True, console=quiet())
    # Checkpointing more often changes nothing a cell learns: a resume may.
    more = {t: {**h, "checkpoint_every": 128} for t, h in pinned.items()}
    more = type(config)(**{**small.__dict__, "seeds": (0, 1), "hyperparams": more})
    summary = run_experiment(more, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.finished] == ["pickplace_nut_m12/no_transfer/seed_1"]
    more = type(config)(**{**more.__dict__, "hyperparams": pinned})
    # A run recorded before files could name them resumes with a file that does.
    record = json.loads((run / "config.json").read_text())
    del record["hyperparams"]
    (run / "config.json").write_text(json.dumps(record))
    more = type(config)(**{**more.__dict__, "seeds": (0, 1, 2)})
    summary = run_experiment(more, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.finished] == ["pickplace_nut_m12/no_transfer/seed_2"]
    assert json.loads((run / "config.json").read_text())["hyperparams"] == pinned


def test_cells_train_with_the_files_transfer_settings_and_a_resume_keeps_them(toy, tmp_path):
    config, _ = toy
    run = tmp_path / "run"
    weighted = {"attention": {"prior_weight": 0.25}}
    small = type(config)(**{**config.__dict__, "methods": ("itn",), "seeds": (0,),
                            "transfer": weighted})  # fmt: skip
    run_experiment(small, run, "local", 1, console=quiet())
    record = json.loads(
        (Cell("pickplace_nut_m12", "itn", 0).dir(run) / "transfer.json").read_text()
    )
    assert record["config"]["prior_weight"] == 0.25
    assert json.loads((run / "config.json").read_text())["transfer"] == weighted
    packaged = type(config)(**{**small.__dict__, "transfer": {}})
    with pytest.raises(ExperimentRunError, match="transfer="):
        run_experiment(packaged, run, "local", 1, resume=True, console=quiet())
    # A run recorded before files could name them resumes with a file that does.
    recorded = json.loads((run / "config.json").read_text())
    del recorded["transfer"]
    (run / "config.json").write_text(json.dumps(recorded))
    summary = run_experiment(small, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.skipped] == ["pickplace_nut_m12/itn/seed_0"]
    # Only the settings the trained methods' networks use count: PST's keep (no PST cell
    # trained) and the analyzer's retries (each cell keeps its matrix) may change.
    with_pst = {**weighted, "pst": {"keep": 2}, "analyzer": {"retries": 5}}
    same = type(config)(**{**small.__dict__, "transfer": with_pst})
    summary = run_experiment(same, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.skipped] == ["pickplace_nut_m12/itn/seed_0"]


def test_a_run_resumed_with_fewer_methods_is_not_refused_for_those_left_out(toy, tmp_path):
    # The ITN and DFS run, resumed to train DFS alone, was refused: ITN's attention settings,
    # which the file for DFS does not list, counted as changed.
    config, _ = toy
    run = tmp_path / "run"
    both = type(config)(**{**config.__dict__, "methods": ("itn", "dfs"), "seeds": (0,)})
    run_experiment(both, run, "local", 1, console=quiet())
    dfs = type(config)(**{**both.__dict__, "methods": ("dfs",)})
    summary = run_experiment(dfs, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.skipped] == ["pickplace_nut_m12/dfs/seed_0"]
    # A setting DFS uses still counts.
    plain = type(config)(**{**dfs.__dict__, "transfer": {"head": {"residual": False}}})
    with pytest.raises(ExperimentRunError, match="transfer="):
        run_experiment(plain, run, "local", 1, resume=True, console=quiet())


def test_a_resume_with_fewer_methods_keeps_the_settings_of_those_left_out(toy, tmp_path):
    # The record took the new file's [transfer] alone: ITN's prior weight was forgotten, a third
    # session with the first file was refused, and one without it trained new ITN seeds at the
    # packaged weight beside the first.
    config, _ = toy
    run = tmp_path / "run"
    weighted = {"attention": {"prior_weight": 0.25}}
    itn = type(config)(**{**config.__dict__, "methods": ("itn",), "seeds": (0,),
                          "transfer": weighted})  # fmt: skip
    run_experiment(itn, run, "local", 1, console=quiet())
    plain = type(config)(**{**itn.__dict__, "methods": ("no_transfer",), "transfer": {}})
    run_experiment(plain, run, "local", 1, resume=True, console=quiet())
    assert json.loads((run / "config.json").read_text())["transfer"] == weighted
    # Named by a file whose methods do not use it, it is not what ITN trained with either.
    other = {"attention": {"prior_weight": 0.125}}
    plain = type(config)(**{**plain.__dict__, "seeds": (0, 1), "transfer": other})
    run_experiment(plain, run, "local", 1, resume=True, console=quiet())
    assert json.loads((run / "config.json").read_text())["transfer"] == weighted
    packaged = type(config)(**{**itn.__dict__, "seeds": (0, 1), "transfer": {}})
    with pytest.raises(ExperimentRunError, match="prior_weight"):
        run_experiment(packaged, run, "local", 1, resume=True, console=quiet())
    again = type(config)(**{**itn.__dict__, "seeds": (0, 1)})
    summary = run_experiment(again, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.finished] == ["pickplace_nut_m12/itn/seed_1"]


def test_new_seeds_are_refused_where_the_packaged_settings_changed_since_the_run_began(
    toy, tmp_path
):
    # The file's settings were compared, the packaged ones under them not: after a release that
    # changed a default, new seeds trained at the new value beside the finished ones.
    config, _ = toy
    run = tmp_path / "run"
    first = type(config)(**{**config.__dict__, "methods": ("itn",), "seeds": (0,)})
    run_experiment(first, run, "local", 1, console=quiet())
    cell = Cell("pickplace_nut_m12", "itn", 0).dir(run)
    more = type(config)(**{**first.__dict__, "seeds": (0, 1)})
    for name, edit, setting in (
        ("checkpoint.json", lambda r: r["hyperparams"]["policy"].update(log_std_init=-9.0),
         "policy.log_std_init: -9.0 -> "),
        ("transfer.json", lambda r: r["config"].update(prior_weight=0.125),
         "prior_weight: 0.125 -> 0.5"),
    ):  # fmt: skip
        kept = (cell / name).read_text()
        record = json.loads(kept)
        edit(record)  # as a release with another default would have recorded it
        (cell / name).write_text(json.dumps(record))
        with pytest.raises(ExperimentRunError, match="packaged defaults having changed") as err:
            run_experiment(more, run, "local", 1, resume=True, console=quiet())
        assert setting in str(err.value)
        assert not Cell("pickplace_nut_m12", "itn", 1).dir(run).exists()
        (cell / name).write_text(kept)
    summary = run_experiment(more, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.finished] == ["pickplace_nut_m12/itn/seed_1"]


def test_new_seeds_alone_are_checked_against_the_runs_finished_cells(toy, tmp_path):
    # A file naming only new seeds has none of the finished cells in its grid: nothing was
    # compared, and the new seeds trained at changed packaged values, a changed expert reward or
    # a changed task.
    config, _ = toy
    run = tmp_path / "run"
    first = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run_experiment(first, run, "local", 1, console=quiet())
    meta_path = Cell("pickplace_nut_m12", "no_transfer", 0).dir(run) / "checkpoint.json"
    kept = meta_path.read_text()
    later = type(config)(**{**first.__dict__, "seeds": (1,)})
    for edit, problem in (
        (lambda r: r["hyperparams"]["policy"].update(log_std_init=-9.0), "policy.log_std_init"),
        (lambda r: r["reward"].update(sha256="0" * 64), "another version of the expert reward"),
        (lambda r: r.update(task_sha256="0" * 64), "trained on the task as it was then"),
    ):
        record = json.loads(kept)
        edit(record)
        meta_path.write_text(json.dumps(record))
        with pytest.raises(ExperimentRunError, match=problem):
            run_experiment(later, run, "local", 1, resume=True, console=quiet())
    meta_path.write_text(kept)
    summary = run_experiment(later, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.finished] == ["pickplace_nut_m12/no_transfer/seed_1"]


def test_a_no_transfer_run_resumed_with_transfer_settings_keeps_its_cells(toy, tmp_path):
    """Its cells use none of them; a default written out is the default."""
    config, _ = toy
    run = tmp_path / "run"
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run_experiment(small, run, "local", 1, console=quiet())
    named = type(config)(**{**small.__dict__, "transfer": {"attention": {"prior_weight": 0.1}}})
    summary = run_experiment(named, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.skipped] == ["pickplace_nut_m12/no_transfer/seed_0"]


def test_pst_keeping_as_many_as_the_file_names_is_refused_before_any_cell(tmp_path):
    from itskill.experiments.config import ExperimentConfigError

    path = tmp_path / "toy.toml"
    named = '[sources]\npickplace_nut_m12 = ["pick_nut_m12", "place_nut_m12"]\n'
    path.write_text(TOY.replace('["itn", "no_transfer"]', '["pst"]') + named
                    + "[transfer.pst]\nkeep = 2\n")  # fmt: skip
    run = tmp_path / "run"
    with pytest.raises(ExperimentConfigError, match="PST keeps 2 of the 2") as err:
        run_experiment(load_experiment(path), run, "local", 1, source_file=path, console=quiet())
    assert err.value.where == "transfer.pst.keep"  # what the file set, not the sources it named
    assert not (run / "config.json").exists()


def test_a_no_transfer_run_resumes_with_other_sources_k_and_analyzer(toy, tmp_path):
    """Its cells never used them, so resuming it to add ITN may name them anew; the ITN run,
    its sources named, then takes another k too (it retrieves nothing)."""
    config, _ = toy
    run = tmp_path / "run"
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run_experiment(small, run, "local", 1, console=quiet())
    other = {"sources": {"pickplace_nut_m12": ("pick_nut_m12", "place_nut_m12")}, "k": 2,
             "llm": "openai:some-model"}  # fmt: skip
    unchanged = type(config)(**{**small.__dict__, **other})
    summary = run_experiment(unchanged, run, "local", 1, resume=True, console=quiet())
    assert [c.name for c in summary.skipped] == [c.name for c in cells(small)]
    assert json.loads((run / "config.json").read_text())["k"] == 2
    with_itn = type(config)(**{**unchanged.__dict__, "methods": ("itn",), "llm": "offline"})
    run_experiment(with_itn, run, "local", 1, resume=True, console=quiet())
    summary = run_experiment(type(config)(**{**with_itn.__dict__, "k": 3}), run, "local", 1,
                             resume=True, console=quiet())  # fmt: skip
    assert not summary.failed


def test_a_run_that_retrieved_its_sources_refuses_another_k(toy, tmp_path):
    config, _ = toy
    run = tmp_path / "run"
    small = type(config)(**{**config.__dict__, "methods": ("dfs",), "seeds": (0,), "k": 2})
    assert small.sources.get("pickplace_nut_m12", "auto") == "auto"
    run_experiment(small, run, "local", 1, console=quiet())
    with pytest.raises(ExperimentRunError, match="k=2"):
        run_experiment(type(config)(**{**small.__dict__, "k": 3}), run, "local", 1,
                       resume=True, console=quiet())  # fmt: skip


def test_resume_refuses_a_reports_copy_of_the_run(toy, tmp_path):
    # The copy (`itskill report RUN --out DIR`, the folder committed to results/) was resumed:
    # its cells failed for want of weights, and new ones trained into the results folder.
    from itskill.experiments.report import experiment_report

    config, _ = toy
    run, copy = tmp_path / "run", tmp_path / "results"
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run_experiment(small, run, "local", 1, console=quiet())
    experiment_report(run, copy, video=False)
    before = sorted(p.relative_to(copy) for p in copy.rglob("*"))
    more = type(config)(**{**small.__dict__, "seeds": (0, 1)})
    with pytest.raises(ExperimentRunError, match="a report's copy of a run"):
        run_experiment(more, copy, "local", 1, resume=True, console=quiet())
    assert sorted(p.relative_to(copy) for p in copy.rglob("*")) == before
    run_experiment(more, run, "local", 1, resume=True, console=quiet())  # the run itself goes on


def test_resume_needs_a_run_and_records_every_sessions_cells(toy, tmp_path):
    config, _ = toy
    run = tmp_path / "run"
    with pytest.raises(ExperimentRunError, match="nothing to resume"):
        run_experiment(config, run, "local", 1, resume=True, console=quiet())
    first = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run_experiment(first, run, "local", 1, console=quiet())
    # A later session adds seed 1 only; its cell failed once in an earlier attempt.
    second = type(config)(**{**first.__dict__, "seeds": (1,)})
    failed = Cell("pickplace_nut_m12", "no_transfer", 1).dir(run)
    failed.mkdir(parents=True)
    (failed / "error.txt").write_text("LLMError: endpoint unreachable\n")
    summary = run_experiment(second, run, "local", 1, resume=True, console=quiet())
    assert [c.seed for c in summary.finished] == [1]
    assert not (failed / "error.txt").exists()
    recorded = json.loads((run / "config.json").read_text())
    assert recorded["seeds"] == [0, 1]  # the report covers both sessions' cells
    assert len(load_cell_results(run)) == 2


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        # A reward search's run directory also has a config.json: it was taken for an
        # experiment's and failed with KeyError: 'eval', or asked for a --resume that then did.
        ('{"kind": "itskill-reward-search", "target": "pick_nut_m12"}', "another kind of run"),
        ('{"name": "toy", "tasks": ', "not valid JSON"),  # cut short, or edited
        ('{"name": "toy"}', r"tasks: missing \(required\); was it edited\?"),
        ("[1, 2]", "expected a table, got list"),
    ],
)
def test_a_directory_that_is_not_an_experiment_run_is_named_as_such(
    toy, tmp_path, content, problem
):
    from itskill.experiments.report import ReportError, experiment_report
    from itskill.files import CorruptFileError

    config, _ = toy
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(content)
    errors = (ExperimentRunError, CorruptFileError)
    for resume in (False, True):
        with pytest.raises(errors, match=problem):
            run_experiment(config, run, "local", 1, resume=resume, console=quiet())
    with pytest.raises((ReportError, CorruptFileError), match=problem):
        experiment_report(run, video=False)


def test_an_executor_that_cannot_run_leaves_no_run_to_resume(toy, tmp_path):
    from itskill.executors import ExecutorError

    config, _ = toy
    run = tmp_path / "run"
    with pytest.raises(ExecutorError, match="needs the Ray executor"):
        run_experiment(config, run, "local", 1, "127.0.0.1:6379", console=quiet())
    assert not (run / "config.json").exists()  # a plain rerun with the fix is not refused


def test_a_file_made_for_a_cluster_runs_here_with_executor_local(toy, tmp_path):
    # The file's Ray address went with `--executor local` and was refused.
    from itskill.experiments.config import ExecutionSettings

    config, _ = toy
    cluster = ExecutionSettings("ray", None, "10.0.0.5:6379")
    small = type(config)(
        **{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,), "execution": cluster}
    )
    summary = run_experiment(small, tmp_path / "run", "local", 1, console=quiet())
    assert [c.seed for c in summary.finished] == [0]


def test_a_resume_keeps_the_runs_name_and_writes_only_what_changes(tmp_path):
    # Resuming with another file recorded that file's name (and copied it over the run's), even
    # with nothing to train; the run's own copy, or a file inside the run, failed to copy onto
    # itself (SameFileError) half-way through.
    run = tmp_path / "exp"
    run.mkdir()
    own = run / "experiment.toml"  # no name: the run is named after the file, "experiment"
    text = TOY.replace('name = "toy"\n', "").replace('["itn", "no_transfer"]', '["no_transfer"]')
    own.write_text(text.replace("seeds = 2", "seeds = [0]"))
    run_experiment(load_experiment(own), run, "local", 1, source_file=own, console=quiet())
    files = ("config.json", "experiment.toml", "sources.json", "provenance.json")
    before = {name: (run / name).read_bytes() for name in files}

    other = tmp_path / "other.toml"
    other.write_text(f'name = "other"\ndescription = "not this run"\n{own.read_text()}')
    summary = run_experiment(
        load_experiment(other), run, "local", 1, resume=True, source_file=other, console=quiet()
    )
    assert summary.finished == [] and len(summary.skipped) == 1
    assert {name: (run / name).read_bytes() for name in files} == before

    # New report settings are recorded, though nothing trains; the run keeps its name.
    own.write_text(own.read_text() + "[report]\nthreshold = 0.5\n")
    run_experiment(
        load_experiment(own), run, "local", 1, resume=True, source_file=own, console=quiet()
    )
    recorded = json.loads((run / "config.json").read_text())
    assert recorded["name"] == "experiment" and recorded["description"] == ""
    assert recorded["report"]["threshold"] == 0.5
    assert (run / "provenance.json").read_bytes() == before["provenance.json"]


def test_a_new_run_refuses_a_directory_of_the_users_files(toy, tmp_path):
    # Their experiment.toml was overwritten, their provenance.json read as the run's.
    config, path = toy
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "experiment.toml").write_text("# my notes\n")
    (mine / "provenance.json").write_text('{"mine": true}\n')
    with pytest.raises(ExperimentRunError) as err:
        run_experiment(config, mine, "local", 1, source_file=path, console=quiet())
    assert str(err.value).startswith(f"{mine}: holds experiment.toml, provenance.json")
    assert "give --out a new or empty directory" in str(err.value)
    assert sorted(p.name for p in mine.iterdir()) == ["experiment.toml", "provenance.json"]
    assert (mine / "experiment.toml").read_text() == "# my notes\n"
    (mine / "experiment.toml").unlink()
    (mine / "provenance.json").unlink()
    (mine / "notes").write_text("x")
    with pytest.raises(ExperimentRunError, match="not a directory"):
        run_experiment(config, mine / "notes", "local", 1, console=quiet())


def test_an_experiment_without_transfer_needs_no_skills(toy, tmp_path, monkeypatch):
    # Every task's sources were resolved whatever the methods: an empty skill space refused it.
    from itskill.skills import store
    from itskill.transfer.sources import SourceError

    monkeypatch.setattr(store, "SHIPPED_LIBRARY", tmp_path / "no_library")
    config, _ = toy
    with pytest.raises(SourceError):  # ITN does need them
        run_experiment(config, tmp_path / "itn", "local", 1, console=quiet())
    alone = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    summary = run_experiment(alone, tmp_path / "run", "local", 1, console=quiet())
    assert [c.method for c in summary.finished] == ["no_transfer"], summary.failed


@pytest.mark.parametrize("recorded", [False, True])
def test_ctrl_c_says_how_to_go_on_only_where_there_is_a_run(toy, tmp_path, monkeypatch, recorded):
    # Stopped before the run existed, the hint gave a --resume that was refused.
    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.experiments import runner

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    # Training starts once the run is recorded; the sources are resolved before.
    monkeypatch.setattr(runner, "run_jobs" if recorded else "resolve_all_sources", interrupted)
    _, path = toy
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["experiment", "run", str(path), "--out", str(out)])
    assert result.exit_code == 130, result.output
    output = " ".join(result.output.split())
    assert (f"continue with: itskill experiment run {path} --out {out} --resume" in output) is (
        recorded
    )
    assert ("no run was recorded yet; run the same command again" in output) is not recorded


def test_a_run_in_use_by_another_session_is_refused_and_left_as_it_is(
    toy, tmp_path, monkeypatch, file_tree
):
    # Two sessions resuming one run trained the same cells into the same files: both failed,
    # and the run could not be finished any more.
    from itskill.experiments import runner

    def stopped(*args, **kwargs):
        raise RuntimeError("stopped before any cell trained")

    monkeypatch.setattr(runner, "run_jobs", stopped)
    config, path = toy
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    run = tmp_path / "run"
    with pytest.raises(RuntimeError, match="stopped"):  # recorded, then stopped
        run_experiment(small, run, "local", 1, source_file=path, console=quiet())
    before = file_tree(run)
    new = tmp_path / "new"
    with directory_lock(run, "experiment"), directory_lock(new, "experiment"):
        for out, resume in ((run, True), (run, False), (new, False)):
            in_use = (
                f"{out} is in use by another itskill experiment run on this machine; wait for "
                "it to end, or stop it and --resume"
            )
            with pytest.raises(ExperimentRunError, match=re.escape(in_use)):
                run_experiment(
                    small, out, "local", 1, resume=resume, source_file=path, console=quiet()
                )
    assert file_tree(run) == before
    assert not new.exists()


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_a_run_holds_its_lock_until_it_ends_however_it_ends(
    toy, tmp_path, monkeypatch, error, lock_held
):
    from itskill.experiments import runner

    run = tmp_path / "run"
    held = []

    def stopped(*args, **kwargs):
        held.append(lock_held(run, "experiment"))
        raise error("stopped before any cell trained")

    monkeypatch.setattr(runner, "run_jobs", stopped)
    config, _ = toy
    small = type(config)(**{**config.__dict__, "methods": ("no_transfer",), "seeds": (0,)})
    with pytest.raises(error):
        run_experiment(small, run, "local", 1, console=quiet())
    # Let go: the next session resumes the run (and is stopped where the first one was).
    with pytest.raises(error):
        run_experiment(small, run, "local", 1, resume=True, console=quiet())
    assert held == [True, True]
    assert not lock_held(run, "experiment")


def test_cells_that_ask_no_model_need_no_api_key(tmp_path, monkeypatch):
    # Every cell built the analyzer's client: without a key, a No_Transfer cell and a resumed
    # ITN cell (its transfer.json holds the matrix) failed with "no API key".
    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.experiments.runner import resolve_all_sources

    for name in ("OPENAI_API_KEY", "OPENAI_BASE_URL", "ITSKILL_LLM_MODEL"):
        monkeypatch.delenv(name, raising=False)
    path = tmp_path / "toy.toml"
    path.write_text('llm = "openai:gpt-4o"\n' + TOY.replace("seeds = 2", "seeds = 1"))
    config = load_experiment(path)
    run = tmp_path / "run"
    sources = resolve_all_sources(config, run)
    itn = Cell("pickplace_nut_m12", "itn", 0)
    train_transfer(
        itn.task, itn.method, sources=sources[itn.task], seed=0, steps=128, algo="a2c",
        out=itn.dir(run), num_envs=2, eval_every=128, eval_episodes=2, n_threads=1,
        progress=False,
    )  # fmt: skip  # its analyzer offline: a run interrupted, resumed where no key is set
    (run / "config.json").write_text(json.dumps(config.to_dict()))
    (run / "sources.json").write_text(json.dumps(sources))
    args = ["experiment", "run", str(path), "--out", str(run), "--resume", "--no-report",
            "--executor", "local", "--workers", "1"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "2 cells trained, 0 already done, 0 failed" in " ".join(result.output.split())


@pytest.mark.parametrize("names", [["no_such_skill"], [""]])
def test_a_named_source_skill_that_cannot_be_used_names_the_file_and_field(tmp_path, names):
    # The skill space's error named neither the experiment file nor sources.<task>.
    from itskill.experiments.config import ExperimentConfigError

    path = tmp_path / "toy.toml"
    path.write_text(TOY + f"[sources]\npickplace_nut_m12 = {json.dumps(names)}\n")
    config = load_experiment(path)
    run = tmp_path / "run"
    with pytest.raises(ExperimentConfigError) as err:
        run_experiment(config, run, "local", 1, source_file=path, console=quiet())
    assert str(err.value).startswith(f"{path}: sources.pickplace_nut_m12: ")
    assert not (run / "config.json").exists()  # nothing recorded: no run to --resume
    # From the command line: one line, exit 2.
    from typer.testing import CliRunner

    from itskill.cli import app

    result = CliRunner().invoke(app, ["experiment", "run", str(path), "--out", str(run)])
    assert result.exit_code == 2, result.output
    assert "sources.pickplace_nut_m12" in result.output and "Traceback" not in result.output


def test_an_edited_run_config_is_refused_with_the_field(toy, tmp_path):
    from itskill.experiments.runner import read_run_config

    config, _ = toy
    run = tmp_path / "run"
    run.mkdir()
    data = config.to_dict()
    data["report"]["threshold"] = "x"
    (run / "config.json").write_text(json.dumps(data))
    with pytest.raises(ExperimentRunError, match=r"config.json: report.threshold: expected"):
        read_run_config(run)
    data["report"]["threshold"] = 0.8
    data["seeds"] = [0, "one"]
    (run / "config.json").write_text(json.dumps(data))
    with pytest.raises(ExperimentRunError, match=r"config.json: seeds\[1\]: expected"):
        read_run_config(run)
    data["seeds"] = [0, 1]
    # Read back with the experiment file's own checks, caps included: a resumed run started
    # this many worker processes.
    data["execution"]["workers"] = 10**9
    (run / "config.json").write_text(json.dumps(data))
    with pytest.raises(ExperimentRunError, match=r"execution.workers: must be at most 1,024"):
        read_run_config(run)
    data["execution"]["workers"] = config.execution.workers
    del data["name"]  # was read as the run named "config", after the file
    (run / "config.json").write_text(json.dumps(data))
    with pytest.raises(ExperimentRunError, match=r"config.json: name: missing \(required\)"):
        read_run_config(run)
    data["name"] = config.name
    (run / "config.json").write_text(json.dumps(data))
    assert read_run_config(run) == config  # as recorded, it passes


def test_a_relative_run_directory_reaches_ray_workers_as_an_absolute_path(
    toy, tmp_path, monkeypatch
):
    # A Ray worker runs from a working directory of its own: a relative run directory had it
    # write the cells there, on a cluster node the driver never reads.
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'itskill[ray]')")
    import itskill.experiments.runner as runner_module
    from itskill.executors import run_jobs

    outs: list[Path] = []

    def on_this_machine(fn, jobs, executor, workers, address):
        outs.extend(Path(out) for *_, out in jobs)
        return run_jobs(fn, jobs, "local", 1, None)

    monkeypatch.setattr(runner_module, "run_jobs", on_this_machine)
    monkeypatch.chdir(tmp_path)
    config, path = toy
    run_experiment(config, Path("run"), "ray", 1, source_file=path, console=quiet())
    assert outs and all(out.is_absolute() and out.is_relative_to(tmp_path) for out in outs)


def test_a_reward_file_edited_between_sessions_is_refused_and_cells_train_the_runs_copy(tmp_path):
    # Only paths were compared: the cells still to train learned the edited reward, the
    # finished ones kept the old, and the report averaged the two.
    reward = tmp_path / "r.py"
    reward.write_text(
        "import numpy as np\n\ndef compute_reward(ctx):\n"
        "    d = np.linalg.norm(ctx['obj_to_ee'][:, 0], axis=-1)\n"
        "    return -d, {'distance': -d}\n"
    )
    path = tmp_path / "toy.toml"
    path.write_text(
        TOY.replace(
            'methods = ["itn", "no_transfer"]\nseeds = 2', 'methods = ["no_transfer"]\nseeds = [0]'
        )
        + '[reward]\npickplace_nut_m12 = "r.py"\n'
    )
    run = tmp_path / "run"
    run_experiment(load_experiment(path), run, "local", 1, console=quiet())
    copy = run / "rewards" / "pickplace_nut_m12.py"
    assert copy.read_bytes() == reward.read_bytes()
    meta = json.loads(
        (run / "cells/pickplace_nut_m12/no_transfer/seed_0/checkpoint.json").read_text()
    )
    assert meta["reward"]["path"] == str(copy.resolve())
    assert meta["reward"]["sandboxed"]  # trained in the reward sandbox, not as plain Python

    original = reward.read_text()
    reward.write_text(
        original.replace("-d, {", "-2 * d, {").replace("'distance': -d", "'distance': -2 * d")
    )
    path.write_text(path.read_text().replace("seeds = [0]", "seeds = [0, 1]"))
    with pytest.raises(ExperimentRunError, match=r"r\.py: changed since .* pickplace_nut_m12"):
        run_experiment(load_experiment(path), run, "local", 1, resume=True, console=quiet())
    # A run from before the copies were kept: its cells' checkpoints say what they trained with.
    copy.unlink()
    with pytest.raises(ExperimentRunError, match="checkpoints record another sha256"):
        run_experiment(load_experiment(path), run, "local", 1, resume=True, console=quiet())
    assert not (run / "cells/pickplace_nut_m12/no_transfer/seed_1").exists()
    reward.write_text(original)
    summary = run_experiment(load_experiment(path), run, "local", 1, resume=True, console=quiet())
    assert [c.seed for c in summary.finished] == [1]
    assert copy.read_text() == original
    # A report's copy of the run keeps the reward its cells trained with.
    experiment_report(run, tmp_path / "copy", video=False)
    assert (tmp_path / "copy" / "rewards" / "pickplace_nut_m12.py").read_text() == original


def test_pst_with_no_source_to_leave_out_is_refused_before_any_cell(tmp_path):
    # Each PST cell failed on its own, after the other methods' cells had trained for hours.
    from itskill.experiments.config import ExperimentConfigError

    path = tmp_path / "toy.toml"
    path.write_text("k = 1\n" + TOY.replace('["itn", "no_transfer"]', '["itn", "pst"]'))
    run = tmp_path / "run"
    with pytest.raises(ExperimentConfigError) as err:
        run_experiment(load_experiment(path), run, "local", 1, source_file=path, console=quiet())
    assert str(err.value).startswith(f"{path}: k: pst on pickplace_nut_m12: PST keeps 1 of the 1")
    assert not (run / "config.json").exists()


def test_pst_added_to_a_run_that_stored_one_source_is_refused_naming_its_sources(tmp_path):
    # A session adding PST to a run whose tasks stored one source each: every PST cell failed.
    from itskill.experiments.runner import SOURCES_FILE, resolve_all_sources

    path = tmp_path / "toy.toml"
    path.write_text(TOY.replace('["itn", "no_transfer"]', '["itn", "pst"]'))
    run = tmp_path / "run"
    run.mkdir()
    (run / SOURCES_FILE).write_text(json.dumps({"pickplace_nut_m12": ["pick_nut_m12"]}))
    with pytest.raises(ExperimentRunError) as err:
        resolve_all_sources(load_experiment(path), run, path)
    assert str(err.value).startswith(
        f"{run / SOURCES_FILE}: pst on pickplace_nut_m12: PST keeps 1 of the 1 source(s)"
    )
    assert "this run keeps the sources it stored" in str(err.value)
    # Two stored sources leave PST one to keep.
    stored = {"pickplace_nut_m12": ["pick_nut_m12", "place_nut_m12"]}
    (run / SOURCES_FILE).write_text(json.dumps(stored))
    assert resolve_all_sources(load_experiment(path), run, path) == stored


@pytest.mark.parametrize(
    "edit",
    [{"seed": "abc"}, {"seed": None}, {"seed": 7}, {"task": [1]}, {"method": "itn"},
     {"num_timesteps": -1}, {"final_success": "high"}],
)  # fmt: skip
def test_a_result_naming_another_cell_or_of_odd_types_is_unfinished(tmp_path, edit):
    # `experiment held-out` stopped with a ValueError or TypeError on these, or measured the
    # directory of the seed the edit named.
    cell = Cell("reach_nut_m12", "no_transfer", 0)
    result = {"task": cell.task, "method": cell.method, "seed": 0, "num_timesteps": 256,
              "final_success": 0.5}  # fmt: skip
    cell.dir(tmp_path).mkdir(parents=True)
    (cell.dir(tmp_path) / RESULT_FILE).write_text(json.dumps(result))
    assert finished_result(cell.dir(tmp_path)) == result
    assert load_cell_results(tmp_path) == {cell: result}
    (cell.dir(tmp_path) / RESULT_FILE).write_text(json.dumps(result | edit))
    assert finished_result(cell.dir(tmp_path)) is None
    assert load_cell_results(tmp_path) == {}
