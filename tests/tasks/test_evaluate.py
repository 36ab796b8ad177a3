"""Evaluation: success and how far into the task episodes get."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from itskill.tasks import get_task
from itskill.tasks.evaluate import NoiseError, NoisyPolicy, evaluate, noise_sigma, with_noise
from itskill.tasks.scripted import ScriptedPolicy


class HoldStill:
    """Keeps the hand where it starts, fingers open."""

    def reset(self, env_ids=None) -> None:
        pass

    def __call__(self, ctx):
        return np.zeros((len(ctx["ee_pos"]), 5)) - np.array([0, 0, 0, 0, 1.0])


def test_subtasks_finished_count_every_stage_on_success_and_none_for_a_still_hand():
    spec = get_task("pick_nut_m12")
    scripted = evaluate(spec, "scripted", episodes=4, num_envs=4)
    assert scripted.success_rate == 1.0
    assert scripted.n_stages == 3 and scripted.mean_stages_done == 3.0
    still = evaluate(spec, HoldStill(), episodes=4, num_envs=4)
    assert still.success_rate == 0.0 and still.mean_stages_done == 0.0
    assert still.stage_steps == [spec.max_steps, 0.0, 0.0]  # the whole episode in the approach


class GraspThenHold:
    """The scripted pick until the fingers hold the nut, then still, fingers closed."""

    def __init__(self, spec, num_envs: int) -> None:
        self.script = ScriptedPolicy(spec, num_envs)

    def reset(self, env_ids=None) -> None:
        self.script.reset(env_ids)

    def __call__(self, ctx):
        actions = self.script(ctx)
        held = ctx["grasped"][:, 0] > 0.5
        actions[held] = [0.0, 0.0, 0.0, 0.0, 1.0]
        return actions


def test_an_episode_that_stops_half_way_counts_the_stages_it_finished():
    # Approach and grasp done, lift not: 2 of Pick's 3 subtasks.
    spec = get_task("pick_nut_m12")
    half = evaluate(spec, GraspThenHold, episodes=4, num_envs=4)
    assert half.success_rate == 0.0 and half.mean_stages_done == 2.0
    # It approaches and grasps, then holds still in the lift for the rest of the episode.
    approach, grasp, lift = half.stage_steps
    assert approach > 0 and grasp > 0 and lift > approach + grasp
    assert sum(half.stage_steps) == spec.max_steps == half.mean_length


class ScriptedInFirstEnv(GraspThenHold):
    """The scripted controller in environment 0, a still hand in every other."""

    def __call__(self, ctx):
        actions = self.script(ctx)
        actions[1:] = [0.0, 0.0, 0.0, 0.0, -1.0]
        return actions


def test_outcomes_list_each_environments_episodes_in_turn():
    # 5 episodes on 2 environments: the first runs 3, the second 2, in that order in outcomes,
    # so two policies measured alike line up episode by episode.
    spec = get_task("reach_nut_m12")
    result = evaluate(spec, ScriptedInFirstEnv, episodes=5, num_envs=2)
    assert result.outcomes == [True, True, True, False, False]
    assert result.successes == 3 and result.success_rate == 0.6


class _Fixed:
    def __init__(self, value: float) -> None:
        self.value, self.resets = value, []

    def reset(self, env_ids=None) -> None:
        self.resets.append(env_ids)

    def __call__(self, ctx):
        return np.full((len(ctx["ee_pos"]), 5), self.value)


def test_noisy_policy_adds_seeded_gaussian_noise_within_the_action_range() -> None:
    ctx = {"ee_pos": np.zeros((4000, 3))}
    inner = _Fixed(0.2)
    actions = NoisyPolicy(inner, 0.1, seed=3)(ctx)
    assert actions.shape == (4000, 5)
    assert abs(actions.mean() - 0.2) < 0.01 and abs(actions.std() - 0.1) < 0.01
    np.testing.assert_array_equal(actions, NoisyPolicy(_Fixed(0.2), 0.1, seed=3)(ctx))
    # Noise past the bounds is clipped as the environment clips; resets reach the policy.
    wide = NoisyPolicy(_Fixed(0.9), 5.0)(ctx)
    assert wide.max() == 1.0 and wide.min() == -1.0
    NoisyPolicy(inner, 0.0).reset(np.array([1]))
    assert inner.resets[-1].tolist() == [1]
    with pytest.raises(ValueError, match="standard deviation"):
        NoisyPolicy(inner, float("nan"))


@pytest.mark.parametrize("text", ["-0.1", "inf", "nan", "lots"])
def test_a_benchmark_refuses_a_noise_that_is_not_a_standard_deviation(text: str, capsys) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--noise", type=noise_sigma)
    with pytest.raises(SystemExit):
        parser.parse_args(["--noise", text])
    # argparse shows the reason, not only "invalid value".
    assert "argument --noise: the action noise must be" in capsys.readouterr().err
    with pytest.raises(NoiseError, match="action noise"):
        noise_sigma(text)


def test_noise_sigma_reads_a_standard_deviation_from_text_or_a_number() -> None:
    assert noise_sigma("0.135") == 0.135 and noise_sigma(0) == 0.0
    assert str(noise_sigma("-0")) == "0.0"  # not -0.0 in a result file
    with pytest.raises(NoiseError, match="must be a number"):
        noise_sigma(None)  # type: ignore[arg-type]


def test_the_scripted_insert_fails_under_exploration_noise() -> None:
    # Its corrections are a few hundredths of the action range: noise of 0.3 undoes them.
    from itskill.tasks.scripted import run_episodes

    assert sum(run_episodes("insert_peg_rect", 8, 8, seed=1)) == 8
    assert sum(run_episodes("insert_peg_rect", 8, 8, seed=1, noise=0.3)) <= 2
    # Fewer episodes than environments: the noisy script is built for the ones that run.
    assert len(run_episodes("insert_peg_rect", 2, 16, seed=1, noise=0.01)) == 2


def test_with_noise_wraps_any_policy_with_noise_drawn_afresh_from_its_seed() -> None:
    spec = get_task("insert_peg_rect")
    assert with_noise("scripted", 0.0) == "scripted"  # no noise: the policy itself
    noisy = with_noise(_Fixed(0.2), "0.1", seed=3)  # a ready policy; the noise as text
    assert noisy.__name__ == "_Fixed with action noise 0.1"
    ctx = {"ee_pos": np.zeros((2000, 3))}
    first, again = (noisy(spec, 2000)(ctx) for _ in range(2))
    np.testing.assert_array_equal(first, again)  # each policy made draws from the seed again
    assert abs(first.std() - 0.1) < 0.01
    other = with_noise(_Fixed(0.2), 0.1, seed=4)(spec, 2000)(ctx)
    assert not np.array_equal(first, other)
    # A policy make_policy builds is built for the environments evaluate runs (2 of 16 here).
    result = evaluate(spec, with_noise("scripted", 0.01, seed=1), 2, seed=1, num_envs=16)
    assert result.episodes == 2 and result.policy == "scripted with action noise 0.01"
