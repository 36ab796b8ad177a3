"""Candidates as Ray tasks on a local Ray instance."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fake_openai import FakeOpenAIServer
from replies import CONSTANT, GOOD
from search_helpers import tiny_config

from itskill.reward import generate_reward, search_client

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'itskill[ray]')")


@pytest.fixture
def local_ray():
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_ray_executor_trains_the_candidates(
    tmp_path: Path, local_ray, quiet, monkeypatch: pytest.MonkeyPatch
) -> None:
    import itskill.reward.search as search_module

    executors: list[str] = []
    real = search_module.run_jobs

    def recorded(fn, jobs, executor, workers, address):
        executors.append(executor)
        return real(fn, jobs, executor, workers, address)

    monkeypatch.setattr(search_module, "run_jobs", recorded)
    run = tmp_path / "run"
    with FakeOpenAIServer([GOOD, CONSTANT]) as server:
        result = generate_reward(
            "pick_nut_m12",
            search_client(run, "openai:fake-model", server.base_url),
            run,
            tiny_config(samples=2, executor="ray"),
            compare_expert=False,
            console=quiet,
        )
    samples = result.history[0]["samples"]
    assert [s["status"] for s in samples] == ["ok", "ok"]
    for k in range(2):
        result_file = run / "iter_0" / f"sample_{k}" / "result.json"
        assert json.loads(result_file.read_text())["env_steps"] == 128
    assert len(list((run / "final").glob("generated_*_seed1/result.json"))) == 1
    # Every training went through Ray: the candidates' and the final reward's.
    assert executors and set(executors) == {"ray"}


def test_a_relative_run_directory_reaches_ray_workers_as_an_absolute_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, quiet
) -> None:
    # A Ray worker runs from a working directory of its own: a relative run directory had it
    # write the candidates' results there, on a cluster node the driver never reads.
    import itskill.reward.search as search_module
    from itskill.executors import run_jobs

    outs: list[Path] = []

    def on_this_machine(fn, jobs, executor, workers, address):
        assert executor == "ray"
        outs.extend(Path(job.out) for (job,) in jobs)
        return run_jobs(fn, jobs, "local", 1, None)

    monkeypatch.setattr(search_module, "run_jobs", on_this_machine)
    monkeypatch.chdir(tmp_path)
    with FakeOpenAIServer([GOOD]) as server:
        generate_reward(
            "pick_nut_m12",
            search_client(Path("run"), "openai:fake-model", server.base_url),
            Path("run"),
            tiny_config(samples=1, executor="ray"),
            compare_expert=False,
            console=quiet,
        )
    assert outs and all(out.is_absolute() and out.is_relative_to(tmp_path) for out in outs)
