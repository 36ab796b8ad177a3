"""Train a target task with a transfer method: sources, analyzer, network, then the trainer.

:func:`train_transfer` has the trainer check the run first (:func:`itskill.rl.train.check_training`:
the settings, the reward, a run already in the directory), then resolves the sources, asks the
analyzer for the contribution matrix (the methods that use it), writes ``transfer.json`` and trains
the method's network with :func:`itskill.rl.train.run_training`, which checkpoints and resumes as
usual. A refused run thus writes nothing. ``transfer.json`` is read back by a rerun on the same
directory, which then resumes with the same sources and matrix without asking the analyzer again.
A run evaluated while it trained gets a copy in its ``best/`` policy too, so that directory
describes itself.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from rich.console import Console
from stable_baselines3.common.policies import ActorCriticPolicy

from itskill.files import Check, copy_whole, write_json
from itskill.llm.client import LLMClient
from itskill.reward.candidate import CandidateNetwork
from itskill.rl.checkpoint import (
    BEST_DIR,
    CANNOT_RESUME,
    META_FILE,
    OBJECT,
    STRING,
    CheckpointError,
    class_path,
    read_record,
)
from itskill.rl.config import load_hyperparams
from itskill.rl.logger import LoggerConfig
from itskill.rl.train import (
    EXPERT,
    RewardSource,
    TrainResult,
    check_training,
    require_same,
    run_training,
    training_alone,
)
from itskill.sim.layout import MAX_STAGES
from itskill.skills import SkillSpace
from itskill.tasks import UnknownTaskError, get_task
from itskill.tasks.spec import TaskSpec
from itskill.transfer.analyzer import ContributionMatrix, analyze, validate_matrix
from itskill.transfer.config import TransferConfig, load_transfer_config
from itskill.transfer.lateral import weights_on_disk
from itskill.transfer.methods import METHODS, Method, get_method, used_settings
from itskill.transfer.sources import (
    AUTO,
    SourceError,
    SourceSkill,
    is_stages,
    parse_keys,
    resolve_sources,
)
from itskill.transfer.stages import fill_performers, stage_map, stage_performers

TRANSFER_FILE = "transfer.json"
FORMAT_VERSION = 1


def target_entry(spec: TaskSpec) -> dict[str, Any]:
    """The target as the analyzer sees it: one segment per stage of the task.

    The stage names, not the task's action list, are the segments: the attention reads the
    current stage from the observation, and a few tasks list more actions than they have stages
    (``removenut_m12`` lists unscrew, grasp, lift and has two stages, unscrew and lift).
    """
    return {
        "id": spec.id,
        "description": spec.command,
        "actions": [st.name for st in spec.stages],
    }


def analyze_sources(
    spec: TaskSpec,
    chosen: Sequence[SourceSkill],
    client: LLMClient | None,
    config: TransferConfig,
) -> ContributionMatrix:
    """The analyzer's contribution matrix of the ``chosen`` sources to the stages of ``spec``,
    asked again up to ``config.analyzer_retries`` times after an invalid reply. One source takes
    every stage, without asking: each row is [1] however the analyzer answers (a fair answer of 0
    for the stages it cannot do would be refused after its retries), and attention over one
    source weights it 1. ``client`` may then be None; it must be a client otherwise."""
    if len(chosen) == 1:
        return ContributionMatrix(
            np.ones((len(spec.stages), 1)),
            tuple(st.name for st in spec.stages),
            (chosen[0].name,),
            reasoning="one source: it takes every stage",
            client="none (one source)",
        )
    if client is None:
        raise ValueError(f"the analyzer needs a language-model client for {len(chosen)} sources")
    return analyze(
        target_entry(spec),
        [s.analyzer_entry() for s in chosen],
        client,
        retries=config.analyzer_retries,
    )


def _stage_names(task_id: str) -> list[str] | None:
    """A source task's stage names; None for a task this installation does not know (a skill
    from a user's task files that are not loaded now), whose source then sees the target's stage."""
    try:
        return [st.name for st in get_task(task_id).stages]
    except UnknownTaskError:
        return None


def _request(sources: str | Sequence[int | str]) -> str | list[int | str]:
    # A list as parse_keys reads it: NumPy's ids, which it takes, are no JSON for the record.
    return sources.strip() if isinstance(sources, str) else parse_keys(sources)


def _is_objects(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, dict) for v in value)


def _is_sources(value: Any) -> bool:
    return _is_objects(value) and all(isinstance(s.get("name"), str) for s in value)


def _is_contribution(value: Any) -> bool:
    return value is None or (isinstance(value, dict) and isinstance(value.get("matrix"), list))


def _is_request(value: Any) -> bool:
    def is_key(item: Any) -> bool:
        return isinstance(item, str) or (isinstance(item, int) and not isinstance(item, bool))

    return (
        value is None
        or isinstance(value, str)
        or (isinstance(value, list) and all(is_key(v) for v in value))
    )


def _is_source_specs(value: Any) -> bool:
    """What the networks build their sources from: a name, a policy class and its stages."""
    return _is_sources(value) and all(
        isinstance(s.get("policy_class"), str)
        and isinstance(s.get("policy"), dict)
        and is_stages(s["policy"].get("stages"))
        for s in value
    )


_RECORD_FIELDS: dict[str, Check] = {
    "target": STRING,
    "method": Check(f"one of {', '.join(METHODS)}", lambda v: isinstance(v, str) and v in METHODS),
    "config": OBJECT,
    "sources_request": Check(
        '"auto", a list of skill names and serial numbers, or null', _is_request
    ),
    "sources": Check("a list of objects with a string name", _is_sources),
    "source_specs": Check(
        "a list of objects with a string name and policy_class and a policy with stages",
        _is_source_specs,
    ),
    "contribution": Check("an object with a matrix, or null", _is_contribution),
    "performers": Check("a list or null", lambda v: v is None or isinstance(v, list)),
    "requested": Check("a list of objects with a string name", _is_sources),
}
"""What each ``transfer.json`` field its readers index must hold: :func:`read_transfer` checks
them, so a hand-edited or damaged record is refused with its file named, not by a TypeError
where the field is first used."""
# Absent from records written before the residual, and before PST's dropped sources were kept.
_OPTIONAL_FIELDS = ("performers", "requested")


def read_transfer(run_dir: str | Path) -> dict[str, Any]:
    """``transfer.json`` of a transfer run directory, checked; :class:`CheckpointError` names the
    file and says what is wrong (missing, not JSON, not UTF-8, of another format, a field
    missing or of the wrong type)."""
    path = Path(run_dir) / TRANSFER_FILE
    if not path.is_file():
        raise CheckpointError(path, "missing (not a directory written by train_transfer)")
    required = [key for key in _RECORD_FIELDS if key not in _OPTIONAL_FIELDS]
    record = read_record(path, required, _RECORD_FIELDS)
    if record.get("format", FORMAT_VERSION) != FORMAT_VERSION:
        raise CheckpointError(
            path,
            f"transfer record format {record['format']!r}, this version reads {FORMAT_VERSION}",
        )
    return record


# Settings a run directory written before they existed was trained with: its network had no
# source-action residual.
_LEGACY_CONFIG = {"residual": False}


def _recorded_config(record: dict[str, Any]) -> dict[str, Any]:
    """The :class:`TransferConfig` fields a run's ``record`` trained with, those a record from
    before a setting existed lacks at the value its run had."""
    return {**_LEGACY_CONFIG, **record["config"]}


def network_settings(record: dict[str, Any]) -> dict[str, Any]:
    """The transfer settings a run's ``record`` (:func:`read_transfer`) trained with that shape
    its method's network or its choice of sources (:attr:`Method.settings`), by
    :class:`TransferConfig` field."""
    return used_settings([record["method"]], _recorded_config(record))


def _check_resume(old: dict[str, Any], new: dict[str, Any], out: Path) -> None:
    old = {**old, "config": _recorded_config(old)}
    keys = ("target", "method", "algo", "seed", "sources_request", "k")
    # A skill named by its serial number is the same source as by its name: the record knows
    # which serial numbers the skills asked for had, those PST did not keep included.
    asked = old.get("requested", old["sources"])
    names = {s.get("id"): s["name"] for s in asked if isinstance(s.get("id"), int)}
    have, want = _as_compared(old, names), _as_compared(new, names)
    require_same(have, want, keys, out, "transfer run")
    # Setting by setting, so that the message names the one that differs.
    require_same(
        {f"config.{k}": v for k, v in have["config"].items()},
        {f"config.{k}": v for k, v in want["config"].items()},
        [f"config.{k}" for k in want["config"]],
        out,
        "transfer run",
    )


def _as_compared(settings: dict[str, Any], names: dict[int, str]) -> dict[str, Any]:
    """The settings as a resume compares them: the sources as the skills they name, however
    the list was written ("a,b" on the command line, a list from Python, serial numbers the
    record's sources had, ``names``, or their names), and only the settings the run's method
    uses (:func:`_unused`)."""
    request = settings.get("sources_request")
    if request is not None and request != AUTO:
        request = [
            names.get(key, key) if isinstance(key, int) else key for key in parse_keys(request)
        ]
    unused = _unused(settings["method"], request)
    config = {k: v for k, v in settings["config"].items() if k not in unused}
    k = None if "k" in unused else settings.get("k")
    return {**settings, "sources_request": request, "k": k, "config": config}


def _unused(method: str, request: Any) -> set[str]:
    """The :class:`TransferConfig` fields a run of ``method`` with sources ``request`` does not
    depend on, which a resume need not be given again: all but the method's own
    (:attr:`Method.settings`, which shape its network or its choice of sources), and how many
    sources to retrieve and whether alike ones are skipped where they are retrieved
    (``request`` is ``auto``). The record holds the analyzer's matrix and the sources, so
    neither the analyzer's retries nor the retrieval's success threshold matter again; a
    resumed network is loaded whole, so a setting its method does not read cannot change it."""
    everything = {f.name for f in fields(TransferConfig)}
    meth = get_method(method)  # a record's was checked when it was read
    if not meth.uses_sources:
        return everything
    used = set(meth.settings) | ({"k", "distinct_actions"} if request == AUTO else set())
    return everything - used


def _settings(
    spec: TaskSpec,
    meth: Method,
    sources: str | Sequence[int | str],
    seed: int,
    algo: str,
    config: TransferConfig,
) -> dict[str, Any]:
    """The settings part of a transfer record: what a rerun must ask for again to resume."""
    return {
        "format": FORMAT_VERSION,
        "target": spec.id,
        "command": spec.command,
        "method": meth.name,
        "algo": algo,
        "seed": seed,
        "sources_request": _request(sources) if meth.uses_sources else None,
        "k": config.k if meth.uses_sources else None,
        "config": config.to_dict(),
    }


def _recorded(out: Path, settings: dict[str, Any]) -> dict[str, Any] | None:
    """The record ``out`` holds, checked against ``settings``; None if it holds none."""
    if not (out / TRANSFER_FILE).is_file():
        return None
    try:
        old = read_transfer(out)
    except CheckpointError as err:
        raise CheckpointError(err.path, err.problem + CANNOT_RESUME) from err
    _check_resume(old, settings, out)
    _check_against_target(out / TRANSFER_FILE, old)
    return old


def _indices(value: Any, length: int, low: int, high: int) -> bool:
    """Whether ``value`` is a list of ``length`` integers in ``[low, high)``."""
    return (
        isinstance(value, list)
        and len(value) == length
        and all(isinstance(v, int) and not isinstance(v, bool) and low <= v < high for v in value)
    )


def _check_against_target(path: Path, record: dict[str, Any]) -> None:
    """:class:`CheckpointError` unless what the record says per target stage fits its target's
    stages and its sources: the contribution matrix (a row per stage, a column per source, each
    row a distribution), the source that performs each stage (``performers``: a source index or
    -1) and each source's own stage for each target stage (``stage_map``). A hand-edited record,
    or one of a task file whose stages changed since, was applied to the wrong stages without a
    word (fewer rows), or stopped the run with a traceback where the network was built."""
    stages = [st.name for st in get_task(record["target"]).stages]
    names = [s["name"] for s in record["sources"]]

    def refuse(problem: str) -> NoReturn:
        raise CheckpointError(path, problem + CANNOT_RESUME)

    specs = [s["name"] for s in record["source_specs"]]
    if specs != names:
        refuse(f"source_specs: the networks of {specs}, but the sources are {names}")
    performers = record.get("performers")
    if performers is not None and not _indices(performers, len(stages), -1, len(names)):
        refuse(
            f"performers: expected {len(stages)} source indices in [-1, {len(names)}) (a source "
            f"per stage of {record['target']}, -1 for none), got {performers!r}"
        )
    for spec in record["source_specs"]:
        mapped = spec.get("stage_map")
        if mapped is not None and not _indices(mapped, len(stages), 0, MAX_STAGES):
            refuse(
                f"source_specs: stage_map of {spec.get('name')!r}: expected {len(stages)} stage "
                f"indices in [0, {MAX_STAGES}) (its own stage for each stage of "
                f"{record['target']}), got {mapped!r}"
            )
    contribution = record["contribution"]
    if contribution is None:
        return
    if contribution.get("sources", names) != names:
        refuse(
            f"contribution: its columns are {contribution['sources']}, but the sources are "
            f"{names}: each column would weight another source"
        )
    if contribution.get("segments", stages) != stages:
        refuse(
            f"contribution: its segments {contribution['segments']} are not the stages of "
            f"{record['target']}, {stages}"
        )
    try:
        validate_matrix(contribution["matrix"], len(stages), len(names))
    except ValueError as err:
        refuse(f"contribution: {err}")


def _check_untrained_sources(out: Path, record: dict[str, Any]) -> None:
    """:class:`SourceError` if ``out`` holds no checkpoint and a source of its ``record`` no
    longer has the weights the record chose (a skill retrained, replaced or removed since).

    A checkpoint carries the weights its network trained with, so a run that has one resumes
    whatever became of its skills; without one, the network is built from the skills on disk,
    and a source it cannot read would refuse to act at the first step of every attempt."""
    if (out / META_FILE).is_file():
        return
    changed = [repr(s.get("name")) for s in record["source_specs"] if not weights_on_disk(s)]
    if changed:
        raise SourceError(
            f"{out / TRANSFER_FILE}: the weights of source skill(s) {', '.join(changed)} changed "
            "or are gone since this record chose them (a skill retrained, replaced or removed); "
            "the run has trained nothing yet: start it in another --out, or delete "
            f"{TRANSFER_FILE} there to choose its sources anew"
        )


def prepare_transfer(
    target: str,
    method: str,
    sources: str | Sequence[int | str] = AUTO,
    seed: int = 0,
    algo: str = "ppo",
    out: str | Path = Path("runs/transfer"),
    client: LLMClient | None = None,
    config: TransferConfig | None = None,
    space: SkillSpace | None = None,
    target_stages: Sequence[int] | None = None,
) -> dict[str, Any]:
    """The record of a transfer run in ``out`` (``transfer.json``): its sources, the analyzer's
    contribution matrix and the stages each source performs, resolved and written once.

    A record already in ``out`` is checked against these settings
    (:class:`~itskill.rl.train.ResumeMismatchError` if they differ) and returned without asking
    the analyzer again, so that whatever trains with this network (the run itself, or the reward
    search's candidates before it) sees the same sources and matrix; while ``out`` holds no
    checkpoint, a source whose weights changed since the record was written is a
    :class:`~itskill.transfer.sources.SourceError`. Sources that cannot join the
    method's network over a target of ``target_stages`` (default: the task's packaged
    hyper-parameters) are refused before the analyzer is asked or anything is written.
    """
    spec, meth = get_task(target), get_method(method)
    config = config or load_transfer_config()
    out = Path(out)
    record = _settings(spec, meth, sources, seed, algo, config)
    old = _recorded(out, record)
    if old is not None:
        _check_untrained_sources(out, old)
        return old
    requested: list[SourceSkill] = []
    chosen: list[SourceSkill] = []
    matrix: ContributionMatrix | None = None
    if meth.uses_sources:
        requested = resolve_sources(spec.id, sources, config, space)
        chosen = meth.select(requested, config)
        if target_stages is None:
            target_stages = load_hyperparams(spec.family, algo, task=spec.id).policy.stages
        meth.policy_class.check_sources([s.spec() for s in chosen], target_stages)
    stage_names = [st.name for st in spec.stages]
    if meth.uses_prior:
        if client is None and len(chosen) > 1:
            from itskill.llm.client import make_client

            client = make_client()
        matrix = analyze_sources(spec, chosen, client, config)
    policy_class = meth.policy_class
    source_stages = [_stage_names(s.task_id) for s in chosen]
    record.update(
        sources=[s.to_dict() for s in chosen],
        requested=[{"id": s.id, "name": s.name} for s in requested],
        source_specs=[
            s.spec()
            if names is None
            else {**s.spec(), "stage_map": list(stage_map(stage_names, names))}
            for s, names in zip(chosen, source_stages, strict=True)
        ],
        performers=(
            list(
                fill_performers(
                    stage_performers(stage_names, source_stages),
                    spec.actions,
                    [s.actions for s in chosen],
                )
            )
            if chosen and config.residual
            else None
        ),
        contribution=None if matrix is None else matrix.to_dict(),
        policy_class=class_path(policy_class),
        created=time.time(),
    )
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / TRANSFER_FILE, record)
    return record


def transfer_network(
    record: dict[str, Any], config: TransferConfig | None = None
) -> tuple[type[ActorCriticPolicy], dict[str, Any] | None]:
    """The policy class a transfer run's ``record`` trains and its keyword arguments (frozen
    sources, prior, source-action residual; None for a method without sources)."""
    meth = get_method(record["method"])
    if not meth.uses_sources:
        return meth.policy_class, None
    config = config or load_transfer_config()
    contribution = record["contribution"]
    return meth.policy_class, {
        "sources": record["source_specs"],
        "prior": None if contribution is None else contribution["matrix"],
        "performers": record.get("performers"),
        **config.policy_kwargs(),
    }


def search_network(
    target: str,
    method: str,
    out: str | Path,
    sources: str | Sequence[int | str] = AUTO,
    seed: int = 0,
    algo: str = "ppo",
    client: LLMClient | None = None,
    config: TransferConfig | None = None,
    space: SkillSpace | None = None,
) -> CandidateNetwork | None:
    """The network a reward search for ``target`` trains its candidates with: ``method``'s
    transfer network over its sources, so that a reward is judged by what it teaches the network
    that will learn the task. The run's record is written to ``out`` (see
    :func:`prepare_transfer`): a transfer run there later trains the same network. None for a
    method without sources (candidates then train the family's network from scratch).
    """
    if not get_method(method).uses_sources:
        return None
    config = config or load_transfer_config()
    record = prepare_transfer(target, method, sources, seed, algo, out, client, config, space)
    policy_class, policy_kwargs = transfer_network(record, config)
    names = ", ".join(s["name"] for s in record["sources"])
    label = f"{record['method']} over {names}"
    return CandidateNetwork(policy_class, policy_kwargs, label, _without_scripted_start(None))


def _without_scripted_start(overrides: dict[str, Any] | None) -> dict[str, Any]:
    """``overrides`` with the task's scripted warm start off (``demos.episodes = 0``) unless they
    set it themselves, for a network with sources: it starts from them, and cannot take the
    staged policy's clone of the script (a task table's demonstrations refused every such
    network). No_Transfer, the target network alone, keeps its task's settings, as its reward
    search's candidates on that network do and as runs before this rule trained."""
    ov = dict(overrides or {})
    demos = ov.get("demos", {})
    if isinstance(demos, Mapping):  # anything else is refused by the hyper-parameters, named
        ov["demos"] = {"episodes": 0, **demos}
    return ov


def train_transfer(
    target: str,
    method: str,
    sources: str | Sequence[int | str] = AUTO,
    seed: int = 0,
    steps: int = 200_000,
    algo: str = "ppo",
    out: str | Path = Path("runs/transfer"),
    reward: str | Path | RewardSource = EXPERT,
    num_envs: int | None = None,
    eval_every: int | None = None,
    eval_episodes: int = 50,
    n_threads: int | None = None,
    client: LLMClient | None = None,
    config: TransferConfig | None = None,
    console: Console | None = None,
    progress: bool = True,
    space: SkillSpace | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    logger: LoggerConfig | None = None,
) -> TrainResult:
    """Train ``target`` with transfer ``method`` (``itn``, ``nia``, ``dfs``, ``pst``,
    ``no_transfer``) until ``steps`` env-steps, in run directory ``out``.

    ``sources`` is ``"auto"`` (the ``config.k`` skills retrieved for the target's command) or skill
    ids/names. ``client`` answers the analyzer (default: :func:`itskill.llm.client.make_client`,
    i.e. ``$ITSKILL_LLM_MODEL`` or the offline backend). ``reward``, ``num_envs``,
    ``eval_every``, ``eval_episodes``, ``n_threads``, ``hyperparams`` and ``overrides`` are
    :func:`itskill.rl.train.train`'s, except that a method with sources never warm-starts from
    the task's scripted demonstrations (``demos.episodes`` is 0 unless ``overrides`` set it).
    Rerunning on the same ``out`` resumes; a run refused (its settings, its reward, another run
    already in ``out``, or another session training there) leaves ``out`` as it was.
    """
    config = config or load_transfer_config()
    out = Path(out)
    spec, meth = get_task(target), get_method(method)
    with training_alone(out):
        # A record already in out, then the trainer, check the run before a record is written: a
        # refused run (another run in out, a bad seed or reward file) must leave out as it was, with
        # no transfer.json to block the next command.
        _recorded(out, _settings(spec, meth, sources, seed, algo, config))
        setup = check_training(
            spec.id,
            algo,
            steps,
            seed,
            reward,
            out,
            num_envs,
            hyperparams,
            _without_scripted_start(overrides) if meth.uses_sources else overrides,
            policy_class=meth.policy_class,
            eval_every=eval_every,
            eval_episodes=eval_episodes,
            own_files=(TRANSFER_FILE,),
        )
        if setup.previous is not None and not (out / TRANSFER_FILE).is_file():
            # Resumed with whatever sources this call names, the checkpoint's network would go on
            # under a record of another one.
            what = (
                "the run's sources and contribution matrix are unknown"
                if meth.uses_sources
                else "the directory holds a run not trained as a transfer (an `itskill train` run?)"
            )
            raise CheckpointError(out / TRANSFER_FILE, f"missing: {what}" + CANNOT_RESUME)
        record = prepare_transfer(
            target, method, sources, seed, algo, out, client, config, space, setup.hp.policy.stages
        )
        _, policy_kwargs = transfer_network(record, config)
        if console is not None and record["sources"]:
            names = ", ".join(s["name"] for s in record["sources"])
            # Not markup: skill names are the user's text ('pick[/v2]').
            console.print(
                f"{record['method']} on {record['target']}: sources {names}", markup=False
            )
        result = run_training(
            setup,
            policy_kwargs,
            logger=logger or LoggerConfig(progress=progress),
            n_threads=n_threads,
            console=console,
        )
        if result.best is not None:
            # The kept best policy describes itself like the run does (method, sources, prior).
            copy_whole(out / TRANSFER_FILE, out / BEST_DIR / TRANSFER_FILE)
        return result
