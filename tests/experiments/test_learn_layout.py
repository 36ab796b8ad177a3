"""How a learn run's records name its files, wherever the run has been moved since."""

from __future__ import annotations

from pathlib import Path

from itskill.experiments.learn_layout import kept_policy_words


def test_the_kept_policy_is_named_in_the_run_however_its_record_names_it(tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / "transfer" / "best").mkdir(parents=True)
    for recorded in ("transfer/best", str(run / "transfer" / "best"), "transfer\\best"):
        record = {"run_dir": "transfer", "policy_dir": recorded}
        assert kept_policy_words(run, record) == "the run's transfer/best"


def test_a_policy_recorded_outside_the_run_is_named_by_its_path(tmp_path: Path) -> None:
    # An older run's record names where its policy was; the run holds none of its own.
    elsewhere = tmp_path / "old" / "transfer" / "best"
    elsewhere.mkdir(parents=True)
    run = tmp_path / "run"
    run.mkdir()
    record = {"run_dir": str(tmp_path / "old" / "transfer"), "policy_dir": str(elsewhere)}
    assert kept_policy_words(run, record) == elsewhere.as_posix()


def test_a_policy_recorded_relative_to_another_directory_is_not_called_the_runs(
    tmp_path: Path, monkeypatch
) -> None:
    # Records from before paths were relative to the run named them from where the command ran.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "old" / "transfer" / "best").mkdir(parents=True)
    run = tmp_path / "run"
    run.mkdir()
    record = {"run_dir": "old/transfer", "policy_dir": "old/transfer/best"}
    assert kept_policy_words(run, record) == "old/transfer/best"
    climbing = {"run_dir": "../old/transfer", "policy_dir": "../old/transfer/best"}
    assert not kept_policy_words(run, climbing).startswith("the run's")
