"""The contribution weights of a trained transfer policy over an episode (the paper's Fig. 8)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from itskill.datafile import is_number
from itskill.files import read_json_or_none, write_json
from itskill.rl.checkpoint import POLICY_FILE, load_policy, policy_sha256, read_meta
from itskill.tasks import get_task, make_batch_env
from itskill.transfer.lateral import TransferPolicy
from itskill.transfer.stages import STAGE_SLICE
from itskill.transfer.train import TRANSFER_FILE, read_transfer

TRACE_FILE = "attention.json"


class TraceError(ValueError):
    """Attention that cannot be traced: a policy without contribution weights, or no episode
    asked for."""


def attention_trace(run_dir: str | Path, episodes: int = 1, seed: int = 0) -> dict[str, Any]:
    """Deterministic episodes of the policy in ``run_dir`` with its weights at every step.

    Returns ``{"task", "method", "sources", "segments", "episodes": [{"stage": [...],
    "raw": [[...]] | None, "weights": [[...]], "success", "length"}]}``: per step the stage the
    observation shows (index into ``segments``), the attention's raw weights (None for fixed
    weights) and the corrected weights ``W`` that scaled the source features for that action.
    """
    if episodes < 1:
        raise TraceError(f"episodes must be positive, got {episodes}")
    run_dir = Path(run_dir)
    meta = read_meta(run_dir)
    policy = load_policy(run_dir)
    if not isinstance(policy, TransferPolicy) or policy.mlp_extractor.weighting is None:
        raise TraceError(
            f"{run_dir}: holds a {meta.get('policy_class', 'staged')} policy, which has no "
            "contribution weights (the methods itn, pst and nia have them)"
        )
    spec = get_task(meta["task"])
    method = None
    if (run_dir / TRANSFER_FILE).is_file():
        method = read_transfer(run_dir).get("method")
    env = make_batch_env(spec.id, num_envs=1, seed=seed)
    runs: list[dict[str, Any]] = []
    try:
        obs = env.reset()
        while len(runs) < episodes:
            stages, raws, weights = [], [], []
            done, success = False, False
            while not done:
                att = policy.attention(obs)
                stages.append(int(np.argmax(obs[0, STAGE_SLICE])))
                raws.append(None if att["raw"] is None else att["raw"][0].tolist())
                weights.append(att["weights"][0].tolist())
                action, _ = policy.predict(obs, deterministic=True)
                obs, _, dones, infos = env.step(action)
                done = bool(dones[0])
                success = bool(infos[0].get("is_success", False)) if done else False
            runs.append(
                {
                    "stage": stages,
                    "raw": None if raws[0] is None else raws,
                    "weights": weights,
                    "success": success,
                    "length": len(stages),
                }
            )
    finally:
        env.close()
    return {
        "task": spec.id,
        "method": method,
        "sources": policy.source_names,
        "segments": [st.name for st in spec.stages],
        "episodes": runs,
    }


def recorded_attention_trace(run_dir: str | Path) -> dict[str, Any]:
    """:func:`attention_trace` of one deterministic episode (seed 0), kept in ``run_dir``.

    The trace is written to ``attention.json`` with the sha256 of the weights it came from. It is
    reused while those weights are unchanged and traced again once they change (a resumed run),
    and it is read as it is where the weights are absent: a run's small files copied to
    ``results/`` keep their Fig. 8 when the report is written again from them.
    """
    run_dir = Path(run_dir)
    path, weights = run_dir / TRACE_FILE, run_dir / POLICY_FILE
    digest = policy_sha256(run_dir) if weights.is_file() else None
    saved = read_json_or_none(path)
    if (
        isinstance(saved, dict)
        and _is_trace(saved.get("trace"))
        and (digest is None or saved.get("weights_sha256") == digest)
    ):
        return saved["trace"]
    trace = attention_trace(run_dir, episodes=1, seed=0)
    write_json(path, {"weights_sha256": digest, "episodes": 1, "seed": 0, "trace": trace})
    return trace


def _is_trace(value: Any) -> bool:
    """Whether ``value`` has the shape :func:`attention_trace` returns, as far as the report
    reads it: a damaged ``attention.json`` is traced again, or refused where the weights are
    gone, rather than failing the report where a field is first used."""
    if not (
        isinstance(value, dict)
        and isinstance(value.get("sources"), list)
        and isinstance(value.get("segments"), list)
        and isinstance(value.get("episodes"), list)
        and value["episodes"]
    ):
        return False
    n = len(value["sources"])
    return all(_is_episode(e, n) for e in value["episodes"])


def _is_episode(episode: Any, n_sources: int) -> bool:
    """One episode of a trace: per step a stage index and a weight for each of ``n_sources``
    sources (and as many raw weights, or none), and whether it succeeded."""

    def rows(value: Any, steps: int) -> bool:
        return (
            isinstance(value, list)
            and len(value) == steps
            and all(
                isinstance(row, list) and len(row) == n_sources and all(map(is_number, row))
                for row in value
            )
        )

    if not isinstance(episode, dict):
        return False
    stages = episode.get("stage")
    if not (
        isinstance(stages, list)
        and stages
        and all(isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in stages)
    ):
        return False
    raw = episode.get("raw")
    return (
        rows(episode.get("weights"), len(stages))
        and (raw is None or rows(raw, len(stages)))
        and isinstance(episode.get("success"), bool)
        and is_number(episode.get("length"))
    )
