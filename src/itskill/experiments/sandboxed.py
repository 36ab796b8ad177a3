"""Transfer training on a reward file that may be generated code: the code runs only in the sandbox.

A reward search's ``best_reward.py`` is a language model's code. The search trains it only in the
reward sandbox (:mod:`itskill.reward.sandbox`), and so does everything that trains on it after:
``itskill learn``'s final training, an experiment's cells, ``benchmarks/reward_at_budget.py``. The
file is compiled in the sandbox (its AST checked, restricted builtins, every call time-limited)
inside a spawned child under the sandbox's memory limit, and trains there; the caller's process
never runs it. The sandbox's CPU-time limit is left off: it is sized for a candidate's budget, and
a training is bounded by its own.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

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

    sandbox = sandbox or load_search_config().sandbox
    return run_limited(
        _train,
        (str(Path(reward_file).resolve()), kind, sandbox, train_kwargs),
        sandbox=replace(sandbox, cpu_limit_s=None),
        name=name,
    )


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
        code = Path(reward_file).read_bytes().decode("utf-8")
    except UnicodeDecodeError as err:
        return f"not UTF-8 text ({err.reason} at byte {err.start})"
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
    fn = compile_reward(source.decode("utf-8"), sandbox)
    meta = {
        "kind": kind,
        "path": reward_path,
        "sha256": hashlib.sha256(source).hexdigest(),
        "sandboxed": True,
    }
    train_kwargs.setdefault("console", Console(emoji=False))
    return train_transfer(reward=RewardSource(fn, meta), **train_kwargs)
