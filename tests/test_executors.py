"""The job executors: every job's result or error comes back, locally and on a local Ray."""

from __future__ import annotations

import importlib.util
import math

import pytest

from itskill.executors import ExecutorError, run_jobs

# A library function, so that Ray's workers can import it (a test module is not importable there).
JOBS = [(4.0,), (9.0,), (-1.0,), (16.0,)]


def _check(results) -> None:
    by_index = {r.index: r for r in results}
    assert sorted(by_index) == [0, 1, 2, 3]
    assert [by_index[i].value for i in (0, 1, 3)] == [2.0, 3.0, 4.0]
    assert not by_index[2].ok
    assert isinstance(by_index[2].error, ValueError)


@pytest.mark.parametrize("workers", [1, 2])
def test_local_executor_returns_every_result_and_error(workers: int) -> None:
    _check(run_jobs(math.sqrt, JOBS, "local", workers))


def test_unknown_executor_is_a_clear_error() -> None:
    with pytest.raises(ExecutorError, match="unknown executor 'slurm'"):
        list(run_jobs(math.sqrt, JOBS, "slurm"))  # type: ignore[arg-type]


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray is not installed")
def test_ray_executor_on_a_local_instance() -> None:
    _check(run_jobs(math.sqrt, JOBS, "ray"))
