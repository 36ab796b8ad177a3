"""The bounds of itskill.limits, as the entry points that take a step budget apply them."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.limits import STEPS_MAX, check_steps
from itskill.rl.train import check_training
from itskill.skills.pretrain import PretrainConfig

PAST = "steps must be between 1 and 1,000,000,000, got 1,000,000,000,000"


def test_a_step_budget_past_the_cap_is_refused_wherever_it_is_given(tmp_path: Path) -> None:
    # A mistyped 10^12 trained on for ever at an undecayed learning rate.
    check_steps(STEPS_MAX)
    for refused in (
        lambda: check_steps(10**12),
        lambda: PretrainConfig(steps=10**12),
        lambda: check_training("reach_nut_m12", "ppo", 10**12, 0, "expert", tmp_path / "run"),
    ):
        with pytest.raises(ValueError, match=PAST):
            refused()
    with pytest.raises(ValueError, match="--steps must be between 1 and"):
        check_steps(0, "--steps")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["experiment", "run", "experiments/smoke.toml"],
        ["experiment", "held-out", "runs/none"],
        ["reward", "generate", "pick_nut_m12"],
        ["skills", "pretrain"],
    ],
)
def test_a_worker_count_past_the_cap_is_refused_by_every_command(command: list[str]) -> None:
    # As the settings files refuse it: a mistyped count would start processes without end.
    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.limits import WORKERS_MAX

    result = CliRunner().invoke(app, [*command, "--workers", str(WORKERS_MAX + 1)])
    assert result.exit_code == 2
    assert "--workers" in result.output and f"{WORKERS_MAX}" in result.output


@pytest.mark.parametrize("command", ["train", "analyze"])
def test_a_source_count_past_the_cap_is_a_usage_error_not_a_traceback(command: str) -> None:
    from typer.testing import CliRunner

    from itskill.cli import app
    from itskill.limits import SOURCES_MAX

    args = ["transfer", command, "pick_nut_m12", "-k", str(SOURCES_MAX + 1)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert f"{SOURCES_MAX}" in result.output
