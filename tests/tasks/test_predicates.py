"""Stage predicates on the states a task passes through."""

from __future__ import annotations

import numpy as np
import pytest

from itskill.tasks import all_tasks, get_task, make_batch_env
from itskill.tasks.predicates import above_fixture
from itskill.tasks.scripted import ScriptedPolicy


def _bottom_below_entrance(metres: float) -> dict[str, np.ndarray]:
    """A context with object 0's bottom centred on its fixture's axis, ``metres`` below it."""
    obj_to_fix = np.zeros((1, 2, 3))
    obj_to_fix[0, 0, 2] = metres
    return {"obj_to_fix": obj_to_fix}


def test_above_fixture_allows_only_the_given_depth_below_the_fixture_point() -> None:
    five_mm_in = _bottom_below_entrance(0.005)
    assert not above_fixture(five_mm_in, 0)[0]  # the default: 2 mm
    assert above_fixture(five_mm_in, 0, 0.004, 0.03, 0.02)[0]
    assert not above_fixture(_bottom_below_entrance(0.025), 0, 0.004, 0.03, 0.02)[0]


@pytest.mark.parametrize(
    "task", [t for t in all_tasks() if get_task(t).kind == "complex" and get_task(t).script]
)
def test_a_scripted_episode_never_falls_back_a_stage(task: str) -> None:
    """The scripted controller finishes each subtask in order, so its stage only rises. A
    stage that falls back while the part moves on (a peg 2-10 mm into its hole read as back in
    its approach) hands the part to the earlier stage's skill, which undoes the progress, and
    takes the stage bonuses back from the reward."""
    spec = get_task(task)
    env = make_batch_env(task, num_envs=4, seed=3, n_threads=1)
    policy = ScriptedPolicy(spec, 4)
    env.reset()
    policy.reset()
    best = np.zeros(4, dtype=np.int64)
    try:
        for _ in range(spec.max_steps - 1):
            ctx = env.context()
            assert np.all(ctx["stage"] >= best), f"stages {ctx['stage']} after {best}"
            best = ctx["stage"]
            env.step(policy(ctx))
        assert spec.success(env.context()).all()
    finally:
        env.close()
