"""Stage predicates on the states a task passes through."""

from __future__ import annotations

import numpy as np
import pytest

from itskill.tasks import get_task, make_batch_env
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


@pytest.mark.parametrize("task", ["pickplaceinsert_peg_rect", "pickplaceinsert_peg_round"])
def test_peg_going_into_its_hole_keeps_the_insert_stage(task: str) -> None:
    """Once the scripted peg is placed over its hole, the stage stays at the insert until the
    episode ends: a stage falling back to the approach mid-insertion hands the peg to the
    approach's skill, which lifts it out, and cuts the reward by two stage bonuses."""
    spec = get_task(task)
    insert = len(spec.stages) - 1
    env = make_batch_env(task, num_envs=4, seed=0, n_threads=1)
    policy = ScriptedPolicy(spec, 4)
    env.reset()
    policy.reset()
    reached = np.zeros(4, dtype=bool)
    deepest = np.zeros(4)
    try:
        for _ in range(spec.max_steps - 1):
            ctx = env.context()
            reached |= ctx["stage"] == insert
            assert np.all(ctx["stage"][reached] == insert)
            deepest = np.maximum(deepest, ctx["insertion_depth"][:, 0])
            env.step(policy(ctx))
    finally:
        env.close()
    assert reached.all()
    # The stage held through the 2-10 mm the old predicate lost (inserted counts from 10 mm).
    assert np.all(deepest > 0.01)
