"""Training-run checkpoints: write them atomically, load the policy back with clear errors.

A run directory holds, after every checkpoint:

- ``model.zip``: the full SB3 model (policy, optimiser state, step count) to resume training;
- ``policy.safetensors``: the policy's weights and observation-normaliser statistics only, what a
  frozen transfer source or an evaluation needs;
- ``checkpoint.json``: metadata (task, algorithm, seed, env-steps done, observation size, policy
  shape, hyper-parameters, reward, versions). It is written last, so its presence means the two
  files beside it are complete.

``as_policy`` turns a run directory into the evaluation ``Policy`` interface of
:mod:`itskill.tasks.evaluate`. That module sits below ``rl`` and does not import it; the CLI (above
both) calls ``as_policy`` before handing a policy reference down.
"""

from __future__ import annotations

import json
import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from itskill.rl.policy import PolicyConfig, StagedActorCriticPolicy
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.sim.vec_env import action_space, observation_space
from itskill.tasks.evaluate import CheckpointError, Policy, PolicyActor, PolicyFactory
from itskill.tasks.spec import TaskSpec

MODEL_FILE = "model.zip"
POLICY_FILE = "policy.safetensors"
META_FILE = "checkpoint.json"
FORMAT_VERSION = 1
REQUIRED_META = ("format", "task", "algo", "seed", "num_timesteps", "obs_size", "policy")


def versions() -> dict[str, str]:
    """Versions of the packages a checkpoint depends on."""
    import mujoco
    import stable_baselines3

    import itskill

    return {
        "itskill": itskill.__version__,
        "torch": torch.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def save_checkpoint(model: Any, run_dir: Path, meta: Mapping[str, Any]) -> dict[str, Any]:
    """Write ``model.zip``, ``policy.safetensors`` and ``checkpoint.json`` into ``run_dir``.

    ``meta`` carries the run's description; the step count, layout size and versions are added.
    Returns the metadata written.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    tmp_zip = run_dir / "model.tmp.zip"
    model.save(tmp_zip)
    os.replace(tmp_zip, run_dir / MODEL_FILE)
    state = {k: v.detach().cpu().contiguous() for k, v in model.policy.state_dict().items()}
    tmp_st = run_dir / (POLICY_FILE + ".tmp")
    save_file(state, str(tmp_st), metadata={"format": str(FORMAT_VERSION)})
    os.replace(tmp_st, run_dir / POLICY_FILE)
    full = {
        "format": FORMAT_VERSION,
        **meta,
        "num_timesteps": int(model.num_timesteps),
        "obs_size": OBSERVATION_LAYOUT.size,
        "action_size": 5,
        "policy": model.policy.config.to_dict(),
        "versions": versions(),
    }
    _atomic_write_text(run_dir / META_FILE, json.dumps(full, indent=2) + "\n")
    return full


def read_meta(run_dir: str | Path) -> dict[str, Any]:
    """``checkpoint.json`` of ``run_dir``, checked; :class:`CheckpointError` says what is wrong."""
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise CheckpointError(run_dir, "no such checkpoint directory")
    if not run_dir.is_dir():
        raise CheckpointError(run_dir, "not a directory (expected a training run directory)")
    path = run_dir / META_FILE
    if not path.is_file():
        raise CheckpointError(
            path, "missing: the directory holds no finished checkpoint (train into it first)"
        )
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise CheckpointError(path, f"corrupt metadata, not valid JSON: {err}") from err
    if not isinstance(meta, dict):
        raise CheckpointError(path, "corrupt metadata: expected a JSON object")
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise CheckpointError(path, f"corrupt metadata: missing field(s) {', '.join(missing)}")
    if meta["format"] != FORMAT_VERSION:
        raise CheckpointError(
            path, f"checkpoint format {meta['format']!r}, this version reads {FORMAT_VERSION}"
        )
    if meta["obs_size"] != OBSERVATION_LAYOUT.size:
        raise CheckpointError(
            path,
            f"observation size {meta['obs_size']}, "
            f"the current layout has {OBSERVATION_LAYOUT.size}",
        )
    return meta


def build_policy(config: PolicyConfig) -> StagedActorCriticPolicy:
    """An untrained policy of the given shape for the shared observation/action spaces.

    ``ortho_init`` is off: the weights are about to be overwritten by a checkpoint's.
    """
    kwargs = config.policy_kwargs()
    kwargs["ortho_init"] = False
    return StagedActorCriticPolicy(observation_space(), action_space(), lambda _: 0.0, **kwargs)


def load_policy(run_dir: str | Path) -> StagedActorCriticPolicy:
    """The policy of the last checkpoint in ``run_dir``: eval mode, statistics frozen, on CPU.

    Raises :class:`CheckpointError` (a ``ValueError`` naming the path and the problem) if the
    directory, its metadata or its weights are missing, corrupt or do not fit.
    """
    run_dir = Path(run_dir)
    meta = read_meta(run_dir)
    try:
        config = PolicyConfig(**{**meta["policy"], "stages": tuple(meta["policy"]["stages"])})
    except (TypeError, ValueError, KeyError) as err:
        raise CheckpointError(run_dir / META_FILE, f"corrupt policy description: {err}") from err
    path = run_dir / POLICY_FILE
    if not path.is_file():
        raise CheckpointError(path, "missing policy weights")
    try:
        state = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as err:
        raise CheckpointError(path, f"corrupt policy weights: {err}") from err
    policy = build_policy(config)
    try:
        policy.load_state_dict(state, strict=True)
    except RuntimeError as err:
        first = str(err).strip().splitlines()[0]
        raise CheckpointError(
            path, f"weights do not fit the recorded policy shape: {first}"
        ) from err
    policy.update_obs_stats = False
    policy.set_training_mode(False)
    return policy


class TrainedPolicy(PolicyActor):
    """A training run's last checkpoint, acting deterministically."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir)
        super().__init__(load_policy(self.path))


def as_policy(ref: str | Path | Policy | PolicyFactory) -> str | Path | Policy | PolicyFactory:
    """A training run directory becomes a policy factory; anything else is returned unchanged."""
    if isinstance(ref, str | Path) and Path(ref).is_dir():
        run_dir = Path(ref)
        read_meta(run_dir)  # fail early, before any environment is built

        def factory(spec: TaskSpec, num_envs: int) -> Policy:
            return TrainedPolicy(run_dir)

        factory.__name__ = str(run_dir)
        return factory
    return ref
