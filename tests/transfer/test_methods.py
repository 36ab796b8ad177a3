"""Each method's ``settings``: exactly the transfer settings its network is built from.

The experiment report lists, and a resume compares, only the settings a method names; one it
reads without naming would change a run unseen, one it names without reading would refuse a
resume for nothing.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from itskill.llm.client import make_client
from itskill.rl.config import load_hyperparams
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.sim.vec_env import action_space, observation_space
from itskill.tasks import get_task
from itskill.transfer import METHODS, TransferConfig, prepare_transfer, transfer_network
from itskill.transfer.stages import STAGE_SLICE

TARGET = "pickplace_nut_m12"
SOURCES = ["pick_nut_m12", "place_nut_m12", "carry_nut_m12"]
BASE = TransferConfig(pst_keep=2)  # with one source PST's attention weights it 1, unchanged
VARIED = {
    "attention_hidden": 16,
    "prior_weight": 0.9,
    "fusion_hidden": (16,),
    "residual": False,
    "pst_keep": 1,
}
"""A value other than ``BASE``'s for every setting some method's network reads."""


def test_every_setting_a_method_names_is_varied_here() -> None:
    named = {name for m in METHODS.values() for name in m.settings}
    assert named == set(VARIED)
    assert all(getattr(BASE, name) != value for name, value in VARIED.items())


def _actions(method: str, config: TransferConfig, out: Path) -> np.ndarray:
    """The mean action of ``method``'s untrained network, built under ``config`` from a fixed
    seed, on fixed observations."""
    spec = get_task(TARGET)
    stages = load_hyperparams(spec.family, "ppo", task=TARGET).policy
    record = prepare_transfer(
        TARGET, method, SOURCES, out=out, client=make_client("offline"), config=config
    )
    policy_class, kwargs = transfer_network(record, config)
    torch.manual_seed(0)
    policy = policy_class(
        observation_space(),
        action_space(),
        lambda _: 1e-3,
        **{**stages.policy_kwargs(), **(kwargs or {})},
    )
    obs = np.random.default_rng(0).normal(size=(8, OBSERVATION_LAYOUT.size)).astype(np.float32)
    # A stage each, as the simulator gives it: random values there made the analyzer's prior a
    # sum of rows, which changed with its weight even where the attention had one source.
    obs[:, STAGE_SLICE] = np.eye(STAGE_SLICE.stop - STAGE_SLICE.start)[np.arange(8) % 5]
    with torch.no_grad():
        return policy.get_distribution(torch.as_tensor(obs)).distribution.mean.numpy()


@pytest.mark.parametrize("method", list(METHODS))
def test_a_method_is_changed_by_the_settings_it_names_and_only_by_them(
    home: Path, tmp_path: Path, method: str
) -> None:
    base = _actions(method, BASE, tmp_path / "base")
    for name, value in VARIED.items():
        varied = _actions(method, replace(BASE, **{name: value}), tmp_path / name)
        changed = varied.shape != base.shape or not np.array_equal(varied, base)
        assert changed == (name in METHODS[method].settings), (method, name)


@pytest.mark.parametrize(("keep", "given", "smaller"), [(1, 1, False), (2, 1, False), (3, 2, True)])
def test_pst_over_too_few_sources_suggests_only_what_can_work(keep, given, smaller) -> None:
    # A smaller keep over one source is refused again: it was suggested all the same.
    from itskill.transfer.pst import select_sources
    from itskill.transfer.sources import SourceError

    with pytest.raises(SourceError, match="that is ITN itself") as err:
        select_sources(["a", "b"][:given], replace(TransferConfig(), pst_keep=keep))
    assert ("smaller [pst] keep" in str(err.value)) == smaller
