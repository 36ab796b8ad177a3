"""Training-run checkpoints: write them atomically, load the policy back with clear errors.

A run directory holds, after every checkpoint:

- ``model.zip``: the full SB3 model (policy, optimiser state, step count) to resume training;
- ``policy.safetensors``: the policy's weights and observation-normaliser statistics only, what a
  frozen transfer source or an evaluation needs;
- ``checkpoint.json``: metadata (task, algorithm, seed, env-steps done, observation size, policy
  shape, hyper-parameters, reward, versions). It is written last, so its presence means the two
  files beside it are complete. Ctrl-C waits for a checkpoint being written to be finished; a run
  killed between ``model.zip`` and ``checkpoint.json`` is found out on resume (``model.zip``'s
  own step count is the truth) and its record repaired. A new run writes its first checkpoint
  before it trains, so there is always a record to repair.

A run evaluated while it trained also holds ``best/``: ``policy.safetensors`` and
``checkpoint.json`` of the policy that scored best in those evaluations, the latter with a
``selection`` record (env-steps, success, episodes). :func:`best_policy_dir` picks it.

``as_policy`` turns a run directory into the evaluation ``Policy`` interface of
:mod:`itskill.tasks.evaluate`. That module sits below ``rl`` and does not import it; the CLI (above
both) calls ``as_policy`` before handing a policy reference down.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import platform
import signal
import threading
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecNormalize

from itskill.datafile import is_count, is_number
from itskill.executors import STOP_SIGNALS
from itskill.files import (
    Check,
    CorruptFileError,
    check_shape,
    copy_whole,
    read_json,
    replaced_whole,
    write_text,
)
from itskill.rl.clock import EVAL_WALL_KEY, TRAIN_WALL_KEY
from itskill.rl.policy import PolicyConfig, StagedActorCriticPolicy
from itskill.sim.layout import OBSERVATION_LAYOUT, OBSERVATION_VERSION
from itskill.sim.vec_env import action_space, observation_space
from itskill.tasks.evaluate import (
    SCRIPTED,
    CheckpointError,
    Policy,
    PolicyActor,
    PolicyFactory,
)
from itskill.tasks.spec import TaskSpec

MODEL_FILE = "model.zip"
POLICY_FILE = "policy.safetensors"
META_FILE = "checkpoint.json"
REWARD_NORM_FILE = "reward_norm.json"
FORMAT_VERSION = 1
REQUIRED_META = ("format", "task", "algo", "seed", "num_timesteps", "obs_size", "policy")
CANNOT_RESUME = (
    "; the run cannot be resumed from it: train into another run directory (--out). Its "
    "metrics.csv and eval.csv stay readable"
)
"""What a damaged checkpoint's error adds when a run was to resume from it."""


_COUNT = Check("an integer of 0 or more", is_count)
STRING = Check("a string", lambda v: isinstance(v, str))
OBJECT = Check("an object", lambda v: isinstance(v, dict))
_SECONDS = Check("a finite number of 0 or more", lambda v: is_number(v) and v >= 0)
_EVALUATION = Check(
    "an object of two whole numbers of 1 or more, every and episodes",
    lambda v: (
        isinstance(v, dict) and all(is_count(v.get(k)) and v[k] >= 1 for k in ("every", "episodes"))
    ),
)
META_FIELDS: dict[str, Check] = {
    "format": _COUNT,
    "task": STRING,
    "task_sha256": STRING,
    "algo": STRING,
    "seed": _COUNT,
    "num_timesteps": _COUNT,
    "budget": _COUNT,
    "obs_size": _COUNT,
    "obs_version": _COUNT,
    "action_size": _COUNT,
    "policy": OBJECT,
    "policy_class": STRING,
    "reward": OBJECT,
    "hyperparams": OBJECT,
    "init": OBJECT,
    "evaluation": _EVALUATION,
    TRAIN_WALL_KEY: _SECONDS,
    EVAL_WALL_KEY: _SECONDS,
}
"""What each ``checkpoint.json`` field that its readers use must hold (those not in
:data:`REQUIRED_META` only when present): :func:`read_meta` checks them, so a hand-edited or
damaged record is refused with the field named, not by a traceback deep in a resume."""
BEST_DIR = "best"
"""Subdirectory of a run holding the policy that scored best in the evaluations during training
(:class:`itskill.rl.eval_callback.DeterministicEvalCallback`)."""


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


def save_checkpoint(
    model: Any, run_dir: Path, meta: Mapping[str, Any], resumable: bool = True
) -> dict[str, Any]:
    """Write ``model.zip``, ``policy.safetensors`` and ``checkpoint.json`` into ``run_dir``.

    ``meta`` carries the run's description; the step count, layout size and versions are added.
    With ``resumable`` False only the policy and its metadata are written (no optimiser state):
    enough to evaluate it or use it as a skill, not to continue its training. Returns the metadata
    written.
    """
    with interrupts_deferred():
        return _save_checkpoint(model, run_dir, meta, resumable)


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP until the block has run, then act on the first as its
    handler would have.

    A checkpoint cut short between its files would pair new weights with an old record. Only
    signals with a Python handler are held (one set to be ignored stays ignored; one left at the
    operating system's default still ends the process), and only in the main thread, the one
    that can change handlers.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    held = {sig: handler for sig, handler in previous.items() if callable(handler)}
    received: list[tuple[int, Any]] = []
    for sig in held:
        signal.signal(sig, lambda signum, frame: received.append((signum, frame)))
    try:
        yield
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
        if received:
            signum, frame = received[0]
            held[signum](signum, frame)


def _save_checkpoint(
    model: Any, run_dir: Path, meta: Mapping[str, Any], resumable: bool
) -> dict[str, Any]:
    run_dir.mkdir(parents=True, exist_ok=True)
    if resumable:
        with replaced_whole(run_dir / MODEL_FILE) as tmp:
            # While it trains, the model holds the session's wrapper of its update (the one
            # that holds Ctrl-C until an update is done, itskill.rl.train): no state, and it
            # cannot be pickled.
            model.save(tmp, exclude=["train"])
    state = {k: v.detach().cpu().contiguous() for k, v in model.policy.state_dict().items()}
    with replaced_whole(run_dir / POLICY_FILE) as tmp:
        save_file(state, str(tmp), metadata={"format": str(FORMAT_VERSION)})
    full = {
        "format": FORMAT_VERSION,
        **meta,
        "num_timesteps": int(model.num_timesteps),
        "obs_size": OBSERVATION_LAYOUT.size,
        "obs_version": OBSERVATION_VERSION,
        "action_size": int(action_space().shape[0]),
        "policy": model.policy.config.to_dict(),
        "versions": versions(),
    }
    env = model.get_env()
    if resumable and isinstance(env, VecNormalize):
        rms = env.ret_rms
        stats = {"mean": float(rms.mean), "var": float(rms.var), "count": float(rms.count)}
        write_text(run_dir / REWARD_NORM_FILE, json.dumps(stats) + "\n")
    write_text(run_dir / META_FILE, json.dumps(full, indent=2) + "\n")
    return full


def restore_reward_norm(env: VecNormalize, run_dir: Path) -> None:
    """Give ``env`` the return statistics saved with the checkpoint in ``run_dir``, so a resumed
    run scales rewards as the interrupted one did; :class:`CheckpointError` if they are missing
    (fresh statistics would rescale every reward the policy learned from) or damaged."""
    path = Path(run_dir) / REWARD_NORM_FILE
    if not path.is_file():
        raise CheckpointError(
            path,
            "missing: the run normalises its rewards and the statistics it scaled them with are "
            "gone" + CANNOT_RESUME,
        )
    try:
        stats = json.loads(path.read_text())
        env.ret_rms.mean, env.ret_rms.var = float(stats["mean"]), float(stats["var"])
        env.ret_rms.count = float(stats["count"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CheckpointError(path, f"corrupt reward-normalisation statistics: {err}") from err


def read_record(
    path: Path, required: Iterable[str], fields: Mapping[str, Check], prefix: str = ""
) -> dict[str, Any]:
    """The JSON object in ``path``, with each of ``required`` and each field of the kind
    ``fields`` says; otherwise :class:`CheckpointError` on ``path`` (not JSON, not UTF-8, not an
    object, fields missing or of the wrong kind), ``prefix`` before the problem."""
    try:
        record = read_json(path)
        check_shape(path, record, dict)
        missing = [k for k in required if k not in record]
        if missing:
            raise CorruptFileError(path, f"missing field(s) {', '.join(missing)}")
        check_shape(path, record, {f"{key}?": check for key, check in fields.items()})
    except CorruptFileError as err:
        raise CheckpointError(path, prefix + err.problem) from err
    return record


TASK_CHANGED = "its parts, start, stages, success or length have changed since"
"""What differs when a checkpoint's task fingerprint is not its task's now."""


def trained_on_another_version(meta: Mapping[str, Any], fingerprint: str) -> bool:
    """Whether the checkpoint record ``meta`` was trained on another version of its task than
    the one whose :attr:`~itskill.tasks.spec.TaskSpec.fingerprint` is ``fingerprint``. A record
    from before the fingerprint was kept (2026-12-07) is taken as it was."""
    return meta.get("task_sha256", fingerprint) != fingerprint


def _nested_checkpoints(run_dir: Path, deepest: int = 4) -> list[Path]:
    """The directories nearest below ``run_dir`` (at most ``deepest`` levels) that hold a
    checkpoint record, relative to it: those at the first depth that has any."""
    for depth in range(1, deepest + 1):
        found = sorted(run_dir.glob("/".join(["*"] * depth) + f"/{META_FILE}"))
        if found:
            return [p.parent.relative_to(run_dir) for p in found]
    return []


def read_meta(run_dir: str | Path) -> dict[str, Any]:
    """``checkpoint.json`` of ``run_dir``, checked; :class:`CheckpointError` says what is wrong."""
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise CheckpointError(run_dir, "no such checkpoint directory")
    if not run_dir.is_dir():
        raise CheckpointError(run_dir, "not a directory (expected a training run directory)")
    path = run_dir / META_FILE
    if not path.is_file():
        nested = _nested_checkpoints(run_dir)
        if nested:
            # A learn run or an experiment holds its trainings in directories of their own.
            shown = ", ".join(str(d) for d in nested[:3]) + (", ..." if len(nested) > 3 else "")
            raise CheckpointError(
                path, f"missing: the checkpoints are in directories below it ({shown})"
            )
        raise CheckpointError(
            path, "missing: the directory holds no finished checkpoint (train into it first)"
        )
    meta = read_record(path, REQUIRED_META, META_FIELDS, "corrupt metadata: ")
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
    if meta.get("obs_version", OBSERVATION_VERSION) != OBSERVATION_VERSION:
        raise CheckpointError(
            path,
            f"trained on observation layout version {meta['obs_version']}, this release "
            f'observes version {OBSERVATION_VERSION} (docs/simulation.md, "Observation"): '
            "the policy would see other values than it learned from; retrain it",
        )
    return meta


def policy_location(checkpoint_file: str | Path) -> Path:
    """Where the policy in ``checkpoint_file`` loads from: a weights file (``.safetensors``) from
    its directory, which holds its metadata; any other file (a Stable-Baselines3 ``.zip``) as it
    is."""
    path = Path(checkpoint_file)
    return path.parent if path.suffix == ".safetensors" else path


def policy_sha256(run_dir: str | Path) -> str:
    """The SHA-256 of a run's ``policy.safetensors``: what tells one set of its weights from
    another (a skill retrained in place keeps its directory)."""
    return hashlib.sha256((Path(run_dir) / POLICY_FILE).read_bytes()).hexdigest()


def best_policy_dir(run_dir: str | Path) -> Path:
    """The directory of the policy to use from a training run: its best evaluated policy
    (``run_dir/best``) if the run was evaluated while it trained, else its last checkpoint.

    PPO can lose a level it reached (the deterministic policy drifts while the exploring one
    barely succeeds), so the last checkpoint is not always the best one the run produced.
    """
    best = Path(run_dir) / BEST_DIR
    return best if (best / META_FILE).is_file() else Path(run_dir)


def export_policy(run_dir: str | Path, target: str | Path) -> Path:
    """Copy the policy to use from a training run (:func:`best_policy_dir`) or a skill directory
    into ``target``, as a skill directory that another machine can load. A stop part-way leaves
    the old policy there or the new one, never a truncated file.

    The path of a policy the run started from stays behind (it names a directory on this
    machine); its task, env-steps and weight hash still say which policy that was.
    """
    source = best_policy_dir(run_dir)
    meta = read_meta(source)
    if "init" in meta:
        meta["init"] = {k: v for k, v in meta["init"].items() if k != "path"}
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    # Often over a skill in use (pretraining into the library): each file is replaced whole, and
    # Ctrl-C waits for the pair, so no reader finds truncated weights or a record of others.
    with interrupts_deferred():
        copy_whole(source / POLICY_FILE, target / POLICY_FILE)
        write_text(target / META_FILE, json.dumps(meta, indent=2) + "\n")
    return target


def build_policy(config: PolicyConfig) -> StagedActorCriticPolicy:
    """An untrained policy of the given shape for the shared observation/action spaces.

    ``ortho_init`` is off: the weights are about to be overwritten by a checkpoint's.
    """
    kwargs = config.policy_kwargs()
    kwargs["ortho_init"] = False
    return StagedActorCriticPolicy(observation_space(), action_space(), lambda _: 0.0, **kwargs)


def class_path(cls: type) -> str:
    """The import path a checkpoint records for a policy class (``module.Class``), the one
    :func:`policy_from_meta` imports it back from."""
    return f"{cls.__module__}.{cls.__qualname__}"


STAGED_POLICY_CLASS = class_path(StagedActorCriticPolicy)


def policy_from_meta(
    policy_class: str, config: Mapping[str, Any], where: str | Path
) -> ActorCriticPolicy:
    """An untrained policy of the class and shape recorded in a checkpoint.

    ``policy_class`` is the import path the trainer records (``module.Class``). The staged policy
    is built from its :class:`PolicyConfig`; any other class must provide a classmethod
    ``from_config(config)`` (the transfer policies do), so this layer never imports them. Only
    classes of the ``itskill`` package are imported: the class a checkpoint names is never code
    of its own.
    """
    cls = (
        StagedActorCriticPolicy
        if policy_class == STAGED_POLICY_CLASS
        else _policy_class(policy_class, where)
    )
    try:
        if cls is StagedActorCriticPolicy:
            return build_policy(PolicyConfig(**{**config, "stages": tuple(config["stages"])}))
        return cls.from_config(dict(config))
    except (TypeError, ValueError, KeyError) as err:
        problem = f"missing field {err}" if isinstance(err, KeyError) else str(err)
        raise CheckpointError(where, f"corrupt policy description: {problem}") from err


def _policy_class(path: str, where: str | Path) -> type[ActorCriticPolicy]:
    """The policy class at import path ``path``, imported only from the ``itskill`` package:
    loading imports the module a checkpoint names, and a skill from elsewhere could name one of
    its own beside it (under ``python -m`` the current directory is on the path)."""
    module, _, name = path.rpartition(".")
    if module.partition(".")[0] != "itskill":
        raise CheckpointError(where, f"policy class {path!r} is not one of itskill's; not imported")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as err:
        raise CheckpointError(where, f"cannot build policy class {path!r}: {err}") from err
    if not (isinstance(cls, type) and issubclass(cls, ActorCriticPolicy)):
        raise CheckpointError(where, f"{path!r} is not a policy class")
    return cls


def load_policy(run_dir: str | Path) -> ActorCriticPolicy:
    """The policy of the last checkpoint in ``run_dir``: eval mode, statistics frozen, on CPU.

    The class is the one recorded in ``checkpoint.json`` (``policy_class``; checkpoints without
    it hold a :class:`StagedActorCriticPolicy`). Raises :class:`CheckpointError` (a
    ``ValueError`` naming the path and the problem) if the directory, its metadata or its weights
    are missing, corrupt or do not fit.
    """
    run_dir = Path(run_dir)
    meta = read_meta(run_dir)
    policy = policy_from_meta(
        meta.get("policy_class", STAGED_POLICY_CLASS), meta["policy"], run_dir / META_FILE
    )
    path = run_dir / POLICY_FILE
    if not path.is_file():
        raise CheckpointError(path, "missing policy weights")
    try:
        state = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as err:
        raise CheckpointError(path, f"corrupt policy weights: {err}") from err
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
    """A training run directory becomes a policy factory; anything else is returned unchanged.
    ``"scripted"`` names the task's controller even where a folder of that name exists (which
    ``./scripted`` reaches)."""
    if isinstance(ref, str | Path) and ref != SCRIPTED and Path(ref).is_dir():
        run_dir = Path(ref)
        read_meta(run_dir)  # fail early, before any environment is built

        def factory(spec: TaskSpec, num_envs: int) -> Policy:
            return TrainedPolicy(run_dir)

        factory.__name__ = str(run_dir)
        return factory
    return ref
