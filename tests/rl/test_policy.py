"""The staged policy: stage shapes, the normaliser's statistics, frozen sub-modules."""

from __future__ import annotations

import torch

from itskill.rl.checkpoint import build_policy
from itskill.rl.policy import PolicyConfig, StagedActorCriticPolicy
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.sim.vec_env import action_space, observation_space


def make(**kw) -> StagedActorCriticPolicy:
    cfg = PolicyConfig(**kw)
    return StagedActorCriticPolicy(
        observation_space(), action_space(), lambda _: 3e-4, **cfg.policy_kwargs()
    )


def test_stage_outputs_shapes() -> None:
    policy = make()
    obs = torch.randn(7, OBSERVATION_LAYOUT.size)
    outs = policy.stage_outputs(obs)
    assert [tuple(o.shape) for o in outs] == [(7, 256), (7, 256), (7, 128)]
    critic = policy.stage_outputs(obs, trunk="critic")
    assert [tuple(o.shape) for o in critic] == [(7, 256), (7, 256), (7, 128)]
    assert not torch.allclose(outs[0], critic[0])  # separate trunks by default
    shared = make(shared_trunk=True, stages=(32, 16, 8))
    assert [o.shape[1] for o in shared.stage_outputs(obs)] == [32, 16, 8]
    assert shared.mlp_extractor.critic is None


def test_normaliser_updates_only_in_rollout_forward() -> None:
    policy = make()
    obs = torch.randn(64, OBSERVATION_LAYOUT.size) * 3 + 5
    policy.predict(obs.numpy(), deterministic=True)
    policy.evaluate_actions(obs, torch.zeros(64, 5))
    policy.stage_outputs(obs)
    assert policy.obs_norm.count.item() == 0
    policy(obs)  # SB3's rollout step
    assert policy.obs_norm.count.item() == 64
    torch.testing.assert_close(policy.obs_norm.mean, obs.double().mean(0))
    torch.testing.assert_close(policy.obs_norm.var, obs.double().var(0, unbiased=False))
    more = torch.randn(32, OBSERVATION_LAYOUT.size)
    policy(more)
    both = torch.cat([obs, more]).double()
    torch.testing.assert_close(policy.obs_norm.mean, both.mean(0))
    torch.testing.assert_close(policy.obs_norm.var, both.var(0, unbiased=False))


def test_normaliser_saved_and_restored_in_state_dict() -> None:
    policy = make()
    policy(torch.randn(50, OBSERVATION_LAYOUT.size) * 2 + 1)
    state = policy.state_dict()
    assert {"obs_norm.mean", "obs_norm.var", "obs_norm.count"} <= set(state)
    clone = build_policy(policy.config)
    clone.load_state_dict(state)
    for key in ("mean", "var", "count"):
        torch.testing.assert_close(getattr(clone.obs_norm, key), getattr(policy.obs_norm, key))
    obs = torch.randn(5, OBSERVATION_LAYOUT.size)
    torch.testing.assert_close(clone.stage_outputs(obs)[2], policy.stage_outputs(obs)[2])


def test_every_sb3_path_normalises_once() -> None:
    policy = make()
    policy(torch.randn(64, OBSERVATION_LAYOUT.size) * 4 + 2)  # non-trivial statistics
    policy.update_obs_stats = False
    obs = torch.randn(6, OBSERVATION_LAYOUT.size) * 4 + 2
    with torch.no_grad():
        actions, values, _ = policy(obs, deterministic=True)
        torch.testing.assert_close(policy._predict(obs, deterministic=True), actions)
        torch.testing.assert_close(policy.predict_values(obs), values)
        ev_values, _, _ = policy.evaluate_actions(obs, actions)
        torch.testing.assert_close(ev_values, values)
        # Agreeing with each other is not enough: every path could normalise twice alike.
        norm = policy.obs_norm
        seen = ((obs.double() - norm.mean) / torch.sqrt(norm.var + 1e-8)).clamp(-10, 10).float()
        actor = policy.mlp_extractor.forward_actor(seen)
        critic = policy.mlp_extractor.forward_critic(seen)
        torch.testing.assert_close(actions, policy.action_net(actor))
        torch.testing.assert_close(values, policy.value_net(critic))
