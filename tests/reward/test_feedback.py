"""Feedback statistics from a candidate's training files, checked on hand-written ones."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.curves import CurveError
from itskill.reward.feedback import EPISODE_RETURN, component_stats, peak_success

METRICS = """\
step,wall_s,updates,episodes,success_rate,ep_return,ep_length,steps_per_s,0.approach/reach,stage_bonus
1024,1.0,1,4,0,2.5,60,900,0.1,0
2048,2.0,1,6,0.5,4.5,60,910,0.3,0.5
3072,3.0,1,0,,,,905,0.2,
"""


def _run(tmp_path: Path, name: str, metrics: str = METRICS) -> Path:
    run = tmp_path / name
    run.mkdir()
    (run / "metrics.csv").write_text(metrics)
    return run


def test_component_stats_are_max_mean_min_over_logging_windows(tmp_path: Path) -> None:
    stats = component_stats([_run(tmp_path, "a")])
    assert set(stats) == {"0.approach/reach", "stage_bonus", EPISODE_RETURN}
    assert stats["0.approach/reach"] == pytest.approx({"max": 0.3, "mean": 0.2, "min": 0.1})
    # Empty cells (a window without finished episodes, a component not paid) are skipped.
    assert stats["stage_bonus"] == pytest.approx({"max": 0.5, "mean": 0.25, "min": 0.0})
    assert stats[EPISODE_RETURN] == pytest.approx({"max": 4.5, "mean": 3.5, "min": 2.5})


def test_component_stats_pool_the_windows_of_every_seed(tmp_path: Path) -> None:
    other = METRICS.replace("0.1,0\n", "0.9,0\n")
    stats = component_stats([_run(tmp_path, "a"), _run(tmp_path, "b", other)])
    assert stats["0.approach/reach"]["max"] == pytest.approx(0.9)
    assert stats["0.approach/reach"]["mean"] == pytest.approx((0.6 + 1.4) / 6)


def test_peak_success_is_the_best_evaluation() -> None:
    assert peak_success([(1024, 0.0), (2048, 0.4), (3072, 0.2)]) == pytest.approx(0.4)
    assert peak_success([]) == 0.0


def test_a_run_without_files_has_no_stats(tmp_path: Path) -> None:
    run = tmp_path / "empty"
    run.mkdir()
    assert component_stats([run]) == {}


def test_a_damaged_metrics_file_is_named(tmp_path: Path) -> None:
    # The trainer now gets past a damaged byte; the candidate then failed here, unnamed.
    run = tmp_path / "a"
    run.mkdir()
    (run / "metrics.csv").write_bytes(METRICS.encode() + b"4096,\xff\n")
    with pytest.raises(CurveError, match=r"metrics\.csv: not UTF-8 text"):
        component_stats([run])


@pytest.mark.parametrize(
    ("row", "problem"),
    [
        ("4096,4.0,1,0,,,,905,lots,", r"column '0.approach/reach': not a number: 'lots'"),
        ("4096,4.0,1,0,,,,905,0.2,0,9", "a row has more cells than the header"),
    ],
)
def test_a_damaged_metrics_row_names_the_file(tmp_path: Path, row: str, problem: str) -> None:
    # A ValueError or TypeError without the file's name reached the search.
    run = _run(tmp_path, "a", METRICS + row + "\n")
    with pytest.raises(CurveError, match=r"metrics\.csv: " + problem):
        component_stats([run])
