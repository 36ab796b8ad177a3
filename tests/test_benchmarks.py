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


def test_paired_policies_compares_the_two_policies_on_the_same_episodes(tmp_path, capsys) -> None:
    """Two policies with one exception each, at different episodes. Of the first 8
    reach_nut_m12 episodes of seed 10,001 the M16 nut's Reach skill misses only episode 3 (it
    ends 21 mm from the nut, success is within 15) and the round peg's reaches only episode 7
    (5 mm), so paired, the M16 skill wins the 6 others. Measuring one policy twice would find 0;
    another seed for either (neither has an exception on 10,000 or 10,002), 7."""
    from itskill.skills import SHIPPED_LIBRARY

    before, after = SHIPPED_LIBRARY / "reach_peg_round", SHIPPED_LIBRARY / "reach_nut_m16"
    out = tmp_path / "paired.json"
    args = ["reach_nut_m12", str(before), str(after), "--episodes", "8", "--seed", "10001"]
    assert _load("paired_policies").main([*args, "--json", str(out)]) == 0
    assert "after won 6 episodes and lost 0; one-sided exact McNemar p = 0.016" in (
        capsys.readouterr().out
    )
    result = json.loads(out.read_text())
    assert result["before"]["success"] == 1 / 8 and result["after"]["success"] == 7 / 8
    assert (result["episodes_won"], result["episodes_lost"]) == (6, 0)
    assert result["p"] == pytest.approx(0.5**6)
