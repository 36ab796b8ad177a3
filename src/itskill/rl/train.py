"""Train a policy on one task with A2C or PPO, checkpointing and resuming in a run directory.

The loop itself is Stable-Baselines3's ``learn``; around it, this module builds the environment,
the reward and the model, logs metrics (:mod:`itskill.rl.logger`) and checkpoints
(:mod:`itskill.rl.checkpoint`). Rerunning the same call on the same ``out`` directory resumes from
the last checkpoint: the model (optimiser included) is reloaded and the step count continues.
"""

from __future__ import annotations

import hashlib
import json
import runpy
import shutil
import warnings
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from itskill.curves import EVAL_FILE, eval_seed, evaluation_seed
from itskill.datafile import read_toml
from itskill.errors import PicklableError
from itskill.files import foreign_entries, held_alone, some_of, write_json
from itskill.limits import SEED_MAX, check_steps
from itskill.reward_contract import EXPERT, RewardOutputError, check_reward_output
from itskill.rl.checkpoint import (
    BEST_DIR,
    CANNOT_RESUME,
    META_FILE,
    MODEL_FILE,
    POLICY_FILE,
    REWARD_NORM_FILE,
    STAGED_POLICY_CLASS,
    TASK_CHANGED,
    class_path,
    interrupts_deferred,
    read_meta,
    restore_reward_norm,
    save_checkpoint,
    trained_on_another_version,
)
from itskill.rl.clock import TRAIN_WALL_KEY, WallClock
from itskill.rl.config import ALGOS, HyperparamError, Hyperparams, default_path, load_hyperparams
from itskill.rl.demos import DEMOS_FILE, warm_start
from itskill.rl.eval_callback import (
    DeterministicEvalCallback,
    last_evaluated,
    read_selection,
    truncate_evaluations,
)
from itskill.rl.init_policy import (
    CRITIC_WARM_UP_FILE,
    describe_init,
    init_policy,
    warm_up_critic,
)
from itskill.rl.logger import TB_DIR, LoggerConfig, MetricsCallback, MetricsWriter
from itskill.rl.policy import StagedActorCriticPolicy
from itskill.sim.task import Context, RewardFn
from itskill.sim.vec_env import BatchEnv
from itskill.tasks import get_task, make_batch_env
from itskill.tasks.evaluate import CheckpointError
from itskill.tasks.spec import TaskSpec

ALGO_CLASSES: dict[str, type[BaseAlgorithm]] = {"a2c": A2C, "ppo": PPO}
_PROBE_ENVS = 2
"""Environments a reward file is probed on: more than one, so a total that is a single number
instead of one per environment is caught."""


class RewardLoadError(PicklableError, ValueError):
    """A reward file that cannot be used: names the file and the problem."""

    def __init__(self, path: str | Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem


class ResumeMismatchError(ValueError):
    """``out`` cannot take the run requested: it holds a run of a different task, algorithm,
    seed, reward or settings, or files that are not a training run's."""


RUN_ENTRIES = frozenset(
    {
        MODEL_FILE,
        POLICY_FILE,
        META_FILE,
        REWARD_NORM_FILE,
        EVAL_FILE,
        DEMOS_FILE,
        CRITIC_WARM_UP_FILE,
        BEST_DIR,
        "metrics.csv",
        "metrics.jsonl",
        TB_DIR,
    }
)
"""What training writes into its run directory (and its ``best/``). A run killed before its first
checkpoint leaves some of them, which a new run there starts again: ``best/`` and ``tb/`` are
deleted and the metrics truncated."""


def _foreign_entries(run_dir: Path, own: frozenset[str]) -> list[str]:
    """Entries of ``run_dir``, and of its ``best/``, that neither training nor its caller
    (``own``) writes (:func:`itskill.files.foreign_entries`)."""
    ours = (RUN_ENTRIES | own).__contains__
    best = [f"{BEST_DIR}/{name}" for name in foreign_entries(run_dir / BEST_DIR, ours)]
    return foreign_entries(run_dir, ours) + best


@dataclass(frozen=True)
class RewardSource:
    """A reward given as a callable, with the description stored in the checkpoint.

    ``meta`` must be JSON-serialisable and hold at least ``kind`` and ``sha256`` (of the code the
    callable was built from): a resumed run checks both, so it never continues under another reward.
    """

    fn: RewardFn
    meta: Mapping[str, Any]

    def __post_init__(self) -> None:
        missing = [k for k in ("kind", "sha256") if k not in self.meta]
        if missing:
            raise ValueError(f"RewardSource.meta lacks {', '.join(missing)}")


@dataclass(frozen=True)
class TrainResult:
    """What :func:`train` did: where, and how many env-steps in total (an interrupted run raises
    ``KeyboardInterrupt`` after saving its checkpoint instead of returning).

    ``wall_s`` is the run's wall time over every session, its evaluations included (a resumed
    run adds the time recorded in its checkpoint; work after the last checkpoint of a crashed
    session is not counted, it was thrown away); ``session_wall_s`` is this call's. The
    learning curve's ``wall_s`` (``eval.csv``) leaves the evaluations out.
    """

    run_dir: Path
    num_timesteps: int
    resumed_from: int
    wall_s: float
    session_wall_s: float
    best: dict[str, Any] | None = None
    """The evaluation that chose the policy in ``run_dir/best`` (env-steps, success, ...), if the
    run was evaluated while it trained."""

    @property
    def resume_note(self) -> str:
        """Where this session started, for a line on the run: empty for a new run."""
        if not self.resumed_from:
            return ""
        if self.num_timesteps == self.resumed_from:
            return " (finished in an earlier session; nothing trained now)"
        return f" (resumed from {self.resumed_from:,})"


def _save(model: Any, run_dir: Path, meta: Mapping[str, Any], clock: WallClock) -> float:
    """Save a checkpoint; returns the run's wall seconds as recorded in it."""
    fields = clock.checkpoint_fields()
    save_checkpoint(model, run_dir, {**meta, **fields})
    return fields[TRAIN_WALL_KEY]


def load_reward(
    reward: str | Path | RewardSource, spec: TaskSpec
) -> tuple[RewardFn, dict[str, Any]]:
    """The reward function and its description for the checkpoint metadata.

    ``"expert"`` is the task's human-designed reward (:func:`itskill.tasks.rewards.expert_reward`),
    a :class:`RewardSource` is used as given (generated rewards arrive this way, already
    sandboxed). Anything else is a path to a Python file defining ``compute_reward(ctx) -> (total,
    components)``, executed as plain Python in this process: a file the user wrote is trusted like
    any script they run; generated code goes through :mod:`itskill.reward.sandbox` instead. The
    file's function is called once on a batch of ``spec``'s initial states here, and its results
    are checked at every call: an exception it raises or a result of the wrong shape or type is a
    :class:`RewardLoadError` naming the file.
    """
    if isinstance(reward, RewardSource):
        return reward.fn, dict(reward.meta)
    if str(reward) == EXPERT:
        from itskill.tasks.rewards import expert_fingerprint, expert_reward

        return expert_reward(spec), {"kind": EXPERT, "sha256": expert_fingerprint(spec)}
    path = Path(reward)
    if not path.is_file():
        what = "a directory" if path.is_dir() else "no such reward file"
        raise RewardLoadError(path, f"{what} (expected {EXPERT!r} or a .py file)")
    source = path.read_bytes()
    try:
        namespace = runpy.run_path(str(path), run_name="itskill_reward")
    # sys.exit() in the file would otherwise end the command silently, with its exit code.
    except (Exception, SystemExit) as err:
        raise RewardLoadError(path, f"failed to run: {type(err).__name__}: {err}") from err
    fn = namespace.get("compute_reward")
    if not callable(fn):
        raise RewardLoadError(path, "defines no function compute_reward(ctx)")
    checked = _FileReward(fn, path)
    _probe(checked, spec)
    return checked, {"kind": "file", "path": str(path.resolve()), "sha256": _sha256(source)}


class _FileReward:
    """A reward file's ``compute_reward`` whose every failure names the file: an exception it
    raises, or a result that is not ``(total[N], {component: [N]})`` with finite values, is a
    :class:`RewardLoadError` instead of a traceback from deep in the simulator."""

    def __init__(self, fn: RewardFn, path: Path) -> None:
        self.fn, self.path = fn, path

    def __call__(self, ctx: Context) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        try:
            result = self.fn(ctx)
        except (Exception, SystemExit) as err:
            raise RewardLoadError(
                self.path, f"compute_reward raised {type(err).__name__}: {err}"
            ) from err
        try:
            return check_reward_output(result, len(ctx["ee_pos"]))
        except RewardOutputError as err:
            raise RewardLoadError(self.path, str(err)) from err


def _probe(reward: _FileReward, spec: TaskSpec) -> None:
    """Call ``reward`` once on a few of ``spec``'s initial states, so that a broken file fails
    before anything is built or written, not at the first training step."""
    env = make_batch_env(spec, _PROBE_ENVS, seed=0)
    try:
        env.reset()
        reward(env.context())
    finally:
        env.close()


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class CheckpointCallback(BaseCallback):
    """Saves a checkpoint at the start of the first rollout after every ``every`` env-steps.

    A rollout starts once the previous one's update is done, so a checkpoint's step count is
    exactly the env-steps its weights learned from. ``trained`` keeps that count for an
    interrupted run: ``start`` (the model's count as the session begins) until the first
    rollout, then the count at the start of each rollout and at the end of each update (the
    steps of a rollout cut short are not counted; an update is never cut short,
    :func:`_whole_updates`), and every step once the last update is done (an interrupt in the
    final evaluation keeps the finished run finished).
    """

    def __init__(
        self, run_dir: Path, every: int, meta: Mapping[str, Any], clock: WallClock, start: int
    ) -> None:
        super().__init__()
        self.run_dir, self.every, self.meta, self.clock = run_dir, every, dict(meta), clock
        self._last = self.trained = start

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        self.trained = self.num_timesteps
        if self.num_timesteps - self._last >= self.every:
            _save(self.model, self.run_dir, self.meta, self.clock)
            self._last = self.num_timesteps

    def _on_training_end(self) -> None:
        self.trained = self.num_timesteps


def require_same(
    have: Mapping[str, Any],
    want: Mapping[str, Any],
    keys: Iterable[str],
    run_dir: Path,
    kind: str = "run",
) -> None:
    """Raise :class:`ResumeMismatchError` naming the first of ``keys`` on which the run
    ``run_dir`` holds (``have``) differs from what this call asks for (``want``)."""
    for key in keys:
        if have.get(key) != want[key]:
            raise ResumeMismatchError(
                f"{run_dir}: holds a {kind} with {key}={have.get(key)!r}, this call asks for "
                f"{key}={want[key]!r}; use another --out directory or the same settings"
            )


def _check_resume(meta: dict[str, Any], want: dict[str, Any], run_dir: Path) -> None:
    # Checkpoints written before the policy class was recorded all hold the staged policy.
    meta = {"policy_class": STAGED_POLICY_CLASS, **meta}
    require_same(meta, want, ("task", "algo", "seed"), run_dir)
    if trained_on_another_version(meta, want["task_sha256"]):
        raise ResumeMismatchError(
            f"{run_dir}: holds a run of {want['task']} as the task was then; {TASK_CHANGED} "
            "(their sha256 differs), so it would go on as another task: use another --out "
            "directory"
        )
    if meta["policy_class"] != want["policy_class"]:
        have_net, want_net = (
            c.rpartition(".")[2] for c in (meta["policy_class"], want["policy_class"])
        )
        raise ResumeMismatchError(
            f"{run_dir}: holds a run of another network, {have_net}; this call trains "
            f"{want_net}: use another --out directory"
        )
    have_init, want_init = meta.get("init") or {}, want.get("init") or {}
    if have_init.get("sha256") != want_init.get("sha256") and have_init.get("path") == (
        want_init.get("path")
    ):
        raise ResumeMismatchError(
            f"{run_dir}: holds a run started from the policy in {have_init['path']} as it was "
            "then; its weights have changed since (retrained in place: their sha256 differs); "
            "use another --out directory, or start the new run from it"
        )
    if have_init.get("sha256") != want_init.get("sha256"):
        raise ResumeMismatchError(
            f"{run_dir}: holds a run started from {have_init.get('path', 'random weights')}, "
            f"this call starts from {want_init.get('path', 'random weights')}; "
            "use another --out directory or the same --init"
        )
    have, new = meta.get("reward", {}), want["reward"]
    if have.get("kind") == new.get("kind") == EXPERT:
        # A run recorded before the expert reward's fingerprint was kept is taken as it was.
        if have.get("sha256", new["sha256"]) != new["sha256"]:
            raise ResumeMismatchError(
                f"{run_dir}: holds a run trained with the expert reward as it was then; the "
                "reward's code or the task's stages have changed since (their sha256 differs), "
                "so it would go on under another reward: use another --out directory"
            )
    elif have.get("kind") != new.get("kind") or have.get("sha256") != new.get("sha256"):
        raise ResumeMismatchError(
            f"{run_dir}: holds a run trained with reward {have!r}, this call gives {new!r}"
        )
    # As the checkpoint stores them: through JSON, tuples become lists.
    have_hp, want_hp = meta.get("hyperparams", {}), json.loads(json.dumps(want["hyperparams"]))
    # Tables the run never used (the starting policy's settings of a run from random weights,
    # the warm start's of one with none) may change: a release retuning them stopped every run.
    unused = {"init"} if not (meta.get("init") or want.get("init")) else set()
    if not any(hp.get("demos", {}).get("episodes") for hp in (have_hp, want_hp)):
        unused.add("demos")
    changed = changed_settings(
        {k: v for k, v in have_hp.items() if k not in unused},
        {k: v for k, v in want_hp.items() if k not in unused},
    )
    if changed:
        raise ResumeMismatchError(
            f"{run_dir}: holds a run trained with other hyper-parameters ({'; '.join(changed)}); "
            "resume with the same --num-envs and hyper-parameter file, or use another --out"
        )
    # A run resumed without evaluations adds none; one with others would put rows of another
    # episode count (or grid) into one curve and choose its best policy across them.
    have_eval, want_eval = meta.get("evaluation"), want.get("evaluation")
    grid = ("every", "episodes")
    if have_eval and want_eval and any(have_eval[k] != want_eval[k] for k in grid):
        raise ResumeMismatchError(
            f"{run_dir}: holds a run evaluated every {have_eval['every']:,} env-steps over "
            f"{have_eval['episodes']} episodes, this call asks for every "
            f"{want_eval['every']:,} over {want_eval['episodes']}; resume with the same "
            "--eval-every and --eval-episodes, or use another --out"
        )


RESUMABLE_CHANGES = ("checkpoint_every",)
"""Hyper-parameters a resumed run may change: they do not touch what it learns."""
_ADDED_SETTINGS: dict[str, Any] = {"a2c.rms_prop_tf_like": False}
"""Settings later releases added, with the value every run before them trained with: a checkpoint
without one ran with that value (its optimiser is restored from ``model.zip`` as it was)."""


def changed_settings(
    have: Mapping[str, Any], want: Mapping[str, Any], prefix: str = ""
) -> list[str]:
    """``key: old -> new`` for each hyper-parameter that differs between a checkpoint's record
    (``have``) and another (``want``). A setting an older checkpoint lacks is
    a change only where :data:`_ADDED_SETTINGS` records what it trained with; other such settings
    came with the features they switch, which the older run did not have."""
    out = []
    for key, new in want.items():
        name = f"{prefix}{key}"
        if name in RESUMABLE_CHANGES or (key not in have and name not in _ADDED_SETTINGS):
            continue
        old = have[key] if key in have else _ADDED_SETTINGS[name]
        if isinstance(old, Mapping) and isinstance(new, Mapping):
            out += changed_settings(old, new, f"{name}.")
        elif old != new:
            out.append(f"{name}: {old!r} -> {new!r}")
    return sorted(out)


def _demos_origin(hyperparams: str | Path | None, spec: TaskSpec) -> tuple[Path, str]:
    """The hyper-parameter file and field that set ``demos.episodes`` for ``spec``'s runs: its
    task table's if that sets them, else its family's."""
    path = Path(hyperparams) if hyperparams is not None else default_path()
    family = read_toml(path, HyperparamError)[spec.family]
    own = family.get("tasks", {}).get(spec.id, {}).get("demos", {})
    table = f"{spec.family}.tasks.{spec.id}" if "episodes" in own else spec.family
    return path, f"{table}.demos.episodes"


def train(
    task: str,
    algo: str = "ppo",
    steps: int = 100_000,
    seed: int = 0,
    reward: str | Path | RewardSource = EXPERT,
    out: str | Path = Path("runs/train"),
    num_envs: int | None = None,
    hyperparams: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    logger: LoggerConfig | None = None,
    n_threads: int | None = None,
    console: Console | None = None,
    eval_every: int | None = None,
    eval_episodes: int = 50,
    policy_class: type[ActorCriticPolicy] = StagedActorCriticPolicy,
    policy_kwargs: Mapping[str, Any] | None = None,
    init: str | Path | None = None,
) -> TrainResult:
    """Train ``algo`` on ``task`` until ``steps`` env-steps in total, in run directory ``out``.

    ``reward`` is ``"expert"``, a :class:`RewardSource`, or a path to a Python file defining
    ``compute_reward`` (see :func:`load_reward`). ``policy_class`` is an SB3 ``ActorCriticPolicy``
    subclass of the ``itskill`` package (the transfer methods pass theirs; a checkpoint is
    loaded back only with one of those, :func:`itskill.rl.checkpoint.policy_from_meta`);
    ``policy_kwargs`` go over the family's policy settings. Hyper-parameters come from the
    packaged table for the task's family (or ``hyperparams``, a TOML file of the same shape),
    with ``overrides`` on top
    (:func:`itskill.rl.config.load_hyperparams`); ``num_envs`` overrides the family's value.

    If ``out`` already holds a checkpoint of the same task, algorithm, seed and reward, training
    resumes from it (optimiser state and step count included) and metrics rows logged after that
    checkpoint are dropped. A checkpoint is written every ``checkpoint_every`` env-steps, at the
    end, and on Ctrl-C (after which ``KeyboardInterrupt`` propagates).

    With ``eval_every``, the deterministic policy is evaluated over ``eval_episodes`` episodes
    every ``eval_every`` env-steps and at the end, into ``eval.csv``, and the best of them is kept
    in ``out/best`` (:class:`itskill.rl.eval_callback.DeterministicEvalCallback`;
    :func:`itskill.rl.checkpoint.best_policy_dir` picks it).

    ``init`` starts the run from a trained policy instead of random weights: a run directory (its
    best policy if it was evaluated), a skill directory, or either's ``policy.safetensors`` (that
    policy itself), of any task, with the same network shape (:mod:`itskill.rl.init_policy`).
    The run then explores and learns with the hyper-parameters' ``init`` table, its critic is
    fitted to the policy's returns first, the observation normaliser keeps the statistics it
    came with, and, with ``eval_every``, the starting policy is evaluated at env-step 0, so the
    best policy kept is never worse than the one it started from (without evaluations there is
    no best policy to keep).

    ``out`` is this call's alone while it runs (:func:`training_alone`).
    """
    with training_alone(out):
        setup = check_training(
            task,
            algo,
            steps,
            seed,
            reward,
            out,
            num_envs,
            hyperparams,
            overrides,
            policy_class,
            init,
            eval_every,
            eval_episodes,
        )
        return run_training(setup, policy_kwargs, logger, n_threads, console)


def training_alone(out: str | Path) -> AbstractContextManager[None]:
    """Hold the run directory ``out`` for one training session of this machine, or raise
    :class:`ResumeMismatchError` at once: two sessions on one directory wrote every metrics row
    twice and left the checkpoint of whichever saved last."""
    return held_alone(
        Path(out),
        "train",
        ResumeMismatchError(
            f"{out} is in use by another itskill training on this machine; wait for it to end, "
            "or stop it and rerun the command to resume"
        ),
    )


@dataclass(frozen=True)
class TrainSetup:
    """A run :func:`check_training` accepted, checked against its run directory: what
    :func:`run_training` trains."""

    spec: TaskSpec
    algo: str
    steps: int
    seed: int
    run_dir: Path
    hp: Hyperparams
    reward_fn: RewardFn
    meta: dict[str, Any]
    """What the run's checkpoints record."""
    policy_class: type[ActorCriticPolicy]
    previous: dict[str, Any] | None
    """The checkpoint metadata of the run resumed from ``run_dir``; None for a new run."""
    eval_every: int | None = None
    """Env-steps between the deterministic evaluations (None: none)."""
    eval_episodes: int = 50


def check_training(
    task: str,
    algo: str = "ppo",
    steps: int = 100_000,
    seed: int = 0,
    reward: str | Path | RewardSource = EXPERT,
    out: str | Path = Path("runs/train"),
    num_envs: int | None = None,
    hyperparams: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    policy_class: type[ActorCriticPolicy] = StagedActorCriticPolicy,
    init: str | Path | None = None,
    eval_every: int | None = None,
    eval_episodes: int = 50,
    own_files: Collection[str] = (),
) -> TrainSetup:
    """Everything :func:`train` checks before it builds or writes anything (its arguments are
    :func:`train`'s): the settings, the reward (a reward file is probed, see :func:`load_reward`)
    and the run ``out`` may already hold, which must be the same run
    (:class:`ResumeMismatchError`) and resumable (:class:`CheckpointError`).

    It only reads, so a refused run leaves ``out`` as it was: a caller that writes into ``out``
    before training (a transfer run's record) checks first, and names its files in
    ``own_files``. A new run is refused an ``out`` that holds anything else (a user's folder, a
    run of another kind), since it would delete ``best/`` and overwrite the metrics there.
    """
    if algo not in ALGO_CLASSES:
        raise HyperparamError("algo", "algo", f"expected one of {list(ALGOS)}, got {algo!r}")
    check_steps(steps)
    if not 0 <= seed <= SEED_MAX:
        raise ValueError(f"seed must be between 0 and {SEED_MAX}, got {seed}")
    for name, value in (("eval_every", eval_every), ("eval_episodes", eval_episodes)):
        if value is not None and value < 1:
            raise ValueError(f"{name} must be at least 1, got {value}")
    spec = get_task(task)
    run_dir = Path(out)
    ov = dict(overrides or {})
    hp: Hyperparams = load_hyperparams(spec.family, algo, hyperparams, ov, spec.id, num_envs)
    if init is not None:
        hp = hp.starting_from_policy()
    if hp.demos.episodes and init is not None:
        # Mostly a packaged task table asks for them, not the user: name the file and table.
        source, where = (
            ("overrides", "demos.episodes") if "demos" in ov else _demos_origin(hyperparams, spec)
        )
        raise HyperparamError(
            source,
            where,
            f"{hp.demos.episodes} demonstrations to warm-start from, and a trained policy to "
            "start from (init): a run starts from one, not both; add --demos 0 to start from "
            "the policy",
        )
    if (hp.demos.episodes or init is not None) and not issubclass(
        policy_class, StagedActorCriticPolicy
    ):
        raise HyperparamError(
            hyperparams or "hyperparams",
            "demos.episodes" if hp.demos.episodes else "init",
            f"a warm start needs a {StagedActorCriticPolicy.__name__}, not {policy_class.__name__}",
        )
    reward_fn, reward_meta = load_reward(reward, spec)
    meta: dict[str, Any] = {
        "task": spec.id,
        "task_sha256": spec.fingerprint,
        "family": spec.family,
        "algo": algo,
        "seed": seed,
        "reward": reward_meta,
        "num_envs": hp.num_envs,
        "hyperparams": hp.to_dict(),
        "policy_class": class_path(policy_class),
        "budget": steps,  # a linear learning rate decays to 0 there
    }
    if init is not None:
        meta["init"] = describe_init(init)
    if eval_every:
        meta["evaluation"] = {
            "every": eval_every,
            "episodes": eval_episodes,
            "seed": eval_seed(seed),
        }
    previous = None
    if (run_dir / META_FILE).exists():
        try:
            previous = read_meta(run_dir)
        except CheckpointError as err:
            raise CheckpointError(err.path, err.problem + CANNOT_RESUME) from err
        if "evaluation" in previous:
            if "evaluation" in meta:
                meta["evaluation"]["seed"] = evaluation_seed(previous)
            # A session without evaluations keeps the record for the sessions after it.
            meta.setdefault("evaluation", previous["evaluation"])
        _check_resume(previous, meta, run_dir)
        if "task_sha256" not in previous:
            # Trained on a task of unknown version so far: stamping today's would vouch for
            # every step already taken.
            del meta["task_sha256"]
        if not (run_dir / MODEL_FILE).is_file():
            raise CheckpointError(run_dir / MODEL_FILE, "missing" + CANNOT_RESUME)
    elif run_dir.exists():
        if not run_dir.is_dir():
            raise ResumeMismatchError(f"{run_dir}: a file, not a directory; give a directory")
        foreign = _foreign_entries(run_dir, frozenset(own_files))
        if foreign:
            raise ResumeMismatchError(
                f"{run_dir}: holds {some_of(foreign)}, which no training run "
                "writes, and no checkpoint to resume; train into a new or empty directory"
            )
    return TrainSetup(
        spec,
        algo,
        steps,
        seed,
        run_dir,
        hp,
        reward_fn,
        meta,
        policy_class,
        previous,
        eval_every,
        eval_episodes,
    )


class ScheduleWarning(UserWarning):
    """A resumed run's linear learning rate follows another budget than before."""


def _warn_of_a_moved_schedule(setup: TrainSetup, resumed_from: int) -> None:
    """Warn when a run with a linear learning rate resumes toward another budget than it was
    trained toward: the rate jumps (or falls faster) where it resumes, and the run follows the
    schedule of neither budget."""
    before, now = (setup.previous or {}).get("budget"), setup.steps
    algo = setup.hp.algo_config
    if before in (None, now) or algo.lr_schedule != "linear" or not 0 < resumed_from < now:
        return  # the same schedule, none, nothing trained yet, or nothing left to train
    rate = algo.learning_rate
    warnings.warn(
        f"{setup.run_dir}: its learning rate decays linearly to 0 at its budget, {before:,} "
        f"env-steps until now: with --steps {now:,} it goes on at "
        f"{rate * max(0.0, 1 - resumed_from / now):.3g}, not "
        f"{rate * max(0.0, 1 - resumed_from / before):.3g}, from {resumed_from:,} env-steps, "
        f"and the run follows neither budget's schedule (a constant lr_schedule trains on "
        "without this)",
        ScheduleWarning,
        stacklevel=3,
    )


def _notifier(logger: LoggerConfig | None, console: Console | None) -> Callable[[str], None]:
    """Prints a line of what the run does before its progress bar appears (a warm start takes
    up to a minute or two), unless progress output is off."""

    def note(text: str) -> None:
        if (logger or LoggerConfig()).progress:
            (console or Console(stderr=True, emoji=False)).print(text, highlight=False)

    return note


def _resumed_model(
    setup: TrainSetup, train_env: VecEnv, clock: WallClock, note: Callable[[str], None]
) -> BaseAlgorithm:
    """The run's model as its last checkpoint saved it, on ``train_env``."""
    model_path = setup.run_dir / MODEL_FILE
    try:
        model = ALGO_CLASSES[setup.algo].load(model_path, env=train_env, device="cpu")
    except Exception as err:
        raise CheckpointError(model_path, f"{type(err).__name__}: {err}{CANNOT_RESUME}") from err
    model._last_obs = None  # the saved observation belongs to the old process's envs
    recorded = int((setup.previous or {})["num_timesteps"])
    if model.num_timesteps != recorded:
        # Killed between model.zip and checkpoint.json: the model is the newer; record it.
        note(
            f"{setup.run_dir}: checkpoint.json records {recorded} env-steps, model.zip holds "
            f"{model.num_timesteps}: resuming from model.zip"
        )
        _save(model, setup.run_dir, setup.meta, clock)
    return model


def _new_model(
    setup: TrainSetup,
    env: BatchEnv,
    train_env: VecEnv,
    policy_kwargs: Mapping[str, Any] | None,
    note: Callable[[str], None],
) -> BaseAlgorithm:
    """A fresh model for the run: random weights, then the scripted controller's clone (a
    ``demos`` table) or the weights of a trained policy (``--init``) where the run asks."""
    hp, seed = setup.hp, setup.seed
    set_random_seed(seed)
    model = ALGO_CLASSES[setup.algo](
        setup.policy_class,
        train_env,
        policy_kwargs={
            **hp.policy.policy_kwargs(),
            **hp.algo_config.optimizer_kwargs(),
            **dict(policy_kwargs or {}),
        },
        seed=seed,
        device="cpu",
        verbose=0,
        **hp.algo_config.sb3_kwargs(),
    )
    if hp.demos.episodes:
        note(f"warm start: cloning the scripted controller over {hp.demos.episodes} episodes")
        summary = warm_start(
            model, setup.spec, env, train_env, hp.demos, hp.algo_config.gamma, seed
        )
        write_json(setup.run_dir / DEMOS_FILE, summary)
        note(
            f"warm start: {summary['episodes_kept']} of {summary['episodes_run']} "
            f"demonstrations kept, clone fitted in {summary['wall_s']:.0f} s"
        )
    if "init" in setup.meta:
        init_policy(model.policy, setup.meta["init"])
        note(
            f"starting from {setup.meta['init']['path']}: fitting the critic to "
            f"{hp.init.critic_episodes} of its episodes"
        )
        summary = warm_up_critic(model, env, train_env, hp.algo_config.gamma, hp.init, seed)
        write_json(setup.run_dir / CRITIC_WARM_UP_FILE, summary)
        note(
            f"critic fitted in {summary['wall_s']:.0f} s ({summary['successes']} of "
            f"{summary['episodes_run']} episodes succeeded with the run's action noise)"
        )
    return model


def _clear_records_after(run_dir: Path, resumed_from: int | None) -> None:
    """Drop the metrics and evaluations a run's directory holds past the checkpoint it resumes
    from (``None``: a new run)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    if resumed_from is None:
        # Files of a session killed before its first checkpoint (or of a release that wrote
        # none at step 0): rows and a best policy of a run whose settings nothing records.
        shutil.rmtree(run_dir / BEST_DIR, ignore_errors=True)
    if not resumed_from:
        # Nothing of them is kept (a run resumed at 0 trains every step again): their
        # TensorBoard events would show beside the new ones.
        shutil.rmtree(run_dir / TB_DIR, ignore_errors=True)
    MetricsWriter(run_dir).truncate_after(-1 if resumed_from is None else resumed_from)
    truncate_evaluations(run_dir, -1 if resumed_from is None else resumed_from)


def _learn(
    model: BaseAlgorithm,
    setup: TrainSetup,
    env: BatchEnv,
    clock: WallClock,
    evaluate_at_start: bool,
    logger: LoggerConfig | None,
    console: Console | None,
) -> None:
    """Train ``model`` on to the run's budget, logging, checkpointing and evaluating on the
    way. Ctrl-C saves a checkpoint before it stops the run."""
    run_dir, meta = setup.run_dir, setup.meta
    # Stable-Baselines3 collects whole rollouts: training ends at the first rollout boundary at
    # or past the budget (one rollout for --steps 1), and the progress bar counts to there.
    rollout = model.n_steps * model.n_envs
    left = max(0, setup.steps - model.num_timesteps)
    end = model.num_timesteps + rollout * -(-left // rollout)
    metrics = MetricsCallback(env, run_dir, end, logger, console, clock)
    checkpoints = CheckpointCallback(
        run_dir, setup.hp.checkpoint_every, meta, clock, start=model.num_timesteps
    )
    # The checkpoints' first: at the end of training they mark the run finished before the last
    # metrics row and the final evaluation, so Ctrl-C in either keeps it finished (cut short
    # while written, the last window's metrics row is lost; a finished run trains no more).
    callbacks: list[BaseCallback] = [checkpoints, metrics]
    if setup.eval_every:
        callbacks.append(
            DeterministicEvalCallback(
                setup.spec,
                run_dir,
                setup.eval_every,
                setup.eval_episodes,
                evaluation_seed(meta),
                meta=meta,
                at_start=evaluate_at_start,
                clock=clock,
            )
        )
    # A logger of our own before learn(): without one Stable-Baselines3 makes an empty
    # SB3-<time> folder in the temporary directory on every call (the metrics callback sets the
    # TensorBoard one once training starts).
    model.set_logger(Logger(folder=None, output_formats=[]))
    try:
        with _whole_updates(model, checkpoints):
            model.learn(
                # 0 for a finished run whose final evaluation was cut short: it runs only that.
                total_timesteps=max(0, setup.steps - model.num_timesteps),
                callback=CallbackList(callbacks),
                log_interval=None,  # type: ignore[arg-type]
                reset_num_timesteps=False,
            )
    except BaseException as err:
        # An error stops the progress bar and flushes TensorBoard (the callback does at a
        # normal end); Ctrl-C also saves the checkpoint.
        metrics.close()
        if not isinstance(err, KeyboardInterrupt):
            raise
        # Counting a rollout whose collection was cut short would have the resumed run collect
        # whole rollouts on top and stop past `steps`, with that rollout never learned from.
        model.num_timesteps = checkpoints.trained
        _save(model, run_dir, meta, clock)
        (console or Console(stderr=True, emoji=False)).print(
            f"interrupted: checkpoint saved at {model.num_timesteps} env-steps in {run_dir}"
        )
        raise


@contextmanager
def _whole_updates(model: BaseAlgorithm, checkpoints: CheckpointCallback) -> Iterator[None]:
    """Run each of ``model``'s updates whole: Ctrl-C (or SIGTERM, SIGHUP) during one is acted on
    once it is done, and the rollout it learned from is then counted (``checkpoints.trained``).
    Cut short, an update left weights that had learned part of a rollout the checkpoint saved
    with them did not count, and the resumed run learned it again."""
    update = model.train

    def whole_update() -> None:
        with interrupts_deferred():
            update()
            checkpoints.trained = model.num_timesteps

    model.train = whole_update  # type: ignore[method-assign]
    try:
        yield
    finally:
        del model.train  # the class's again (a checkpoint leaves the wrapper out)


def run_training(
    setup: TrainSetup,
    policy_kwargs: Mapping[str, Any] | None = None,
    logger: LoggerConfig | None = None,
    n_threads: int | None = None,
    console: Console | None = None,
) -> TrainResult:
    """Train the run :func:`check_training` accepted; the other arguments are :func:`train`'s."""
    torch.set_num_threads(1)
    hp, meta, run_dir, steps = setup.hp, setup.meta, setup.run_dir, setup.steps
    resuming = setup.previous is not None
    resumed_from = int(setup.previous["num_timesteps"]) if setup.previous else 0
    keep_obs_stats = bool(hp.demos.episodes) or "init" in meta
    note = _notifier(logger, console)

    # A resumed run draws fresh initial states, not a replay of the first ones.
    env_seed = int(np.random.SeedSequence([setup.seed, resumed_from]).generate_state(1)[0])
    env = make_batch_env(
        setup.spec.id,
        hp.num_envs,
        seed=env_seed,
        reward_fn=setup.reward_fn,
        n_threads=n_threads,
        training=True,
    )
    train_env: VecEnv = env
    if hp.normalize_reward:
        train_env = VecNormalize(
            env, norm_obs=False, norm_reward=True, gamma=hp.algo_config.gamma, clip_reward=10.0
        )
        # A finished run trains on no reward and may lack them; where it has them, its closing
        # checkpoint (after an evaluation still due) must write them back, not fresh ones.
        if resuming and (resumed_from < steps or (run_dir / REWARD_NORM_FILE).is_file()):
            restore_reward_norm(train_env, run_dir)

    clock = WallClock.from_checkpoint(setup.previous or {})  # a warm start's time counts
    try:
        if resuming:
            model = _resumed_model(setup, train_env, clock, note)
            resumed_from = int(model.num_timesteps)
            recorded_eval = setup.previous.get("evaluation")
            if (
                recorded_eval
                and setup.eval_every is None
                and resumed_from < steps
                and read_selection(run_dir) is not None  # only where one was chosen
            ):
                # best/ (what skills add, --init and exports take) stays the policy chosen
                # before, however far this session trains past it.
                note(
                    f"{run_dir}: this session adds no evaluations, so best/ stays the policy "
                    f"its evaluations to {resumed_from:,} env-steps chose; resume with "
                    f"--eval-every {recorded_eval['every']} --eval-episodes "
                    f"{recorded_eval['episodes']} to go on evaluating"
                )
            _warn_of_a_moved_schedule(setup, resumed_from)
            set_random_seed(env_seed)  # seed + resumed_from may pass the 2**32 numpy takes
        else:
            model = _new_model(setup, env, train_env, policy_kwargs, note)
            # Its first checkpoint before any training: a session killed while a later one is
            # written resumes from model.zip or the checkpoint before it, never from step 0 with
            # the run's record gone (a warm start's minutes lost with it).
            _save(model, run_dir, meta, clock)
        # Building or loading the model seeds the environments with the run's seed: the fresh
        # initial states of a resumed run are drawn from env_seed only from here on.
        train_env.seed(env_seed)
        if keep_obs_stats:
            # The normaliser keeps the statistics the starting policy was fitted to (the
            # demonstrations', or the trained policy's): statistics that moved with the RL
            # rollouts would shift every input it learned on (a policy object forgets this flag,
            # so a resumed run sets it again).
            model.policy.update_obs_stats = False
        rollout = model.n_steps * model.n_envs
        if model.num_timesteps - rollout >= steps:
            # Trained past where this budget stops (the first rollout at or over it): what it
            # holds is not a run of this budget, whose learning rate would also have decayed
            # sooner, and figures read from it would carry the wrong budget.
            raise ResumeMismatchError(
                f"{run_dir}: holds a run trained to {model.num_timesteps:,} env-steps, past the "
                f"{steps:,} asked for; use another --out directory or --steps "
                f"{model.num_timesteps:,} or more"
            )
        eval_every = setup.eval_every
        finished = model.num_timesteps >= steps
        if finished and not (eval_every and (last_evaluated(run_dir) or -1) < model.num_timesteps):
            return TrainResult(
                run_dir,
                model.num_timesteps,
                resumed_from,
                clock.prior_s,
                0.0,
                read_selection(run_dir),
            )
        _clear_records_after(run_dir, resumed_from if resuming else None)
        _learn(model, setup, env, clock, keep_obs_stats, logger, console)
        session_s = clock.session_s()
        # As the checkpoint stores it, so a later call that finds the run finished reports the
        # same figure.
        total_s = _save(model, run_dir, meta, clock)
        return TrainResult(
            run_dir,
            int(model.num_timesteps),
            resumed_from,
            total_s,
            session_s,
            read_selection(run_dir),
        )
    finally:
        env.close()
