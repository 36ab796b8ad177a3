"""Every task's scene compiles and simulates cleanly; all tasks share one observation layout."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.sim.panda import PANDA_XML_ENV, PandaModelNotFoundError, find_panda_xml
from itskill.tasks import all_tasks, make_env

TASKS = list(all_tasks())


def warnings_of(data: mujoco.MjData) -> dict[str, int]:
    """MuJoCo's warning counters that fired, by name (Menagerie's model tests check these)."""
    return {
        mujoco.mjtWarning(i).name: int(data.warning[i].number)
        for i in range(len(data.warning))
        if data.warning[i].number
    }


@pytest.mark.parametrize("name", TASKS)
def test_task_compiles_and_steps_without_warnings(name):
    env = make_env(name)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs = env.step(rng.uniform(-1, 1, 5))[0]
    assert warnings_of(env.data) == {}
    assert np.all(np.isfinite(obs))
    assert np.all(np.isfinite(env.data.qpos))
    env.close()


@pytest.mark.parametrize("name", TASKS)
def test_observation_layout_is_the_same_for_every_task(name):
    env = make_env(name)
    obs, _ = env.reset(seed=1)
    assert env.observation_space.shape == (OBSERVATION_LAYOUT.size,)
    assert obs.shape == (OBSERVATION_LAYOUT.size,)
    # Slots are filled from the task's parts, unused slots are zero with mask 0.
    spec = all_tasks()[name]
    L = OBSERVATION_LAYOUT
    for i in range(2):
        used = i < len(spec.objects)
        assert obs[L[f"obj{i}_mask"]][0] == float(used)
        if not used:
            assert not obs[L[f"obj{i}_pos"]].any()
    for j in range(2):
        assert obs[L[f"fix{j}_mask"]][0] == float(j < len(spec.fixtures))
    ctx = env.context()
    np.testing.assert_allclose(obs[L["ee_pos"]], ctx["ee_pos"][0], atol=1e-6)
    assert obs[L["stage_onehot"]].sum() == 1.0
    env.close()


def test_slice_names_cover_the_vector_without_gaps():
    names = [s.name for s in OBSERVATION_LAYOUT.slices]
    assert len(names) == len(set(names))
    assert names[:3] == ["ee_pos", "ee_yaw_sincos", "ee_vel"]
    stops = [s.start for s in OBSERVATION_LAYOUT.slices[1:]]
    assert stops == [s.stop for s in OBSERVATION_LAYOUT.slices[:-1]]
    assert OBSERVATION_LAYOUT.slices[-1].stop == OBSERVATION_LAYOUT.size


def test_panda_model_is_found(monkeypatch):
    monkeypatch.delenv(PANDA_XML_ENV, raising=False)
    path = find_panda_xml()
    assert path.is_file() and path.name == "panda.xml"


def test_panda_env_var_pointing_at_missing_file_is_a_clear_error(monkeypatch, tmp_path):
    missing = tmp_path / "nowhere" / "panda.xml"
    monkeypatch.setenv(PANDA_XML_ENV, str(missing))
    with pytest.raises(PandaModelNotFoundError) as err:
        find_panda_xml()
    assert PANDA_XML_ENV in str(err.value) and str(missing) in str(err.value)
