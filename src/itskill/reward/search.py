"""The reward optimisation loop (the paper's section III-A; Eureka's loop, made resumable).

For each of ``iterations`` iterations: ask the model for ``samples`` rewards (with, after the
first, the best reward so far and how its policy trained), check each in the sandbox and on a probe
batch (regenerating broken ones with the error), train every accepted one as a job on the executor,
and keep the best: highest success, ties broken by correlation with the expert reward. A
candidate's success on the search's seed is partly luck at a short budget, so before the choice
the ``select_top`` best distinct rewards are retrained on ``select_seeds`` more seeds, and the one
with the highest mean over all its seeds is chosen. Candidates train the trainer's network from
scratch, or the :class:`~itskill.reward.candidate.CandidateNetwork` given (a transfer network
for a complex task: :func:`itskill.transfer.search_network`). Then retrain the chosen reward with
``final_seeds`` fresh seeds, and the expert reward with the same budget and seeds, and plot
success per iteration against the expert (Fig. 6).

Run directory (every file written atomically; see ``docs/reward.md``)::

    config.json  plan.json  usage.json  llm_cache/  network/ (a transfer network's record, if any)
    iter_<i>/sample_<k>/{reply.txt, reward.py, status.json, result.json, train/seed_<s>/}
    iter_<i>/summary.json
    select/reward_<code hash>_seed<s>/{result.json, train/}
    best_reward.py  final/{generated_<code hash>,expert}_seed<s>/  summary.json  fig6.png

Resuming (``resume=True``) replays the model's replies from ``llm_cache/`` in the original order,
never retrains a candidate whose ``result.json`` exists, and restarts the others (their training
continues from its last checkpoint).
"""

from __future__ import annotations

import ast
import hashlib
import json
import math
import shutil
from collections.abc import Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

import itskill
from itskill.executors import check_executor, default_workers, run_jobs
from itskill.files import (
    check_shape,
    foreign_entries,
    held_alone,
    read_json,
    read_utf8,
    some_of,
    write_json,
    write_text,
)
from itskill.llm.client import LLMClient, Message, Usage, make_client
from itskill.llm.offline.backend import BACKEND
from itskill.llm.prompts import (
    execution_error_feedback,
    policy_feedback,
    reward_messages,
    template_text,
)
from itskill.llm.usage_log import UsageLog
from itskill.reward.candidate import (
    RESULT_FILE,
    TRAIN_DIR,
    CandidateJob,
    CandidateNetwork,
    run_candidate,
)
from itskill.reward.config import RewardSearchConfig, SearchConfigError, load_search_config
from itskill.reward.generator import Sample, fenced, generate_samples, probe_contexts
from itskill.reward.plan import TaskPlan, plan_command, plan_for_task
from itskill.stats import format_rate, mean_interval
from itskill.tasks import all_tasks, get_task

RUN_KIND = "itskill-reward-search"
RUN_FORMAT = 1
CONFIG_FILE = "config.json"
PLAN_FILE = "plan.json"
USAGE_FILE = "usage.json"
SUMMARY_FILE = "summary.json"
BEST_FILE = "best_reward.py"
FIGURE_FILE = "fig6.png"
CACHE_DIR = "llm_cache"
NETWORK_DIR = "network"
"""Where a search whose candidates train a transfer network keeps that network's record."""
OFFLINE_NOTE = f"{BACKEND} (not a language model)"

__all__ = [
    "RewardSearchConfig",
    "RewardSearchError",
    "RewardSearchResult",
    "generate_reward",
    "load_search",
    "load_search_config",
    "read_run",
    "search_client",
]


class RewardSearchError(ValueError):
    """A run directory that cannot be used, or a search that produced no usable reward."""


@dataclass
class RewardSearchResult:
    """A finished search: the plan, the chosen reward and how it compares with the expert's.

    ``best_success`` and ``expert_success`` are means over the final seeds of the best
    deterministic success through training, with the same budget (``expert_success`` is None
    when the expert was not compared; either is None when its reward failed on every final seed,
    which ``final`` records). ``history`` has one entry per iteration.
    """

    run_dir: Path
    plan: TaskPlan
    best_code: str
    best_path: Path
    best_success: float | None
    expert_success: float | None
    history: list[dict[str, Any]]
    best: dict[str, Any] = field(default_factory=dict)
    final: dict[str, Any] = field(default_factory=dict)
    llm: str = ""
    offline: bool = False


def search_client(
    run_dir: str | Path,
    llm: str | None = None,
    base_url: str | None = None,
    api_key: str | None = None,
) -> LLMClient:
    """The client for a search in ``run_dir``: ``llm`` as :func:`itskill.llm.make_client` takes it,
    with its reply cache in ``run_dir/llm_cache`` so that a resumed run replays the replies."""
    return make_client(llm, base_url=base_url, api_key=api_key, cache_dir=Path(run_dir) / CACHE_DIR)


def resolve_target(target: str) -> str | None:
    """The task id ``target`` names, or None if it is a command to plan.

    A single word that is no task id is an unknown task (:class:`UnknownTaskError`), not a
    command: "pick_nut_m21" is a typo, not an instruction.
    """
    target = target.strip()
    if target in all_tasks():
        return target
    if len(target.split()) == 1:
        get_task(target)  # raises UnknownTaskError listing the known tasks
    return None


def _rank(entry: dict[str, Any]) -> tuple[float, float]:
    corr = entry.get("correlation")
    return (entry["success"], corr if corr is not None else -math.inf)


class _Run:
    """One search's run directory and its bookkeeping."""

    def __init__(
        self, out: Path, client: LLMClient, console: Console, usage_since: Usage | None
    ) -> None:
        self.out, self.client, self.console = out, client, console
        self.usage = UsageLog(out / USAGE_FILE, client, usage_since)

    def __enter__(self) -> _Run:
        return self

    def __exit__(self, *exc: object) -> None:
        # Ctrl-C or an error mid-iteration: the tokens already paid for are on record (a resumed
        # run replays those replies from the cache, where they count as free).
        self.usage.save()

    def run_jobs(self, jobs: list[CandidateJob], config: RewardSearchConfig, label: str) -> dict:
        """Run the jobs without a ``result.json``; return every job's result by index.

        A job whose worker itself failed (a full disk, a lost Ray worker; not its candidate,
        which writes a failed result) leaves no result file: once the other jobs are done,
        :class:`RewardSearchError` stops the search before the model is asked again, and a
        resumed run trains that job again.
        """
        results: dict[int, dict[str, Any]] = {}
        todo = []
        for i, job in enumerate(jobs):
            path = Path(job.out) / RESULT_FILE
            if path.is_file():
                results[i] = read_json(path)
            else:
                todo.append(i)
        if not todo:
            return results
        # Ray schedules by the cluster's free CPUs unless told a limit; this machine's core
        # count says nothing about a cluster.
        workers = (
            config.workers
            if config.executor == "ray"
            else min(config.workers or default_workers(), len(todo))
        )
        progress = Progress(
            TextColumn(f"[bold]{label}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=self.console,
            transient=True,
        )
        with progress:
            bar = progress.add_task(label, total=len(jobs), completed=len(results))
            stream = run_jobs(
                run_candidate,
                [(jobs[i],) for i in todo],
                config.executor,  # type: ignore[arg-type]
                workers,
                config.ray_address,
            )
            lost = []
            for res in stream:
                job = jobs[todo[res.index]]
                progress.advance(bar)
                if not res.ok:
                    # No fault of the reward's: carried on with as a failed candidate, it was fed
                    # back to the model as one, and the finished search never trained it again.
                    lost.append(f"{_job_where(job)}: {type(res.error).__name__}: {res.error}")
                    self.console.print(f"  {lost[-1]}", highlight=False)
                    continue
                results[todo[res.index]] = res.value
                self.console.print(f"  {_job_line(job, res.value)}", highlight=False)
        if lost:
            raise RewardSearchError(
                f"{len(lost)} job(s) failed in their worker, not in the reward they trained "
                f"(first: {lost[0]}); the others' results are kept: run the command again with "
                "--resume to train those again and go on"
            )
        return results


def _job_where(job: CandidateJob) -> str:
    """The job's folder within the run: ``iter_0/sample_3``, ``final/<reward>_seed1``."""
    return "/".join(Path(job.out).parts[-2:])


def _job_line(job: CandidateJob, result: dict[str, Any]) -> str:
    where = _job_where(job)
    if result.get("status") != "ok":
        return f"{where}: failed: {result.get('error')}"
    corr = result.get("correlation")
    return (
        f"{where}: success {result['success']:.0%}"
        + (f", correlation with expert {corr:+.2f}" if corr is not None else "")
        + f" ({result.get('wall_s', 0):.0f} s)"
    )


def _is_search(config: Any) -> bool:
    """Whether ``config`` (a run's config.json) is a reward search's: an experiment run and a
    training run have a config.json too."""
    return isinstance(config, dict) and config.get("kind") == RUN_KIND


def check_new_run(out: Path) -> None:
    """Raise :class:`RewardSearchError` if ``out`` cannot take a new search: it holds one (to
    continue with ``--resume``), another kind of run, or any files but the candidates' network
    and the reply cache (a caller that writes those into ``out`` before the search checks
    first)."""
    if not (out / CONFIG_FILE).exists():
        others = foreign_entries(out, lambda name: name in (NETWORK_DIR, CACHE_DIR))
        if others:
            # A learn or training run there was overwritten (its plan.json, summary.json) and
            # could no longer be resumed.
            raise RewardSearchError(
                f"{out}: holds {some_of(others)} and is not a reward search (no "
                f"{CONFIG_FILE}); give --out a new or empty directory"
            )
        return
    try:
        ours = _is_search(read_json(out / CONFIG_FILE))
    except ValueError:  # not JSON: not a search this version wrote either
        ours = False
    if not ours:
        # --resume would refuse it too: the only way on is another directory.
        raise RewardSearchError(
            f"{out} holds another kind of run, or files that are not a reward search (its "
            f"{CONFIG_FILE} is not a reward search's): choose another --out"
        )
    raise RewardSearchError(
        f"{out} already holds a reward search: continue it with --resume {out} "
        "or choose another --out"
    )


def _check_resume(out: Path, header: dict[str, Any]) -> dict[str, Any]:
    path = out / CONFIG_FILE
    if not path.is_file():
        raise RewardSearchError(
            f"{out}: not a reward search run (no {CONFIG_FILE}); "
            "start one with itskill reward generate ... --out DIR"
        )
    try:
        stored = read_json(path)
    except ValueError as err:
        raise RewardSearchError(str(err)) from err
    if not _is_search(stored):
        raise RewardSearchError(f"{path}: not a reward search run")
    if stored.get("format") != RUN_FORMAT:
        raise RewardSearchError(
            f"{path}: run format {stored.get('format')!r}, this version reads {RUN_FORMAT}"
        )
    for key in ("target", "llm", "compare_expert", "network"):
        if stored.get(key) != header[key]:
            raise RewardSearchError(
                f"{out}: made with {key}={stored.get(key)!r}, this call has {header[key]!r}; "
                "resume with the same settings or start a new run with another --out"
            )
    have, want = stored.get("settings", {}), json.loads(json.dumps(header["settings"]))
    differ = sorted(k for k in set(have) | set(want) if have.get(k) != want.get(k))
    if differ:
        changes = ", ".join(f"{k}={have.get(k)!r} (now {want.get(k)!r})" for k in differ)
        raise RewardSearchError(
            f"{out}: made with other settings: {changes}; resume with the same settings or start "
            "a new run with another --out"
        )
    return stored


def _check_prompt(out: Path, recorded: dict[str, Any], prompt_sha256: str) -> None:
    """Refuse to resume the search in ``out``, whose ``config.json`` is ``recorded``, if its
    reward prompt changed since it began (a run from before the prompt was recorded is not
    checked): no reply would replay from the cache, every request would be paid for again, and
    each finished candidate whose new code differs would be trained again in place of its
    result."""
    stored = recorded.get("prompt_sha256")
    if stored is not None and stored != prompt_sha256:
        raise RewardSearchError(
            f"{out}: its reward prompt changed since the run began (the prompt templates or "
            "ITSKILL_PROMPTS_DIR, the task's file, or an itskill upgrade): resuming would ask "
            "the model anew and train its finished candidates again; restore them, or start a "
            "new run with another --out"
        )


def plan_target(target: str, client: LLMClient) -> TaskPlan:
    """The plan of ``target``: from its task file for a task id, by ``client`` for a command."""
    task = resolve_target(target)
    return plan_for_task(task) if task is not None else plan_command(target, client)


def _plan(
    target: str, client: LLMClient, out: Path, plan: TaskPlan | None, resume: bool
) -> TaskPlan:
    """The search's plan: a resumed run's stored one, else ``plan``, else a new one. Writes
    nothing: a fresh run records it only once the run itself is recorded."""
    path = out / PLAN_FILE
    if resume and path.is_file():
        return TaskPlan.from_dict(read_json(path), where=str(path))
    return plan or plan_target(target, client)


def _write_sample(sample_dir: Path, sample: Sample) -> None:
    status = sample.to_status()
    path = sample_dir / "status.json"
    if path.is_file() and read_json(path) == json.loads(json.dumps(status)):
        return  # a resumed run regenerated the same sample: leave the files as they are
    code = sample_dir / "reward.py"
    if code.is_file() and code.read_bytes() != (sample.code + "\n").encode():
        # Replayed differently (a probe timed out this time, the model was asked again): the
        # training of the old code must not be credited to the new.
        (sample_dir / RESULT_FILE).unlink(missing_ok=True)
        shutil.rmtree(sample_dir / TRAIN_DIR, ignore_errors=True)
    write_text(sample_dir / "reply.txt", sample.reply)
    write_text(code, sample.code + "\n")
    write_json(path, status)


def _feedback(
    best: dict[str, Any] | None, failure: tuple[str, str] | None, iteration: int = 1
) -> list[Message]:
    """What follows the base prompt in iteration ``iteration`` (1-based): the best reward so far
    and how its policy trained (the Eureka reflection), or, while nothing has trained, the last
    failure."""
    if best is not None:
        success = min(max(best["success"], 0.0), 1.0)
        text = policy_feedback(best["code"], success, best["stats"], iteration)
        code = best["code"]
    elif failure is not None:
        code, error = failure
        text = execution_error_feedback(code, error, iteration)
    else:
        return []
    return [{"role": "assistant", "content": fenced(code)}, {"role": "user", "content": text}]


def _code_key(code: str) -> str:
    """What makes two rewards the same: their syntax tree, so that code differing only in
    comments or layout (the offline backend's header names the sample) counts once."""
    try:
        return ast.dump(ast.parse(code))
    except SyntaxError:
        return code


def _reuse_results(
    jobs: list[CandidateJob], keys: list[str], results_of: dict[str, Path], out: Path
) -> int:
    """Give each job whose reward (by :func:`_code_key`) this search has already trained a copy
    of that result (naming where it came from) instead of training it again: the same code,
    seeds and budget train the same policy. Returns how many jobs were served so."""
    reused = 0
    for job, key in zip(jobs, keys, strict=True):
        path, source = Path(job.out) / RESULT_FILE, results_of.get(key)
        if source is None or path.is_file():
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json(path, {**read_json(source), "reused_from": str(source.parent.relative_to(out))})
        reused += 1
    return reused


def _tagged(kind: str, code: str | None) -> str:
    """A retraining's directory name: its kind, and for generated code the code's hash. A search
    resumed after a crash or a reply replayed differently may choose another reward, and a
    result found under a name without the hash would be another reward's."""
    return kind if code is None else f"{kind}_{hashlib.sha256(code.encode()).hexdigest()[:12]}"


def _job(
    config: RewardSearchConfig,
    task: str,
    out: Path,
    code: str | None,
    seeds,
    network: CandidateNetwork | None,
) -> CandidateJob:
    return CandidateJob(
        task=task,
        out=out,
        code=code,
        seeds=tuple(seeds),
        steps=config.steps,
        num_envs=config.num_envs,
        algo=config.algo,
        eval_every=config.eval_every,
        eval_episodes=config.eval_episodes,
        correlation_envs=config.correlation_envs,
        sandbox=config.sandbox,
        timeout_s=config.candidate_timeout_s,
        network=network,
    )


def _entry(sample: Sample, result: dict[str, Any] | None) -> dict[str, Any]:
    """A sample's line in an iteration summary."""
    entry: dict[str, Any] = {"sample": sample.index, "regenerations": len(sample.attempts) - 1}
    if not sample.accepted:
        return {**entry, "status": "rejected", "error": sample.error}
    assert result is not None
    entry["status"] = result.get("status", "failed")
    if entry["status"] != "ok":
        return {**entry, "error": result.get("error"), "wall_s": result.get("wall_s")}
    keys = ("success", "final_success", "correlation", "env_steps", "wall_s", "sha256")
    return {**entry, **{k: result.get(k) for k in keys}}


def _summarise_final(results: list[dict[str, Any]], seeds: list[int]) -> dict[str, Any]:
    ok = [(s, r) for s, r in zip(seeds, results, strict=True) if r.get("status") == "ok"]
    data: dict[str, Any] = {
        "seeds": [s for s, _ in ok],
        "success": [r["success"] for _, r in ok],
        "final_success": [r["final_success"] for _, r in ok],
        "failed": {str(s): r.get("error") for s, r in zip(seeds, results, strict=True)
                   if r.get("status") != "ok"},
    }  # fmt: skip
    if ok:
        data["mean"], data["ci_low"], data["ci_high"] = mean_interval(data["success"])
        data["final_mean"] = sum(data["final_success"]) / len(ok)
    else:
        data["mean"] = data["ci_low"] = data["ci_high"] = data["final_mean"] = None
    return data


def generate_reward(
    target: str,
    client: LLMClient,
    out: str | Path,
    config: RewardSearchConfig | None = None,
    resume: bool = False,
    compare_expert: bool = True,
    console: Console | None = None,
    network: CandidateNetwork | None = None,
    plan: TaskPlan | None = None,
    usage_since: Usage | None = None,
) -> RewardSearchResult:
    """Search a reward for ``target`` (a task id or a command) with ``client``, in run dir ``out``.

    Pass a client made by :func:`search_client` (its reply cache in ``out``) so that ``resume``
    can replay the model. ``resume=True`` continues a run in ``out`` made with the same target,
    model and settings; without it, ``out`` must not hold a search yet. Raises
    :class:`RewardSearchError` for an unusable run directory (one another search on this machine
    is using included) or when no candidate trained,
    :class:`~itskill.reward.plan.PlanError` for a command that cannot be grounded, and the
    client's :class:`~itskill.llm.client.LLMError` when the model cannot be reached.

    ``network`` is what every candidate, the selection and the final retraining (the expert
    reward's too) train; None trains the family's own network from scratch. ``plan`` is
    :func:`plan_target`'s plan of ``target`` when the caller already made one (to retrieve the
    network's sources), so the model is not asked twice; a resumed run keeps its stored plan.
    ``usage_since`` is the client's usage when the search's work began, where a caller asked
    the model for it first (the plan and the network's analysis); its ``usage.json`` counts
    from there (default: from this call, as when the client served other steps before).
    """
    config = config or RewardSearchConfig()
    console = console or Console(stderr=True, emoji=False)
    # Ray runs a candidate on any node, from a working directory of its own: a relative run
    # directory would have it write there (every node must see the run at the same path).
    out = Path(out).absolute() if config.executor == "ray" else Path(out)
    resolve_target(target)  # an unknown task id fails before anything is written
    check_executor(config.executor, config.workers, config.ray_address)  # so does a bad executor
    header = {
        "kind": RUN_KIND,
        "format": RUN_FORMAT,
        "target": target,
        "llm": client.name,
        "compare_expert": compare_expert,
        "network": None if network is None else network.describe(),
        "settings": config.result_settings(),
    }
    # Before the directory is checked or written. Its own key: itskill learn holds its lock on
    # the run directory above this one.
    with search_lock(out):
        return _search(
            target,
            client,
            out,
            config,
            header,
            resume=resume,
            compare_expert=compare_expert,
            console=console,
            network=network,
            plan=plan,
            usage_since=usage_since,
        )


def search_lock(out: Path) -> AbstractContextManager[None]:
    """Hold the search in ``out`` for this session (:func:`~itskill.files.held_alone`): a
    :class:`RewardSearchError` if another session on this machine holds it."""
    busy = RewardSearchError(
        f"{out} is in use by another itskill reward generate on this machine; wait for it to "
        f"end, or stop it and continue with --resume {out}"
    )
    return held_alone(out, "reward-search", busy)


def sample_folder(row: Mapping[str, Any]) -> str:
    """Where a candidate's files are in its run, ``iter_<i>/sample_<k>``: the folders count
    iterations from 0, the messages from 1."""
    return f"iter_{row['iteration']}/sample_{row['sample']}"


def _search(
    target: str,
    client: LLMClient,
    out: Path,
    config: RewardSearchConfig,
    header: dict[str, Any],
    *,
    resume: bool,
    compare_expert: bool,
    console: Console,
    network: CandidateNetwork | None,
    plan: TaskPlan | None,
    usage_since: Usage | None,
) -> RewardSearchResult:
    """:func:`generate_reward`'s search, once its run directory is this session's alone."""
    recorded: dict[str, Any] | None = None
    if resume:
        recorded = _check_resume(out, header)
        if (out / SUMMARY_FILE).is_file():
            # Nothing is left to train; replaying the search would only add its time to the
            # recorded duration.
            console.print(f"{out}: the search has already finished", highlight=False)
            return load_search(out)
    else:
        check_new_run(out)
    run = _Run(out, client, console, usage_since)  # its clock starts here: the planning counts
    # Planned before anything is written: a command the planner refuses must leave no run behind,
    # or the same --out would be refused as taken and --resume would fail on it again.
    created = not out.exists()
    try:
        plan = _plan(target, client, out, plan, resume)
        # A prompt template that does not validate fails here too, before the run is written.
        base = reward_messages(plan.describe())
        # The feedback templates too: from the second iteration on, every request carries one.
        feedback = [template_text(name) for name in ("policy_feedback", "execution_error")]
    except BaseException:
        if created:  # all it holds is the reply cache of a command that cannot be planned
            shutil.rmtree(out, ignore_errors=True)
        raise
    prompt = json.dumps([base, feedback], sort_keys=True)
    prompt_sha256 = hashlib.sha256(prompt.encode()).hexdigest()
    if recorded is not None:
        _check_prompt(out, recorded, prompt_sha256)
    else:
        write_json(
            out / CONFIG_FILE,
            {
                **header,
                "offline": client.offline,
                "config": config.to_dict(),
                "itskill": itskill.__version__,
                "prompt_sha256": prompt_sha256,
                "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            },
        )
    write_json(out / PLAN_FILE, plan.to_dict())
    with run:  # its usage is saved however the search ends
        backend = f"{client.name}: {OFFLINE_NOTE}" if client.offline else client.name
        console.print(f"reward search in {out} with {backend}", highlight=False)
        if network is not None:
            console.print(f"candidates train {network.label}", highlight=False)
        run.usage.save()
        console.print(f"plan: task {plan.task}; " + " ".join(plan.subtasks), highlight=False)

        contexts = probe_contexts(plan.task, config.probe_envs, config.probe_steps)
        history: list[dict[str, Any]] = []
        candidates: list[dict[str, Any]] = []  # every trained sample, with its code and _code_key
        results_of: dict[str, Path] = {}  # _code_key -> the result of its training in this search
        best: dict[str, Any] | None = None
        failure: tuple[str, str] | None = None
        for i in range(config.iterations):
            label = f"iteration {i + 1}/{config.iterations}"
            samples = generate_samples(
                base + _feedback(best, failure, i + 1),
                client,
                config.samples,
                contexts,
                config.sandbox,
                config.max_regenerations,
                config.temperature,
                after_request=run.usage.save,
                iteration=i + 1,
            )
            it_dir = out / f"iter_{i}"
            for sample in samples:
                _write_sample(it_dir / f"sample_{sample.index}", sample)
            accepted = [s for s in samples if s.accepted]
            console.print(
                f"{label}: {len(accepted)}/{len(samples)} samples pass the sandbox and the probe",
                highlight=False,
            )
            jobs = [
                _job(config, plan.task, it_dir / f"sample_{s.index}", s.code, config.seeds, network)
                for s in accepted
            ]
            keys = [_code_key(s.code) for s in accepted]
            reused = _reuse_results(jobs, keys, results_of, out)
            # A reward sampled twice in this iteration (a low temperature) trains once; its
            # twins get a copy of the result afterwards.
            lead: dict[str, CandidateJob] = {}
            for job, key in zip(jobs, keys, strict=True):
                lead.setdefault(key, job)
            twins = sum(
                lead[key] is not job and not (Path(job.out) / RESULT_FILE).is_file()
                for job, key in zip(jobs, keys, strict=True)
            )
            if reused or twins:
                console.print(
                    f"{label}: {reused + twins} sample(s) repeat a reward trained before or in "
                    "this iteration: trained once, result reused",
                    highlight=False,
                )
            run.run_jobs(list(lead.values()), config, f"{label}: training")
            for job, key in zip(jobs, keys, strict=True):
                if (Path(job.out) / RESULT_FILE).is_file():
                    results_of.setdefault(key, Path(job.out) / RESULT_FILE)
            _reuse_results(jobs, keys, results_of, out)
            results = [read_json(Path(job.out) / RESULT_FILE) for job in jobs]
            by_sample = {s.index: results[j] for j, s in enumerate(accepted)}
            entries = [_entry(s, by_sample.get(s.index)) for s in samples]
            trained = [e for e in entries if e["status"] == "ok"]
            key_of = {s.index: key for s, key in zip(accepted, keys, strict=True)}
            candidates += [
                {**e, "iteration": i, "code": samples[e["sample"]].code, "key": key_of[e["sample"]]}
                for e in trained
            ]
            it_best = max(trained, key=_rank) if trained else None
            if it_best is not None and (best is None or _rank(it_best) > _rank(best)):
                code = samples[it_best["sample"]].code
                stats = by_sample[it_best["sample"]]["stats"]
                best = {**it_best, "iteration": i, "code": code, "stats": stats}
                write_text(out / BEST_FILE, code + "\n")
            if not trained:
                # Every sample was rejected or failed: feed the last failure back.
                last = samples[-1]
                error = last.error if not last.accepted else by_sample[last.index].get("error")
                failure = (last.code, str(error))
            summary = {
                "iteration": i,
                "samples": entries,
                "accepted": len(accepted),
                "trained": len(trained),
                "best_sample": it_best["sample"] if it_best else None,
                "best_success": it_best["success"] if it_best else None,
                "best_correlation": it_best.get("correlation") if it_best else None,
                "best_so_far": best["success"] if best else None,
            }
            write_json(it_dir / SUMMARY_FILE, summary)
            history.append(summary)
            console.print(
                f"{label}: best success {format_rate(summary['best_success'])}, "
                f"best so far {format_rate(summary['best_so_far'])}",
                highlight=False,
            )

        if best is None:
            run.usage.save()
            raise RewardSearchError(
                f"no candidate reward trained in {config.iterations} iteration(s): every sample "
                f"was rejected or failed; see {out}/iter_*/sample_*/status.json and result.json"
            )
        selection = None
        if config.select_top:
            selection, chosen = _select(run, config, plan.task, out, candidates, network)
            best = {
                **chosen,
                "selected_success": selection["candidates"][selection["chosen"]]["mean"],
            }
            write_text(out / BEST_FILE, best["code"] + "\n")
        final_seeds = config.final_seed_list
        kinds = [("generated", best["code"])] + ([("expert", None)] if compare_expert else [])
        jobs = [
            _job(
                config,
                plan.task,
                out / "final" / f"{_tagged(kind, code)}_seed{s}",
                code,
                (s,),
                network,
            )
            for kind, code in kinds
            for s in final_seeds
        ]
        results = run.run_jobs(jobs, config, "final: retraining best and expert rewards")
        n = len(final_seeds)
        final = {
            "seeds": final_seeds,
            "steps": config.steps,
            "generated": _summarise_final([results[j] for j in range(n)], final_seeds),
            "expert": _summarise_final([results[j] for j in range(n, 2 * n)], final_seeds)
            if compare_expert
            else None,
        }
        usage = run.usage.save()
        best_info = {k: v for k, v in best.items() if k not in ("code", "key", "stats")}
        best_info["path"] = BEST_FILE
        summary = {
            "status": "complete",
            "task": plan.task,
            "command": plan.command,
            "llm": client.name,
            "offline": client.offline,
            "plan": plan.to_dict(),
            "network": header["network"],
            "iterations": history,
            "best": best_info,
            "selection": selection,
            "final": final,
            "best_success": final["generated"]["mean"],
            "expert_success": final["expert"]["mean"] if final["expert"] else None,
            "usage": usage["total"],
        }
        from itskill.reward.figure import plot_fig6

        plot_fig6(summary, out / FIGURE_FILE)
        write_json(out / SUMMARY_FILE, summary)
        console.print(
            f"best reward: iteration {best['iteration'] + 1}, sample {best['sample']} "
            f"({sample_folder(best)}), in "
            f"{out / BEST_FILE}; over seeds {final_seeds}: "
            f"generated {format_rate(summary['best_success'])}"
            + (f", expert {format_rate(summary['expert_success'])}" if compare_expert else ""),
            highlight=False,
        )
        return load_search(out)


def _select(
    run: _Run,
    config: RewardSearchConfig,
    task: str,
    out: Path,
    candidates: list[dict[str, Any]],
    network: CandidateNetwork | None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Retrain the ``select_top`` best distinct rewards on ``select_seeds`` more seeds (one job
    per reward and seed, so the jobs spread evenly over the workers) and choose the one with the
    highest mean success over the search's seeds and these; ties go to the search's ranking.
    Returns the selection's summary and the chosen candidate."""
    distinct: dict[str, dict[str, Any]] = {}
    for c in sorted(candidates, key=_rank, reverse=True):
        distinct.setdefault(c["key"], c)
    top = list(distinct.values())[: config.select_top]
    seeds = config.select_seed_list
    jobs = [
        _job(config, task, out / "select" / f"{_tagged('reward', c['code'])}_seed{s}",
             c["code"], (s,), network)
        for c in top
        for s in seeds
    ]  # fmt: skip
    results = run.run_jobs(jobs, config, "selection: the best rewards on more seeds")
    rows = []
    for n, c in enumerate(top):
        mine = [results[n * len(seeds) + j] for j in range(len(seeds))]
        ok = [r["success"] for r in mine if r.get("status") == "ok"]
        every = [c["success"]] * len(config.seeds) + ok
        rows.append(
            {
                "iteration": c["iteration"],
                "sample": c["sample"],
                "search_success": c["success"],
                "select_success": [r.get("success") for r in mine],
                "failed": len(mine) - len(ok),
                "mean": sum(every) / len(every),
            }
        )
    # A reward that failed on a selection seed is not chosen over one that trained on all.
    chosen = max(range(len(rows)), key=lambda k: (rows[k]["failed"] == 0, rows[k]["mean"], -k))
    run.console.print(
        f"selection over seeds {list(config.seeds) + seeds}: "
        + ", ".join(
            f"iteration {r['iteration'] + 1} sample {r['sample']} {format_rate(r['mean'])}"
            for r in rows
        )
        + f"; chosen: iteration {rows[chosen]['iteration'] + 1} sample {rows[chosen]['sample']}",
        highlight=False,
    )
    summary = {
        "search_seeds": list(config.seeds),
        "seeds": seeds,
        "candidates": rows,
        "chosen": chosen,
    }
    return summary, top[chosen]


def load_search(run_dir: str | Path) -> RewardSearchResult:
    """The result of the finished search in ``run_dir``; :class:`RewardSearchError` if it is not
    a reward search run or has not finished (resume it)."""
    run_dir = Path(run_dir)
    data = read_run(run_dir)
    summary = data["summary"]
    if summary is None:
        raise RewardSearchError(
            f"{run_dir}: the search has not finished (no {SUMMARY_FILE}); continue it with "
            f"itskill reward generate --resume {run_dir}"
        )
    best_path = run_dir / BEST_FILE
    if data["best_code"] is None:
        raise RewardSearchError(
            f"{best_path}: missing, though {SUMMARY_FILE} says the search finished; the chosen "
            f"reward is {run_dir}/iter_<i>/sample_<k>/reward.py, with the iteration (from 1) and "
            f"sample {SUMMARY_FILE}'s best names"
        )
    return RewardSearchResult(
        run_dir=run_dir,
        plan=TaskPlan.from_dict(summary["plan"], where=f"{run_dir / SUMMARY_FILE}: plan"),
        best_code=data["best_code"],
        best_path=best_path,
        best_success=summary["best_success"],
        expert_success=summary["expert_success"],
        history=summary["iterations"],
        best=summary["best"],
        final=summary["final"],
        llm=summary["llm"],
        offline=summary["offline"],
    )


# What the readers of a run (``itskill reward show``, :func:`load_search`, ``--resume``) take from
# its files, so that a file edited into another shape is refused by name rather than failing in
# whichever reader first trips on it (shapes as :func:`itskill.files.check_shape` reads them).
_RATE = (float, None)
_BAND = {"seeds": [int], "mean": _RATE, "ci_low": _RATE, "ci_high": _RATE}
_ITERATION = {
    "iteration": int,
    "samples": list,
    "accepted": int,
    "trained": int,
    "best_sample": (int, None),
    "best_success": _RATE,
    "best_correlation?": _RATE,
    "best_so_far": _RATE,
}
_CONFIG = {
    "target": str,
    "llm": str,
    "compare_expert": bool,
    "offline?": bool,
    "network?": ({"label": str}, None),
    "settings?": dict,
    "config?": dict,
}
_USAGE = {
    "total": {
        "requests": int,
        "prompt_tokens": int,
        "completion_tokens": int,
        "cache_hits": int,
        "cost_usd": float,
        "wall_s": float,
    },
    "sessions": list,
}
_SUMMARY = {
    "plan": dict,  # and what TaskPlan.from_dict reads
    "llm": str,
    "offline": bool,
    "iterations": [_ITERATION],
    "best": {"iteration": int, "sample": int, "success": float, "selected_success?": float},
    "selection?": (
        {
            "seeds": [int],
            "candidates": [
                {
                    "iteration": int,
                    "sample": int,
                    "search_success": float,
                    "select_success": [_RATE],
                    "mean": float,
                }
            ],
        },
        None,
    ),
    "final": {"steps": int, "generated": _BAND, "expert": (_BAND, None)},
    "best_success": _RATE,
    "expert_success": _RATE,
}


def read_run(run_dir: str | Path) -> dict[str, Any]:
    """Everything on disk about a search, finished or not: ``config``, ``plan`` (or None),
    ``iterations`` (the iteration summaries written so far), ``summary`` (None until it finishes),
    ``usage`` and ``best_code`` (or None). :class:`RewardSearchError` naming the file and field
    for a file that is not valid JSON or not of the shape the search writes."""
    run_dir = Path(run_dir)
    path = run_dir / CONFIG_FILE
    if not run_dir.is_dir():
        why = "a file, not a run directory" if run_dir.exists() else "no such run directory"
        raise RewardSearchError(f"{run_dir}: {why}")
    if not path.is_file():
        raise RewardSearchError(f"{run_dir}: not a reward search run (no {CONFIG_FILE})")
    try:
        config = read_json(path)
        if not _is_search(config):
            raise RewardSearchError(f"{path}: not a reward search run")
        check_shape(path, config, _CONFIG)

        def checked(file: Path, shape: Any) -> Any:
            data = read_json(file)
            check_shape(file, data, shape)
            return data

        def optional(name: str, shape: Any) -> Any:
            return checked(run_dir / name, shape) if (run_dir / name).is_file() else None

        iterations = []
        i = 0
        while (run_dir / f"iter_{i}" / SUMMARY_FILE).is_file():
            iterations.append(checked(run_dir / f"iter_{i}" / SUMMARY_FILE, _ITERATION))
            i += 1
        plan = optional(PLAN_FILE, dict)
        if plan is not None:
            TaskPlan.from_dict(plan, where=f"{run_dir / PLAN_FILE}: plan")
        summary = optional(SUMMARY_FILE, _SUMMARY)
        if summary is not None:
            TaskPlan.from_dict(summary["plan"], where=f"{run_dir / SUMMARY_FILE}: plan")
        return {
            "run_dir": str(run_dir),
            "config": config,
            "plan": plan,
            "iterations": iterations,
            "summary": summary,
            "usage": optional(USAGE_FILE, _USAGE),
            "best_code": read_utf8(run_dir / BEST_FILE)
            if (run_dir / BEST_FILE).is_file()
            else None,
        }
    except ValueError as err:
        if isinstance(err, RewardSearchError):
            raise
        raise RewardSearchError(str(err)) from err


def config_from_run(
    run_dir: str | Path, overrides: dict[str, Any] | None = None
) -> RewardSearchConfig:
    """The settings a run was made with (for resuming it), ``overrides`` on top."""
    stored = read_run(run_dir)["config"].get("config", {})
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    if given.get("executor", stored.get("executor")) != "ray" and "ray_address" not in given:
        # The stored address goes with the stored cluster: resuming with `--executor local`
        # (the cluster gone) leaves it behind; one given with it is refused.
        stored = {k: v for k, v in stored.items() if k != "ray_address"}
    try:
        return load_search_config(overrides={**stored, **given})
    except SearchConfigError as err:
        if err.setting in given:
            raise  # a flag's value: the command line names it
        # A setting this version no longer takes (a bound lowered, the file edited) is the
        # record's, not a flag's: name the file.
        raise SearchConfigError(Path(run_dir) / CONFIG_FILE, err.where, err.problem) from err
