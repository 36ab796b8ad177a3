"""Train and measure one reward candidate, in a process of its own.

:func:`run_candidate` is the job the executors run (a local worker process or a Ray task). It
starts a fresh child process for the candidate, so the sandbox's CPU and memory limits
(:func:`itskill.reward.sandbox.apply_process_limits`) bound exactly one candidate, a candidate that
kills its process takes down nothing else, and a wall-clock limit can stop it. The child compiles
the code in the sandbox, trains it for every seed (:func:`itskill.rl.train.train`, resumable;
the job's :class:`CandidateNetwork` where it has one, a transfer network for a complex task),
and writes ``result.json`` atomically:

- ``success``: the mean over seeds of the best deterministic success through training (the
  evaluations every ``eval_every`` env-steps and the final one), ``final_success`` likewise for the
  last evaluation;
- ``stats``: every reward component's (and the episode return's) max/mean/min through training;
- ``correlation``: Pearson correlation of the candidate's total reward with the expert reward on
  the states a short stochastic rollout of the trained policy visits;
- ``wall_s``, ``env_steps``, and per seed the evaluation curve.

A candidate whose reward raises or times out during training, or whose process dies, gets
``status: "failed"`` and the error instead. A ``result.json`` that exists is never redone.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from itskill.executors import stop_on_first_interrupt
from itskill.files import read_json, write_json
from itskill.reward.sandbox import SandboxConfig, apply_process_limits, compile_reward, death_cause

RESULT_FILE = "result.json"
TRAIN_DIR = "train"
EXPERT = "expert"
_CORRELATION_SEED = 30_000
_EVAL_SEED = 20_000
"""Seed of the evaluation episodes (with 25 environments): DeterministicEvalCallback's."""
_INTERRUPTED = 130
"""Exit code of a candidate process stopped by Ctrl-C (as a shell reports SIGINT)."""


@dataclass(frozen=True)
class CandidateNetwork:
    """The network every candidate of a search trains, where it is not the trainer's own.

    A complex task's search passes the transfer network its final training will use (frozen
    source skills, analyzer prior): trained from scratch at a candidate's budget, every reward
    for such a task scores 0% and the search cannot tell them apart. ``policy_class`` must be
    importable in a worker process (it travels by name); ``label`` names the network in logs and
    in the run's ``config.json``.
    """

    policy_class: type
    policy_kwargs: Mapping[str, Any] | None
    label: str

    def describe(self) -> dict[str, str]:
        from itskill.rl.checkpoint import class_path

        return {"policy_class": class_path(self.policy_class), "label": self.label}


@dataclass(frozen=True)
class CandidateJob:
    """Everything a worker needs to train one candidate (picklable, for any executor).

    ``code`` is the generated reward's source, or None for the task's expert reward (the
    baseline of the final comparison).
    """

    task: str
    out: Path
    code: str | None
    seeds: tuple[int, ...]
    steps: int
    num_envs: int
    algo: str
    eval_every: int
    eval_episodes: int
    correlation_envs: int
    sandbox: SandboxConfig
    timeout_s: float
    network: CandidateNetwork | None = None

    def train_dir(self, seed: int) -> Path:
        return Path(self.out) / TRAIN_DIR / f"seed_{seed}"


def run_candidate(job: CandidateJob) -> dict[str, Any]:
    """Train ``job`` in a child process and return its ``result.json`` (written either way)."""
    path = Path(job.out) / RESULT_FILE
    if path.is_file():
        return read_json(path)
    Path(job.out).mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    parent = os.getppid()
    child = multiprocessing.get_context("spawn").Process(
        target=_child_main, args=(job, os.getpid()), name=f"candidate:{job.out}"
    )
    child.start()
    try:
        problem = _supervise(child, job, start, parent)
    except KeyboardInterrupt:
        # A terminal's Ctrl-C has reached the child already, a forwarded one has not; either way
        # it saves a checkpoint and stops (a second SIGINT is ignored there).
        with contextlib.suppress(ProcessLookupError):
            os.kill(child.pid, signal.SIGINT)
        child.join(60.0)
        if child.is_alive():
            child.kill()
        raise
    if child.exitcode == _INTERRUPTED:
        raise KeyboardInterrupt
    if not path.is_file():
        problem = problem or death_cause(child.exitcode, job.sandbox, "the candidate's process")
        write_json(path, {"status": "failed", "error": problem, "wall_s": time.monotonic() - start})
    return read_json(path)


def _supervise(child: Any, job: CandidateJob, start: float, parent: int) -> str | None:
    """Wait for the candidate's process; the reason it was stopped, if it was."""
    problem = None
    while child.is_alive():
        child.join(1.0)
        if os.getppid() != parent and multiprocessing.parent_process() is not None:
            # The run that submitted this job is gone (kill -9): stop, leave no orphan training.
            child.kill()
            os._exit(1)
        if child.is_alive() and time.monotonic() - start > job.timeout_s:
            child.kill()
            child.join()
            problem = f"timed out: training took longer than {job.timeout_s:g} s (wall clock)"
    return problem


def _watch_parent(parent_pid: int) -> None:
    """End this process when the one that started it dies (no orphan keeps training)."""

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _child_main(job: CandidateJob, parent_pid: int) -> None:
    stop_on_first_interrupt()
    _watch_parent(parent_pid)
    start = time.monotonic()
    try:
        apply_process_limits(job.sandbox)
        result = {"status": "ok", **_train_and_measure(job)}
    except KeyboardInterrupt:
        os._exit(_INTERRUPTED)  # Ctrl-C: no result, the candidate is redone on resume
    except Exception as err:
        tail = traceback.format_exception_only(type(err), err)[-1].strip()
        result = {"status": "failed", "error": tail}
    result["wall_s"] = time.monotonic() - start
    write_json(Path(job.out) / RESULT_FILE, result)


def _train_and_measure(job: CandidateJob) -> dict[str, Any]:
    # Imported here, not at the top: the worker that only supervises the child needs none of it.
    from itskill.reward.feedback import component_stats, eval_curve, peak_success
    from itskill.rl.checkpoint import as_policy
    from itskill.rl.logger import LoggerConfig
    from itskill.rl.train import RewardSource, train
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import evaluate
    from itskill.tasks.rewards import expert_reward

    spec = get_task(job.task)
    expert = expert_reward(spec)
    if job.code is None:
        reward_fn, reward, sha = expert, EXPERT, EXPERT
    else:
        reward_fn = compile_reward(job.code, job.sandbox)
        sha = reward_fn.sha256
        reward = RewardSource(reward_fn, {"kind": "generated", "sha256": sha})
    network = {}
    if job.network is not None:
        network = {
            "policy_class": job.network.policy_class,
            "policy_kwargs": job.network.policy_kwargs,
        }
    runs = []
    for seed in job.seeds:
        result = train(
            job.task,
            job.algo,
            job.steps,
            seed,
            reward=reward,
            out=job.train_dir(seed),
            num_envs=job.num_envs,
            logger=LoggerConfig(progress=False, tensorboard=False),
            n_threads=1,
            eval_every=job.eval_every,
            eval_episodes=job.eval_episodes,
            **network,
        )
        curve = eval_curve(job.train_dir(seed))
        if not curve or curve[-1][0] < result.num_timesteps:
            # Interrupted between the last checkpoint and its evaluation: evaluate it now, with
            # the evaluation callback's episodes, so the final policy always counts.
            policy = as_policy(job.train_dir(seed))
            final = evaluate(spec, policy, job.eval_episodes, _EVAL_SEED, num_envs=25)
            curve.append((result.num_timesteps, final.success_rate))
        runs.append(
            {
                "seed": seed,
                "success": peak_success(curve),
                "final_success": curve[-1][1],
                "env_steps": result.num_timesteps,
                "curve": curve,
            }
        )
    correlation = expert_correlation(
        job.task, job.train_dir(job.seeds[0]), reward_fn, expert, job.correlation_envs
    )
    return {
        "sha256": sha,
        "success": float(np.mean([r["success"] for r in runs])),
        "final_success": float(np.mean([r["final_success"] for r in runs])),
        "correlation": correlation,
        "env_steps": int(sum(r["env_steps"] for r in runs)),
        "stats": component_stats(job.train_dir(s) for s in job.seeds),
        "runs": runs,
    }


def expert_correlation(
    task: str, run_dir: Path, reward_fn: Any, expert_fn: Any, num_envs: int
) -> float | None:
    """Pearson correlation of ``reward_fn``'s and ``expert_fn``'s totals on the states visited in
    one episode per environment of the trained policy in ``run_dir``, acting stochastically (the
    states it explores, not only its single best path). None if either reward is constant there.
    """
    from itskill.rl.checkpoint import load_policy
    from itskill.tasks import get_task, make_batch_env

    policy = load_policy(run_dir)
    env = make_batch_env(task, num_envs, seed=_CORRELATION_SEED)
    ours, theirs = [], []
    try:
        obs = env.reset()
        for _ in range(get_task(task).max_steps):
            actions, _ = policy.predict(obs, deterministic=False)
            step = env.advance(actions)
            obs = step.obs
            ours.append(np.asarray(reward_fn(step.context)[0], dtype=np.float64))
            theirs.append(np.asarray(expert_fn(step.context)[0], dtype=np.float64))
    finally:
        env.close()
    a, b = np.concatenate(ours), np.concatenate(theirs)
    if a.std() < 1e-12 or b.std() < 1e-12:
        return None
    return float(np.corrcoef(a, b)[0, 1])
