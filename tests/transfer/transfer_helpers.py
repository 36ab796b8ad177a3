"""Helpers for the transfer tests: tiny random source checkpoints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import save_file

from itskill.rl.checkpoint import (
    FORMAT_VERSION,
    META_FILE,
    POLICY_FILE,
    STAGED_POLICY_CLASS,
    build_policy,
)
from itskill.rl.policy import PolicyConfig
from itskill.sim.layout import OBSERVATION_LAYOUT

TINY = (8, 8, 8)


def make_source(run_dir: Path, seed: int, stages: tuple[int, ...] = TINY) -> dict:
    """A random staged policy saved as a finished checkpoint; returns its source spec.

    Its normaliser has non-trivial statistics, so a source that ignored its own would show.
    """
    torch.manual_seed(seed)
    config = PolicyConfig(stages=stages)
    policy = build_policy(config)
    for p in policy.parameters():
        torch.nn.init.normal_(p, std=0.5)
    rng = np.random.default_rng(seed)
    policy.obs_norm.mean.copy_(torch.as_tensor(rng.normal(size=OBSERVATION_LAYOUT.size)))
    policy.obs_norm.var.copy_(torch.as_tensor(rng.uniform(0.5, 2.0, OBSERVATION_LAYOUT.size)))
    policy.obs_norm.count.fill_(100.0)
    run_dir.mkdir(parents=True)
    save_file(
        {k: v.contiguous() for k, v in policy.state_dict().items()}, str(run_dir / POLICY_FILE)
    )
    meta = {
        "format": FORMAT_VERSION,
        "task": "pick_nut_m12",
        "algo": "ppo",
        "seed": seed,
        "num_timesteps": 0,
        "obs_size": OBSERVATION_LAYOUT.size,
        "action_size": 5,
        "policy": config.to_dict(),
        "policy_class": STAGED_POLICY_CLASS,
    }
    (run_dir / META_FILE).write_text(json.dumps(meta))
    return {
        "name": f"tiny{seed}",
        "task": "pick_nut_m12",
        "run_dir": str(run_dir),
        "policy_class": STAGED_POLICY_CLASS,
        "policy": config.to_dict(),
    }
