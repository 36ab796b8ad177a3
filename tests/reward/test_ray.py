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


def test_ray_executor_trains_the_candidates(tmp_path: Path, local_ray, quiet) -> None:
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
