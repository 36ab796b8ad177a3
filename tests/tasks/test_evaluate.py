"""Evaluation: success and how far into the task episodes get."""

from __future__ import annotations

import numpy as np

from itskill.tasks import get_task
from itskill.tasks.evaluate import evaluate
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
