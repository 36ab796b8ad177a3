"""Train and measure one reward candidate, in a process of its own.

:func:`run_candidate` is the job the executors run (a local worker process or a Ray task). It
trains the candidate in a fresh child process (:func:`itskill.reward.limited.run_limited`), so
the sandbox's CPU and memory limits bound exactly one candidate, a candidate that
kills its process takes down nothing else, and a wall-clock limit can stop it. The child compiles
the code in the sandbox, trains it for every seed (:func:`itskill.rl.train.train`, resumable;
the job's :class:`CandidateNetwork` where it has one, a transfer network for a complex task),
and ``result.json`` is written atomically:

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

import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from itskill.files import read_json, write_json
from itskill.reward.limited import ChildFailed, RemoteTraceback, run_limited
from itskill.reward.sandbox import SandboxConfig, compile_reward
from itskill.reward_contract import EXPERT

if TYPE_CHECKING:  # the worker that only supervises the child imports no simulator
    from itskill.sim.task import RewardFn

RESULT_FILE = "result.json"
TRAIN_DIR = "train"
_CORRELATION_SEED = 30_000
_MACHINE_FAULTS = (OSError, ImportError)
"""What the child raises that is the machine's failure, not the candidate's (a full disk, a
broken installation): no result is written, and a resumed search trains the candidate again.
Anything else is the candidate's, whether its code raised in the sandbox or made training fail
outside it (rewards that drive the networks' weights to nan), and a resume would only repeat it."""


@dataclass(frozen=True)
class CandidateNetwork:
    """The network every candidate of a search trains, where it is not the trainer's own.

    A complex task's search passes the transfer network its final training will use (frozen
    source skills, analyzer prior): trained from scratch at a candidate's budget, every reward
    for such a task scores 0% and the search cannot tell them apart. ``policy_class`` must be
    importable in a worker process (it travels by name); ``label`` names the network in logs and
    in the run's ``config.json``; ``overrides`` are the hyper-parameter overrides every training
    on it takes (:func:`itskill.rl.train.train`'s: a transfer network's turn off the task's
    scripted warm start, which only the trainer's own network can take).
    """

    policy_class: type
    policy_kwargs: Mapping[str, Any] | None
    label: str
    overrides: Mapping[str, Any] | None = None

    def describe(self) -> dict[str, str]:
        """The network as the run's ``config.json`` records it: class path and label."""
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
        """Where seed ``seed``'s training run goes."""
        return Path(self.out) / TRAIN_DIR / f"seed_{seed}"


def run_candidate(job: CandidateJob) -> dict[str, Any]:
    """Train ``job`` in a limited child process and return its ``result.json`` (written either
    way: a candidate whose code fails, or whose process dies or times out, is ``failed``)."""
    path = Path(job.out) / RESULT_FILE
    if path.is_file():
        return read_json(path)
    Path(job.out).mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    try:
        result = {
            "status": "ok",
            **run_limited(
                _train_and_measure,
                (job,),
                sandbox=job.sandbox,
                name="the candidate's process",
                timeout_s=job.timeout_s,
            ),
        }
    except ChildFailed as err:  # killed by a limit or a signal, or past its time limit
        result = {"status": "failed", "error": str(err)}
    except Exception as err:
        if not isinstance(err.__cause__, RemoteTraceback) or isinstance(err, _MACHINE_FAULTS):
            raise  # not the candidate's failure: no result, so a resume runs it again
        tail = traceback.format_exception_only(type(err), err)[-1].strip()
        result = {"status": "failed", "error": tail}  # the reward raised or timed out
    result["wall_s"] = time.monotonic() - start
    write_json(path, result)
    return result


def _train_and_measure(job: CandidateJob) -> dict[str, Any]:
    # Imported here, not at the top: the worker that only supervises the child needs none of it.
    from itskill.curves import NoEvaluationsError, evaluation_seed, read_curve
    from itskill.reward.feedback import component_stats, peak_success
    from itskill.rl.checkpoint import as_policy, read_meta
    from itskill.rl.eval_callback import EVAL_ENVS
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
            "overrides": job.network.overrides,
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
        try:
            # A damaged file raises, naming itself: the candidate fails rather than being
            # measured on its final policy alone.
            done = read_curve(job.train_dir(seed), job.steps)
            curve = [(int(s), float(v)) for s, v in zip(done.steps, done.success, strict=True)]
        except NoEvaluationsError:
            curve = []
        if not curve or curve[-1][0] < result.num_timesteps:
            # Interrupted between the last checkpoint and its evaluation: evaluate it now, with
            # the evaluation callback's episodes, so the final policy always counts.
            policy = as_policy(job.train_dir(seed))
            episodes_seed = evaluation_seed(read_meta(job.train_dir(seed)))
            final = evaluate(spec, policy, job.eval_episodes, episodes_seed, num_envs=EVAL_ENVS)
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
    task: str, run_dir: Path, reward_fn: RewardFn, expert_fn: RewardFn, num_envs: int
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
