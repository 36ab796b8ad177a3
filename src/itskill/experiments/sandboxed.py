"""Transfer training on a reward file that may be generated code: the code runs only in the sandbox.

A reward search's ``best_reward.py`` is a language model's code. The search trains it only in the
reward sandbox (:mod:`itskill.reward.sandbox`), and so do the trainings on it after the search:
``itskill learn``'s final one, an experiment's cells, ``benchmarks/reward_at_budget.py``'s runs.
(A file given to ``itskill train --reward`` or ``itskill transfer train --reward`` is the user's
own script and runs as plain Python.) The file is compiled in the sandbox (its AST checked,
restricted builtins, every call time-limited) inside a spawned child under a memory limit, and
trains there; the caller's process never runs it. The sandbox's CPU-time limit is left off: it
is sized for a candidate's budget, and a training is bounded by its own. The memory limit is the
sandbox's, raised for a training of many environments (each holds its own simulator).
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from itskill.files import CorruptFileError, decode_utf8, read_utf8

if TYPE_CHECKING:
    from itskill.reward.sandbox import SandboxConfig
    from itskill.rl.train import TrainResult


def train_transfer_sandboxed(
    reward_file: str | Path,
    kind: str,
    sandbox: SandboxConfig | None = None,
    name: str = "the training's process",
    **train_kwargs: Any,
) -> TrainResult:
    """:func:`itskill.transfer.train_transfer` with ``reward_file`` compiled in the sandbox, in a
    child process (``name`` in its errors) under ``sandbox``'s limits (default: the packaged
    search settings').

    The checkpoint records the reward as ``{"kind": kind, "path", "sha256" (of the file's
    bytes), "sandboxed": True}``: ``"generated"`` for a search's own output, ``"file"`` for a
    file given to an experiment, so a run trained on it before it was sandboxed still resumes.
    ``train_kwargs`` are picklable arguments of ``train_transfer`` (no console: the child makes
    its own). Errors: the sandbox's (the code refused, a call past its time limit),
    :class:`~itskill.reward.limited.ChildFailed` (the child killed by a limit), or the
    training's own, raised here."""
    from itskill.reward import load_search_config
    from itskill.reward.limited import run_limited
    from itskill.rl.eval_callback import EVAL_ENVS

    sandbox = sandbox or load_search_config().sandbox
    limits = replace(sandbox, cpu_limit_s=None)
    if limits.memory_limit_mb is not None:
        envs = _num_envs(train_kwargs) + EVAL_ENVS
        limits = replace(limits, memory_limit_mb=max(limits.memory_limit_mb, _memory_mb(envs)))
    return run_limited(
        _train,
        (str(Path(reward_file).resolve()), kind, sandbox, train_kwargs),
        sandbox=limits,
        name=name,
    )


def train_transfer_on(reward: str, kind: str, name: str, **train_kwargs: Any) -> TrainResult:
    """:func:`itskill.transfer.train_transfer` on ``reward``: the expert reward in this process,
    a reward file through :func:`train_transfer_sandboxed` (``kind``, ``name`` as there)."""
    from itskill.reward_contract import EXPERT
    from itskill.transfer import train_transfer

    if reward == EXPERT:
        return train_transfer(reward=EXPERT, **train_kwargs)
    return train_transfer_sandboxed(reward, kind, name=name, **train_kwargs)


_BASE_MB = 2048
_PER_ENV_MB = 48
"""Address space a training needs: PyTorch, the networks and buffers, and per environment its
simulator (about 35 MB each, measured with pickplace_nut_m12: 48 training environments and the
evaluation's 25 took 3.4 GB; at 96 the 4 GB limit failed to build them)."""


def _memory_mb(envs: int) -> int:
    return _BASE_MB + _PER_ENV_MB * envs


def _num_envs(train_kwargs: dict[str, Any]) -> int:
    """The training environments of ``train_kwargs`` (None: its task family's packaged count)."""
    if train_kwargs.get("num_envs") is not None:
        return int(train_kwargs["num_envs"])
    from itskill.rl.config import load_hyperparams
    from itskill.tasks import get_task

    spec = get_task(train_kwargs["target"])
    algo, path = train_kwargs.get("algo", "ppo"), train_kwargs.get("hyperparams")
    return load_hyperparams(spec.family, algo, path, task=spec.id).num_envs


def check_reward_file(
    reward_file: str | Path, task: str, sandbox: SandboxConfig | None = None
) -> str | None:
    """Why ``reward_file`` cannot train ``task``, or None: it is checked as a search checks a
    sample, compiled in the sandbox and run on a probe batch of the task's contexts in a limited
    child, so that a broken file is refused when an experiment file is read, not in every cell.
    """
    from itskill.reward import load_search_config
    from itskill.reward.generator import probe_contexts
    from itskill.reward.probe import Probe

    config = load_search_config()
    try:
        code = read_utf8(reward_file)
    except CorruptFileError as err:
        return err.problem
    if not code.strip():
        return "the file is empty: it must define compute_reward(ctx)"
    contexts = probe_contexts(task, config.probe_envs, config.probe_steps)
    with Probe(contexts, sandbox or config.sandbox) as probe:
        return probe.check(code)


def _train(
    reward_path: str, kind: str, sandbox: SandboxConfig, train_kwargs: dict[str, Any]
) -> TrainResult:
    """The child's body: compile, then train."""
    from rich.console import Console

    from itskill.reward.sandbox import compile_reward
    from itskill.rl.train import RewardSource
    from itskill.transfer import train_transfer

    source = Path(reward_path).read_bytes()
    fn = compile_reward(decode_utf8(source, reward_path), sandbox)
    meta = {
        "kind": kind,
        "path": reward_path,
        "sha256": hashlib.sha256(source).hexdigest(),
        "sandboxed": True,
    }
    train_kwargs.setdefault("console", Console(emoji=False))
    return train_transfer(reward=RewardSource(fn, meta), **train_kwargs)
