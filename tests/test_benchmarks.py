"""Every benchmark script still starts: they import the library directly, and a rename there
would otherwise only show when someone next measures something."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARK_DIR = Path(__file__).resolve().parents[1] / "benchmarks"
BENCHMARKS = sorted(BENCHMARK_DIR.glob("*.py"))


@pytest.mark.parametrize("script", BENCHMARKS, ids=lambda p: p.stem)
def test_benchmark_parses_its_arguments(script: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, BENCHMARK_DIR / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pull_jam_tells_a_straight_pull_from_a_sideways_drag() -> None:
    """docs/skills.md explains Remove's hold-still optimum with these two pulls: straight up, a
    freshly grasped peg comes out held; dragged sideways, the fingers lose it in the hole."""
    pull = _load("pull_jam").pull
    straight = pull("remove_peg_rect", 0.0, 1.0, envs=4, seed=0)
    dragged = pull("remove_peg_rect", -1.0, 1.0, envs=4, seed=0)
    assert straight["pulling"] == 1.0 and dragged["pulling"] == 1.0
    assert straight["out_held"] == 1.0 and straight["lost_in_hole"] == 0.0
    assert dragged["out_held"] == 0.0 and dragged["lost_in_hole"] == 1.0


def test_paired_policies_finds_no_difference_between_a_policy_and_itself(tmp_path, capsys) -> None:
    from itskill.skills import SHIPPED_LIBRARY

    skill = SHIPPED_LIBRARY / "reach_nut_m12"
    out = tmp_path / "paired.json"
    args = ["reach_nut_m12", str(skill), str(skill), "--episodes", "4", "--json", str(out)]
    assert _load("paired_policies").main(args) == 0
    assert "won 0 episodes and lost 0" in capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["before"]["success"] == result["after"]["success"] and result["p"] == 1.0
