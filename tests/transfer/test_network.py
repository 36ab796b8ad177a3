"""The transfer networks: frozen sources, gradients, the analyzer prior in W, checkpoints."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import A2C
from torch import nn
from transfer_helpers import TINY, make_source

from itskill.rl.checkpoint import load_policy, policy_sha256
from itskill.rl.logger import LoggerConfig
from itskill.rl.train import train
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.sim.vec_env import action_space, observation_space
from itskill.transfer import DFSPolicy, ITNPolicy, NIAPolicy, TransferPolicy
from itskill.transfer.lateral import NOT_READY
from itskill.transfer.stages import STAGE_SLICE

PRIOR = [[0.9, 0.1], [0.2, 0.8], [0.5, 0.5], [0.3, 0.7], [0.6, 0.4]]  # 5 stages x 2 sources


def build(cls: type[TransferPolicy], sources: list[dict], **kw) -> TransferPolicy:
    kwargs = {"prior": PRIOR, "stages": TINY, **kw}
    return cls(observation_space(), action_space(), lambda _: 1e-3, sources=sources, **kwargs)


def obs_at(stage: int, n: int = 4, seed: int = 0) -> torch.Tensor:
    obs = np.random.default_rng(seed).normal(size=(n, OBSERVATION_LAYOUT.size)).astype(np.float32)
    obs[:, STAGE_SLICE] = 0.0
    obs[:, STAGE_SLICE.start + stage] = 1.0
    return torch.as_tensor(obs)


def source_params(policy: TransferPolicy) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in policy.mlp_extractor.sources.state_dict().items()}


def test_sources_are_the_saved_policies_with_their_own_normalisers(tiny_sources) -> None:
    policy = build(ITNPolicy, tiny_sources)
    obs = obs_at(0)
    for spec, src in zip(tiny_sources, policy.mlp_extractor.sources, strict=True):
        saved = load_policy(spec["run_dir"])
        assert saved.obs_norm.count.item() == 100.0
        for mine, theirs in zip(src.stage_outputs(obs), saved.stage_outputs(obs), strict=True):
            assert torch.equal(mine, theirs)
        assert not any(p.requires_grad for p in src.parameters())


def test_each_source_sees_the_stage_of_its_own_task(tiny_sources) -> None:
    # Source 0 performs the last two of the target's five stages (a Place in a pick-and-place).
    mapped = {**tiny_sources[0], "stage_map": [0, 0, 0, 0, 1]}
    policy = build(ITNPolicy, [mapped, tiny_sources[1]])
    feats, _ = policy.mlp_extractor.source_outputs(obs_at(4))
    saved = [load_policy(s["run_dir"]) for s in tiny_sources]
    for mine, theirs in zip(feats[0], saved[0].stage_outputs(obs_at(1)), strict=True):
        assert torch.equal(mine, theirs)
    # A spec without a map sees the target's stage, as before maps existed.
    for mine, theirs in zip(feats[1], saved[1].stage_outputs(obs_at(4)), strict=True):
        assert torch.equal(mine, theirs)
    with pytest.raises(ValueError, match="stage_map must be"):
        build(ITNPolicy, [{**tiny_sources[0], "stage_map": [0, 9]}, tiny_sources[1]])


PERFORMERS = [0, 0, 1, 1, -1]


def test_the_residual_adds_the_performing_sources_action(tiny_sources) -> None:
    policy = build(ITNPolicy, tiny_sources, performers=PERFORMERS)
    saved = [load_policy(s["run_dir"]) for s in tiny_sources]
    for stage, who in enumerate(PERFORMERS):
        obs = obs_at(stage)
        mean = policy.get_distribution(obs).distribution.mean
        head = policy.action_net(policy.mlp_extractor.actor_stages(obs)[-1])
        source = saved[who].action_net(saved[who].stage_outputs(obs)[-1]) if who >= 0 else 0.0
        torch.testing.assert_close(mean, head + source)
        # The head starts near zero: the untrained network acts like the source of the stage.
        assert head.abs().max() < 0.05
    without = build(ITNPolicy, tiny_sources)
    assert without.mlp_extractor.latent_dim_pi == TINY[-1]
    assert policy.mlp_extractor.latent_dim_pi == TINY[-1] + 5
    with pytest.raises(ValueError, match="performers must be"):
        build(ITNPolicy, tiny_sources, performers=[0, 2])
    with pytest.raises(ValueError, match="performers must be 1 to"):  # an IndexError when built
        build(ITNPolicy, tiny_sources, performers=[])
    # A matrix of two rows for five stages lent its last row to stages 2-4 without a word.
    with pytest.raises(ValueError, match="the contribution matrix has 2 rows, the target 5 stag"):
        build(ITNPolicy, tiny_sources, performers=PERFORMERS, prior=PRIOR[:2])


@pytest.mark.parametrize("performers", [None, PERFORMERS])
def test_gradients_reach_target_fusion_attention_but_not_sources(tiny_sources, performers) -> None:
    policy = build(ITNPolicy, tiny_sources, performers=performers)
    policy.set_training_mode(True)
    obs = torch.cat([obs_at(0), obs_at(3, seed=1)])
    values, log_prob, _ = policy.evaluate_actions(obs, torch.zeros(len(obs), 5))
    (values.sum() - log_prob.sum()).backward()
    ex = policy.mlp_extractor
    for name, module in [
        ("target stage 1", ex.actor.stages[0]),
        ("fusion", ex.merge),
        ("attention encoders", ex.weighting.encoders),
        ("attention mix", ex.weighting.mix),
        ("critic", ex.critic),
        ("action head", policy.action_net),
    ]:
        grads = [p.grad for p in module.parameters()]
        assert all(g is not None and g.abs().sum() > 0 for g in grads), name
    assert all(p.grad is None for p in ex.sources.parameters())
    optimised = {id(p) for group in policy.optimizer.param_groups for p in group["params"]}
    assert optimised == {id(p) for p in policy.parameters() if p.requires_grad}
    assert not optimised & {id(p) for p in ex.sources.parameters()}
    # SB3 switches the whole policy to train mode around updates; the sources stay in eval mode.
    assert policy.training and not any(m.training for m in ex.sources.modules())


def test_the_prior_row_of_the_current_stage_corrects_w(tiny_sources) -> None:
    beta = 0.5
    policy = build(ITNPolicy, tiny_sources, prior_weight=beta)
    weights = {}
    for stage in (0, 1, 4):
        att = policy.attention(obs_at(stage))
        # W = (1 - beta) * raw + beta * prior[stage], rows sum to 1.
        np.testing.assert_allclose(
            att["weights"] - (1 - beta) * att["raw"],
            beta * np.tile(PRIOR[stage], (4, 1)),
            atol=1e-6,
        )
        np.testing.assert_allclose(att["weights"].sum(1), 1.0, atol=1e-6)
        weights[stage] = att["weights"]
    assert np.abs(weights[0] - weights[1]).max() > 0.2
    # The final attention layer starts small: the raw weights begin near uniform.
    np.testing.assert_allclose(att["raw"], 0.5, atol=0.05)


def test_nia_uses_the_prior_as_fixed_weights_and_dfs_sums(tiny_sources) -> None:
    nia = build(NIAPolicy, tiny_sources)
    att = nia.attention(obs_at(1))
    assert att["raw"] is None
    np.testing.assert_array_equal(nia.attention(obs_at(1).numpy())["weights"], att["weights"])
    np.testing.assert_allclose(att["weights"], np.tile(PRIOR[1], (4, 1)), atol=1e-6)
    assert not hasattr(nia.mlp_extractor.weighting, "mix")

    dfs = build(DFSPolicy, tiny_sources, prior=None)
    obs = obs_at(2)
    ex = dfs.mlp_extractor
    feats, _ = ex.source_outputs(obs)
    first = ex.actor.stages[0](ex.normalize(obs)) + feats[0][0] + feats[1][0]
    assert torch.allclose(dfs.stage_outputs(obs)[0], first)
    with pytest.raises(ValueError, match="no contribution weights"):
        dfs.attention(obs)


def test_bad_network_settings_are_clear_errors(tiny_sources, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="needs the analyzer's contribution matrix"):
        build(ITNPolicy, tiny_sources, prior=None)
    with pytest.raises(ValueError, match=r"shape \(5, 3\), expected \(5, 2\)"):
        build(ITNPolicy, tiny_sources, prior=[[1, 0, 0]] * 5)
    with pytest.raises(ValueError, match="as wide as the target's"):
        build(DFSPolicy, tiny_sources, prior=None, stages=(16, 8, 8))
    two_stage = make_source(tmp_path / "two", seed=7, stages=(8, 8))
    with pytest.raises(ValueError, match="has 2 stages, the target 3"):
        build(ITNPolicy, [two_stage], prior=[[1.0]] * 5)
    with pytest.raises(ValueError, match="at least one source"):
        build(ITNPolicy, [], prior=None)
    # Built from Python, not only through transfer.toml: W went negative, a source ran twice.
    with pytest.raises(ValueError, match=r"prior_weight must be in \[0, 1\], got 2.0"):
        build(ITNPolicy, tiny_sources, prior_weight=2.0)
    with pytest.raises(ValueError, match="a source is given twice"):
        build(ITNPolicy, [tiny_sources[0]] * 2)


def test_the_frozen_sources_stay_in_eval_mode_however_the_network_is_switched(
    tiny_sources,
) -> None:
    policy = build(ITNPolicy, tiny_sources)
    for module in (policy, policy.mlp_extractor):
        module.train()
        assert policy.mlp_extractor.actor.training
        assert not any(s.training for s in policy.mlp_extractor.sources.modules())


@pytest.mark.parametrize("algo", ["a2c", "ppo"])
def test_sources_bit_identical_after_training(tiny_sources, tmp_path: Path, algo: str) -> None:
    frozen = source_params(build(ITNPolicy, tiny_sources))
    out = tmp_path / "run"
    overrides = {"n_steps": 16, "batch_size": 32, "n_epochs": 2} if algo == "ppo" else {}

    def run(steps: int) -> ITNPolicy:
        train(
            "pickplace_nut_m12", algo, steps, 0, "expert", out, num_envs=2, overrides=overrides,
            logger=LoggerConfig(progress=False, tensorboard=False), policy_class=ITNPolicy,
            policy_kwargs={"sources": tiny_sources, "prior": PRIOR, "stages": TINY},
        )  # fmt: skip
        return load_policy(out)

    early, late = run(32), run(128)
    for policy in (early, late):
        for key, value in source_params(policy).items():
            assert torch.equal(value, frozen[key]), key
    # ...while the target, fusion and attention did learn in between.
    ex_early, ex_late = early.mlp_extractor, late.mlp_extractor
    for a, b in [(ex_early.actor, ex_late.actor), (ex_early.merge, ex_late.merge),
                 (ex_early.weighting, ex_late.weighting)]:  # fmt: skip
        assert not all(
            torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters(), strict=True)
        )
    assert ex_late.obs_norm.count.item() > ex_early.obs_norm.count.item()


@pytest.mark.parametrize("performers", [None, PERFORMERS])
def test_a_saved_itn_is_self_contained(tiny_sources, tmp_path: Path, performers) -> None:
    out = tmp_path / "run"
    sources = [{**tiny_sources[0], "stage_map": [0, 1, 2, 2, 2]}, tiny_sources[1]]
    kwargs = {"sources": sources, "prior": PRIOR, "stages": TINY, "performers": performers}
    train(
        "pickplace_nut_m12", "a2c", 32, 0, "expert", out, num_envs=2,
        logger=LoggerConfig(progress=False, tensorboard=False), policy_class=ITNPolicy,
        policy_kwargs=kwargs,
    )  # fmt: skip
    reference = load_policy(out)
    assert reference.config.performers == (None if performers is None else tuple(performers))
    obs = obs_at(3).numpy()
    expected, _ = reference.predict(obs, deterministic=True)
    for spec in tiny_sources:
        shutil.rmtree(spec["run_dir"])
    moved = tmp_path / "elsewhere"
    shutil.move(out, moved)
    again, _ = load_policy(moved).predict(obs, deterministic=True)
    np.testing.assert_array_equal(again, expected)
    zipped, _ = A2C.load(moved / "model.zip", device="cpu").policy.predict(obs, deterministic=True)
    np.testing.assert_array_equal(zipped, expected)


def test_a_source_retrained_in_place_is_not_mixed_into_a_network_made_before(
    tiny_sources, tmp_path: Path
) -> None:
    sources = [{**s, "weights_sha256": policy_sha256(s["run_dir"])} for s in tiny_sources]
    out = tmp_path / "run"
    kwargs = {"sources": sources, "prior": PRIOR, "stages": TINY}
    quiet = LoggerConfig(progress=False, tensorboard=False)
    run = {"num_envs": 2, "logger": quiet, "policy_class": ITNPolicy, "policy_kwargs": kwargs}
    train("pickplace_nut_m12", "a2c", 16, 0, "expert", out, **run)
    trained_with = source_params(load_policy(out))
    # The first skill is retrained in place, wider: the files no longer match the spec.
    shutil.rmtree(sources[0]["run_dir"])
    make_source(Path(sources[0]["run_dir"]), seed=7, stages=(16, 16, 16))
    # A new network from the old spec refuses to act instead of taking the new weights...
    with pytest.raises(RuntimeError, match="changed since the network was specified"):
        build(ITNPolicy, sources).predict(obs_at(0).numpy())
    # ...and the run resumes on the weights it trained with (it was refused before).
    assert train("pickplace_nut_m12", "a2c", 32, 0, "expert", out, **run).resumed_from == 16
    resumed = source_params(load_policy(out))
    assert all(torch.equal(trained_with[k], resumed[k]) for k in trained_with)


def test_a_policy_without_source_weights_refuses_to_act(tiny_sources) -> None:
    config = build(ITNPolicy, tiny_sources).config.to_dict()
    empty = ITNPolicy.from_config(config)
    with pytest.raises(RuntimeError, match="never loaded"):
        empty.predict(obs_at(0).numpy())
    assert "never loaded" in NOT_READY


def test_a_trained_transfer_policy_can_be_a_source(tiny_sources, tmp_path: Path) -> None:
    out = tmp_path / "itn"
    train(
        "pickplace_nut_m12", "a2c", 16, 0, "expert", out, num_envs=2,
        logger=LoggerConfig(progress=False, tensorboard=False), policy_class=ITNPolicy,
        policy_kwargs={
            "sources": tiny_sources, "prior": PRIOR, "stages": TINY, "performers": PERFORMERS,
        },
    )  # fmt: skip
    inner = load_policy(out)
    spec = {
        "name": "itn_skill",
        "task": "pickplace_nut_m12",
        "run_dir": str(out),
        "policy_class": "itskill.transfer.itn.ITNPolicy",
        "policy": inner.config.to_dict(),
    }
    outer = build(ITNPolicy, [spec, tiny_sources[0]])
    obs = obs_at(2)
    nested = outer.mlp_extractor.sources[0]
    for a, b in zip(nested.stage_outputs(obs), inner.stage_outputs(obs), strict=True):
        assert torch.equal(a, b)
    # Its action, residual included, is what the outer network's attention sees.
    _, actions = outer.mlp_extractor.source_outputs(obs)
    torch.testing.assert_close(actions[0], inner.get_distribution(obs).distribution.mean)
    assert isinstance(outer.mlp_extractor.sources[0].mlp_extractor.merge, nn.Module)
    # Its own sources run once per pass of the outer network: they ran twice, once for its
    # features and again for its residual action.
    runs = []
    nested_extractor = nested.mlp_extractor
    original = nested_extractor.source_outputs
    nested_extractor.source_outputs = lambda x: runs.append(1) or original(x)
    outer.mlp_extractor.source_outputs(obs)
    assert len(runs) == 1
