"""``itskill learn "COMMAND"``: the whole method on a new command, end to end.

plan the command → retrieve source skills → analyze their contributions → generate its reward
(the Eureka-style search, whose candidates train the transfer network over those sources) →
train the transfer network with the generated reward → evaluate it → add it to the skill space
as a new skill → write the report.

Everything lands in one run directory (``runs/learn/<slug>/`` by default)::

    learn.json        the command, budget, seed and LLM backend (a resume must match them)
    provenance.json   sessions: command line, machine, start, end
    llm_cache/        every LLM reply (a resumed or repeated step asks nothing twice)
    plan.json         the validated plan
    sources.json      the retrieved source skills
    analysis.json     the analyzer's contribution matrix
    reward/           the reward search's run directory (best_reward.py, summary.json, fig6.png)
    transfer/         the transfer training run (checkpoints, metrics.csv, eval.csv, transfer.json)
    evaluation.json   the final held-out evaluation
    skill.json        the skill added to the skill space, or the threshold it fell below
    summary.json      all of the above in one file; report.md, report.html, figures/, videos/

A step whose file exists is not redone on ``--resume``; the reward search and the training
resume from their own checkpoints. Budgets are data (``itskill/experiments/data/learn.toml``).
"""

from __future__ import annotations

import hashlib
import re
import shutil
from dataclasses import asdict, dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape

from itskill.curves import read_curve
from itskill.datafile import (
    DataFileError,
    check_positive,
    check_table,
    check_type,
    is_number,
    read_toml,
)
from itskill.experiments.learn_layout import (
    LEARN_FILE,
    REWARD_DIR,
    TRANSFER_DIR,
    USAGE_FILE,
    best_reward_file,
    in_run,
    kept_policy_words,
    policy_dir,
)
from itskill.experiments.provenance import Sessions
from itskill.experiments.report import PROVENANCE_FILE, ReportFiles, learn_report
from itskill.files import (
    Check,
    CorruptFileError,
    check_shape,
    copy_whole,
    foreign_entries,
    held_alone,
    read_json,
    read_json_or_none,
    some_of,
    write_json,
)
from itskill.limits import (
    EPISODES_MAX,
    NUM_ENVS_MAX,
    SEED_MAX,
    SOURCES_MAX,
    STEPS_MAX,
    check_steps,
)
from itskill.llm.usage_log import UsageLog
from itskill.rl.config import ALGOS

STEPS = ("plan", "sources", "analyze", "reward", "train", "evaluate", "skill", "report")

# What a later step reads of each step's file: a file damaged or edited between sessions is
# named when it is read, not met as a KeyError steps later.
_PLAN_SHAPE = {
    "command": str,
    "task": str,
    "notes?": str,
    "subtasks": [str],
    "actions": [str],
    "objects": [str],
}
_SOURCES_SHAPE = {"retrieved": [{"name": str}], "used": [{"name": str}]}
_ANALYSIS_SHAPE = Check(
    "{} (no analysis) or an object with segments, sources and matrix",
    lambda v: isinstance(v, dict) and (not v or {"segments", "sources", "matrix"} <= v.keys()),
)
_ANALYSIS_FIELDS = {"segments?": [str], "sources?": [str], "matrix?": [[float]]}
_REWARD_SHAPE = {
    "run_dir": str,
    "best_path": str,
    "best_success": float,
    "expert_success": (float, None),
    "network?": (str, None),
}
_EVALUATION_SHAPE = {"success_rate": float, "episodes": int, "ci_low": float, "ci_high": float}
_SKILL_ADDED = ("id", "name", "skill_space")
_SKILL_NOT_ADDED = ("min_success", "policy")
_SKILL_SHAPE = Check(
    f"an object with {', '.join(_SKILL_ADDED)} (added) or {', '.join(_SKILL_NOT_ADDED)} (not)",
    lambda v: (
        isinstance(v, dict)
        and isinstance(v.get("added", True), bool)
        and set(_SKILL_ADDED if v.get("added", True) else _SKILL_NOT_ADDED) <= v.keys()
    ),
)
_SKILL_FIELDS = {
    "id?": int,
    "name?": str,
    "skill_space?": str,
    "min_success?": float,
    "policy?": str,
}


class LearnError(ValueError):
    """A run directory or budget that cannot be used; the message says what to do."""


class BudgetError(DataFileError):
    """A budgets file that does not validate: names the file, the field and the problem."""


@dataclass(frozen=True)
class TransferBudget:
    """The transfer training of ``itskill learn``: ``steps`` and ``eval_every`` are required, the
    rest have defaults (PPO, as ``itskill transfer train``; ``a2c`` is the paper's)."""

    steps: int
    eval_every: int
    method: str = "itn"
    algo: str = "ppo"
    num_envs: int | None = None
    eval_episodes: int = 50
    k: int = 3


@dataclass(frozen=True)
class LearnBudget:
    """One named budget: reward search settings, transfer training, final evaluation."""

    name: str
    transfer: TransferBudget
    reward: dict[str, Any]
    """Overrides of :class:`itskill.reward.RewardSearchConfig`'s packaged defaults."""
    eval_episodes: int = 100
    min_success: float = 0.5
    """Final success the new skill needs to join the skill space (as for pretrained skills); a
    policy below it stays in the run directory, so later runs do not retrieve it as a source."""
    compare_expert: bool = True
    description: str = ""

    def search_config(self, seed: int = 0) -> Any:
        """The reward search settings (validated by the reward package) of the run with ``seed``.

        Seed 0 trains the candidates on the configured seeds; seed ``s`` shifts every seed the
        search trains on by ``s`` times their span, so runs with other seeds sample the whole
        method, the reward search included, and no two share a training seed."""
        from itskill.reward import load_search_config

        config = load_search_config(overrides=self.reward)
        span = config.last_seed + 1
        return replace(config, seeds=tuple(s + seed * span for s in config.seeds))

    @property
    def max_seed(self) -> int:
        """The largest seed whose shifted reward search (:meth:`search_config`) still trains on
        seeds training takes."""
        last = self.search_config().last_seed
        return (SEED_MAX - last) // (last + 1)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def default_budgets_path() -> Path:
    """The packaged budgets file."""
    return Path(str(resources.files("itskill.experiments") / "data" / "learn.toml"))


def _field(
    path: Path,
    where: str,
    table: dict,
    key: str,
    kind: type,
    default: Any = ...,
    most: int | None = None,
) -> Any:
    """``table[key]`` of type ``kind`` (an int: 1 or more, and at most ``most`` when given), or
    ``default`` when it is left out (``...``: required)."""
    if key not in table:
        if default is ...:
            raise BudgetError(path, f"{where}.{key}", "missing (required)")
        return default
    if kind is int:
        return check_positive(path, f"{where}.{key}", table[key], BudgetError, most)
    return check_type(path, f"{where}.{key}", table[key], kind, BudgetError)


def _budget(path: Path, name: str, raw: Any) -> LearnBudget:
    from itskill.reward.config import SearchConfigError
    from itskill.transfer import METHODS

    allowed = {"description", "compare_expert", "reward", "transfer", "evaluation"}
    check_table(path, name, raw, BudgetError, allowed)
    where = f"{name}.transfer"
    if "transfer" not in raw:
        raise BudgetError(path, where, "missing table (required)")
    tr = check_table(path, where, raw["transfer"], BudgetError, TransferBudget.__dataclass_fields__)
    transfer = TransferBudget(
        steps=_field(path, where, tr, "steps", int, most=STEPS_MAX),
        eval_every=_field(path, where, tr, "eval_every", int, most=STEPS_MAX),
        method=_field(path, where, tr, "method", str, "itn"),
        algo=_field(path, where, tr, "algo", str, TransferBudget.algo),
        # Bounded as everywhere (itskill.limits): more crashed the training at allocation,
        # failed its evaluations with MemoryError, or ran thousands of frozen sources, after the
        # whole reward search (whose own counts the search settings bound).
        num_envs=_field(path, where, tr, "num_envs", int, None, NUM_ENVS_MAX),
        eval_episodes=_field(path, where, tr, "eval_episodes", int, 50, EPISODES_MAX),
        k=_field(path, where, tr, "k", int, 3, SOURCES_MAX),
    )
    if transfer.method not in METHODS:
        raise BudgetError(path, f"{where}.method", f"expected one of {list(METHODS)}")
    if transfer.algo not in ALGOS:
        raise BudgetError(path, f"{where}.algo", f"expected one of {list(ALGOS)}")
    reward = check_table(path, f"{name}.reward", raw.get("reward", {}), BudgetError)
    ev = raw.get("evaluation", {})
    check_table(path, f"{name}.evaluation", ev, BudgetError, {"episodes", "min_success"})
    min_success = _field(
        path, f"{name}.evaluation", ev, "min_success", float, LearnBudget.min_success
    )
    if not 0.0 <= min_success <= 1.0:
        raise BudgetError(path, f"{name}.evaluation.min_success", "must be between 0 and 1")
    budget = LearnBudget(
        name=name,
        transfer=transfer,
        reward=dict(reward),
        eval_episodes=_field(path, f"{name}.evaluation", ev, "episodes", int, 100, EPISODES_MAX),
        min_success=min_success,
        compare_expert=_field(path, name, raw, "compare_expert", bool, True),
        description=_field(path, name, raw, "description", str, ""),
    )
    try:
        budget.search_config()
    except SearchConfigError as err:
        # The table's fields are the search's own, by name (its [sandbox] a sub-table): the field
        # as this file has it, not as an override of the packaged search settings.
        raise BudgetError(path, f"{name}.reward.{err.where}", err.problem) from err
    except ValueError as err:
        raise BudgetError(path, f"{name}.reward", str(err)) from err
    return budget


def load_budgets(path: str | Path | None = None) -> dict[str, LearnBudget]:
    """Every budget in ``path`` (default: the packaged ``learn.toml``), validated."""
    path = Path(path) if path is not None else default_budgets_path()
    data = read_toml(path, BudgetError)
    if not data:
        raise BudgetError(path, "file", "defines no budget")
    return {name: _budget(path, name, raw) for name, raw in data.items()}


def _words(command: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", command.lower()).strip("-")


def slugify(command: str) -> str:
    """A directory name for a command: lower case words joined by hyphens, at most 60 chars."""
    slug = _words(command)[:60].rstrip("-")
    if not slug:
        raise LearnError(f"command {command!r} has no letters or digits")
    return slug


@dataclass(frozen=True)
class LearnResult:
    """What ``learn`` produced."""

    run_dir: Path
    summary: dict[str, Any]
    report: ReportFiles


class _Steps:
    """Prints ``[i/n] step`` lines and skips a step whose result file exists.

    A line's text holds the user's command, file and skill names: it is escaped, so that rich
    does not read ``asdf [red]x`` or ``pick[/v2]`` as markup.
    """

    def __init__(self, console: Console, run_dir: Path) -> None:
        self.console, self.run_dir, self.i = console, run_dir, 0

    def begin(self, name: str, text: str) -> None:
        self.i += 1
        self.console.print(f"[bold cyan][{self.i}/{len(STEPS)}] {name}[/bold cyan]: {escape(text)}")

    def done(self, text: str, cached: bool = False) -> None:
        mark = "(kept from the previous session) " if cached else ""
        self.console.print(f"    [green]✓[/green] {mark}{escape(text)}", highlight=False)

    def cached(self, file: str, *shapes: Any) -> dict[str, Any] | None:
        """``file``'s record from an earlier session, checked against each of ``shapes``; None if
        the step has not run."""
        path = self.run_dir / file
        if not path.is_file():
            return None
        value = read_json(path)
        try:
            for shape in shapes:
                check_shape(path, value, shape)
        except CorruptFileError as err:
            redo = "delete it and --resume to run its step again"
            if file == "skill.json":
                # The step may have added the skill already: run again, it adds a second copy.
                redo = (
                    "if the skill space holds this run's skill (`itskill skills list`), remove it "
                    f"first (`itskill skills remove NAME`); then {redo}"
                )
            raise CorruptFileError(path, f"{err.problem}; {redo}") from None
        return value


def _check_run_dir(
    run_dir: Path, settings: dict[str, Any], resume: bool, recorded: Any | None
) -> None:
    """Record ``settings`` in ``run_dir``; :class:`LearnError` when it holds a learn run (its
    ``learn.json``, ``recorded``) and ``resume`` is not given, one with other settings, or, with
    ``resume``, no learn run."""
    path = run_dir / LEARN_FILE
    if recorded is not None:
        if not resume:
            raise LearnError(
                f"{run_dir} already holds a learn run; pass --resume to continue it or "
                "--out to start another"
            )
        found = _difference(recorded, settings)
        if found is not None:
            key, was, now = found
            raise LearnError(
                f"{run_dir} was started with {key}={was!r}, this call gives {now!r}; resume "
                "with the same settings or use another --out"
            )
    elif not resume and run_dir.exists() and not run_dir.is_dir():
        raise LearnError(f"{run_dir} is a file: give --out a new or empty directory")
    elif not resume and (found := foreign_entries(run_dir)):
        # A step finds its files from an earlier session by name: another run's plan.json or
        # sources.json there would be taken for this run's, and the user's files overwritten.
        raise LearnError(
            f"{run_dir}: holds {some_of(found)} and is not a learn run (no {LEARN_FILE}); a new "
            "run would read or overwrite the files there: give --out a new or empty directory"
        )
    elif resume:
        # Starting afresh instead would spend hours where a continuation was asked for: a
        # mistyped --out must be said, as `experiment run --resume` says it.
        if not run_dir.exists():
            why = "no such directory"
        elif run_dir.is_dir() and not foreign_entries(run_dir):
            why = "the directory is empty"
        else:
            why = f"no {LEARN_FILE}"
        raise LearnError(
            f"nothing to resume: there is no learn run in {run_dir} ({why}); give the run's "
            "--out, or leave out --resume to start a new run"
        )
    write_json(path, settings)


def _recorded_min_success(recorded: Any | None, default: float) -> float:
    """The ``min_success`` a learn run's ``learn.json`` (``recorded``) holds; ``default`` where
    it holds none."""
    budget = recorded.get("budget") if isinstance(recorded, dict) else None
    value = budget.get("min_success") if isinstance(budget, dict) else None
    return float(value) if is_number(value) and 0.0 <= value <= 1.0 else default


_RESUMED_WITH_ANOTHER = ("budget.min_success",)
"""Settings a resume may change: the threshold decides only whether the trained policy joins
the skill space, a step redone without training again (a policy kept out at 50% is added at 40%
with ``--resume --min-success 0.4``)."""


def _difference(old: Any, new: Any, key: str = "") -> tuple[str, Any, Any] | None:
    """The first setting (as a dotted key) whose value differs between a run's recorded
    settings and this call's; None if they agree. A budget's description is prose, not a
    setting: rewording it does not make another run; nor do :data:`_RESUMED_WITH_ANOTHER`."""
    if isinstance(old, dict) and isinstance(new, dict):
        for name in new:
            dotted = f"{key}.{name}" if key else name
            if name == "description" or dotted in _RESUMED_WITH_ANOTHER:
                continue
            found = _difference(old.get(name), new[name], dotted)
            if found is not None:
                return found
        return None
    return None if old == new else (key, old, new)


def learn_dir(command: str, out: str | Path | None) -> Path:
    """The run directory of ``itskill learn COMMAND [--out OUT]``.

    A command longer than its slug's 60 characters gets a hash of the whole command after the
    slug, so two that begin alike do not share a directory. A run made before that (in the
    bare slug's directory, whose ``learn.json`` records this very command) is still found there.
    """
    if out:
        return Path(out)
    command = command.strip()
    slug = slugify(command)
    bare = Path("runs/learn") / slug
    if slug == _words(command):
        return bare
    recorded = read_json_or_none(bare / LEARN_FILE)
    if isinstance(recorded, dict) and recorded.get("command") == command:
        return bare
    return bare.with_name(f"{slug}-{hashlib.sha256(command.encode()).hexdigest()[:8]}")


def learn(
    command: str,
    budget: str = "default",
    steps: int | None = None,
    llm: str | None = None,
    out: str | Path | None = None,
    seed: int = 0,
    resume: bool = False,
    budgets_file: str | Path | None = None,
    video: bool = True,
    console: Console | None = None,
    min_success: float | None = None,
) -> LearnResult:
    """Learn ``command`` end to end (see the module docstring); returns the run and its report.

    ``steps`` overrides the budget's transfer env-steps and ``min_success`` its threshold for
    adding the skill; ``llm`` is ``"offline"`` (no network), ``"openai:MODEL"``, or None for
    ``$ITSKILL_LLM_MODEL``, else offline.
    """
    from itskill.llm import make_client
    from itskill.reward import check_command

    check_command(command)  # before the slug: an empty command would be said to have no letters
    console = console or Console(emoji=False)
    budgets = load_budgets(budgets_file)
    if budget not in budgets:
        raise LearnError(f"unknown budget {budget!r}; expected one of {list(budgets)}")
    b = budgets[budget]
    if steps is not None:
        try:
            check_steps(steps, "--steps")
        except ValueError as err:
            raise LearnError(str(err)) from err
        b = replace(b, transfer=replace(b.transfer, steps=steps))
    if min_success is not None:
        if not 0.0 <= min_success <= 1.0:
            raise LearnError(f"--min-success must be between 0 and 1, got {min_success}")
        b = replace(b, min_success=min_success)
    if not 0 <= seed <= b.max_seed:
        # Checked before any step: the reward search, step 4, would refuse the shifted seeds
        # after the plan and the analysis (paid requests with a model) were made.
        raise LearnError(
            f"--seed must be between 0 and {b.max_seed:,} with the {budget!r} budget (its reward "
            "search trains on seeds shifted by the run's seed)"
        )
    command = command.strip()
    run_dir = learn_dir(command, out)
    created = not run_dir.exists()
    client = make_client(llm, cache_dir=run_dir / "llm_cache")
    # Before the record is checked or written.
    busy = LearnError(
        f"{run_dir} is in use by another itskill learn on this machine; wait for it to end, "
        "or stop it and --resume"
    )
    with held_alone(run_dir, "learn", busy):
        path = run_dir / LEARN_FILE
        recorded = read_json(path) if path.is_file() else None  # read once, under the lock
        if resume and min_success is None:
            # The threshold the run was started (or last resumed) with, not the budget's again.
            b = replace(b, min_success=_recorded_min_success(recorded, b.min_success))
        settings = {"command": command, "budget": b.to_dict(), "seed": seed, "llm": client.name}
        _check_run_dir(run_dir, settings, resume, recorded)
        sessions = Sessions(run_dir / PROVENANCE_FILE)
        sessions.start()
        usage = UsageLog(run_dir / USAGE_FILE, client)
        try:
            summary = _pipeline(command, b, seed, client, usage, run_dir, video, console)
        except BaseException as err:
            if created and not (run_dir / "plan.json").is_file():
                # Nothing was learned (an ungroundable command, no LLM): leave no directory that
                # a retry would have to --resume.
                shutil.rmtree(run_dir, ignore_errors=True)
            else:
                usage.save()  # what this session paid for, though it did not finish
                failed = isinstance(err, Exception)
                sessions.finish(status=f"failed: {err}" if failed else "interrupted")
            raise
        sessions.finish(status="complete")
        report = learn_report(run_dir, summary)
        skill = summary["skill"]
        outcome = (
            f"skill {skill['name']!r} added"
            if skill["added"]
            else f"below {skill['min_success']:.0%}, not added to the skill space"
        )
        rest = (
            f"{command!r}: success {summary['evaluation']['success_rate']:.0%}; {outcome}; "
            f"report {report.markdown}"
        )
        # A policy below the threshold was trained, not learned: not in green, as a success.
        head = (
            "[bold green]learned[/bold green]"
            if skill["added"]
            else "[bold yellow]trained[/bold yellow]"
        )
        console.print(f"{head} {escape(rest)}")
        return LearnResult(run_dir, summary, report)


def _pipeline(
    command: str,
    b: LearnBudget,
    seed: int,
    client: Any,
    usage: UsageLog,
    run_dir: Path,
    video: bool,
    console: Console,
) -> dict[str, Any]:
    steps = _Steps(console, run_dir)

    steps.begin("plan", f"grounding {command!r} in the task catalogue ({client.name})")
    plan = _plan(command, client, steps)

    steps.begin("sources", f"retrieving up to {b.transfer.k} source skills for {plan['task']}")
    sources = _sources(plan["task"], b, steps)

    steps.begin("analyze", "contribution of each source to each stage of the task")
    _analyze(plan["task"], b, seed, sources, client, steps)

    steps.begin("reward", "generating the reward (generate, train candidates, reflect)")
    reward = _reward(command, plan, b, seed, sources, client, run_dir, steps, console)

    steps.begin(
        "train",
        f"{b.transfer.method.upper()} with {b.transfer.algo.upper()} for "
        f"{b.transfer.steps:,} env-steps on the generated reward",
    )
    transfer = _train(plan["task"], b, seed, sources, reward, client, run_dir, steps)

    steps.begin("evaluate", f"{b.eval_episodes} held-out episodes, deterministic policy")
    evaluation = _evaluate(plan["task"], policy_dir(run_dir, transfer), b.eval_episodes, steps)

    steps.begin("skill", "adding the new skill to the skill space")
    skill = _add_skill(command, plan, b, seed, transfer, evaluation, run_dir, steps)

    steps.begin("report", "writing report.md and report.html")
    summary = {
        "command": command,
        "budget": b.name,
        "seed": seed,
        "llm": client.name,
        "plan": plan,
        "reward": reward,
        "sources": sources,
        "transfer": transfer,
        "evaluation": evaluation,
        "skill": skill,
        "video": video,
        # Every session's requests, the reward search's included (its own usage.json has them
        # again, as that step's share).
        "usage": usage.save()["total"],
    }
    write_json(run_dir / "summary.json", summary)
    return summary


def _plan(command: str, client: Any, steps: _Steps) -> dict[str, Any]:
    from itskill.reward.search import plan_target

    cached = steps.cached("plan.json", _PLAN_SHAPE)
    if cached is None:
        # As the reward search reads it (step 4): a task id as itself, and a single word that is
        # none ("pick_nut_m1") refused now, not after three steps as the search's target.
        cached = plan_target(command, client).to_dict()
        write_json(steps.run_dir / "plan.json", cached)
        was_cached = False
    else:
        was_cached = True
    steps.done(
        f"task {cached['task']}: {' → '.join(cached['actions'])}"
        + (f" ({cached['notes']})" if cached.get("notes") else ""),
        was_cached,
    )
    return cached


def _reward(
    command: str,
    plan: dict[str, Any],
    b: LearnBudget,
    seed: int,
    sources: dict[str, list[dict[str, Any]]],
    client: Any,
    run_dir: Path,
    steps: _Steps,
    console,
) -> dict[str, Any]:
    """The reward search; its candidates train the network the transfer step will train (its
    record written to ``transfer/`` now, so both see the same sources and prior). The search is
    given the run's plan: asked again, a model could ground the command in another task."""
    from itskill.reward import TaskPlan, generate_reward
    from itskill.reward.search import CONFIG_FILE, config_from_run
    from itskill.transfer import search_network

    task = plan["task"]

    cached = steps.cached("reward.json", _REWARD_SHAPE)
    was_cached = cached is not None
    if cached is None:
        out = run_dir / REWARD_DIR
        # A search already begun keeps its settings: one a release before the shifted seeds
        # started would otherwise be refused as made with other seeds.
        begun = (out / CONFIG_FILE).is_file()
        config = config_from_run(out, {}) if begun else b.search_config(seed)
        network = search_network(
            task,
            b.transfer.method,
            run_dir / "transfer",
            sources=_source_request(sources),
            seed=seed,
            algo=b.transfer.algo,
            client=client,
        )
        res = generate_reward(
            command,
            client,
            out,
            config,
            # Not "the directory is not empty": a search killed before its first file was
            # complete left only a temporary, and is started again.
            resume=begun,
            compare_expert=b.compare_expert,
            console=console,
            network=network,
            plan=TaskPlan.from_dict(plan),
        )
        if res.best_success is None:
            # Nothing to transfer with: the reward that won the search fails when trained again.
            errors = res.final["generated"]["failed"]
            first = next(iter(errors.values()), "")
            raise LearnError(
                f"the search's chosen reward failed on every final seed ({first}); its code and "
                f"results are in {out}"
            )
        cached = {
            # Relative to the learn run, which may be moved or copied to results/.
            "run_dir": REWARD_DIR,
            "best_path": res.best_path.relative_to(run_dir).as_posix(),
            "best_success": res.best_success,
            "expert_success": res.expert_success,
            "iterations": config.iterations,
            "samples": config.samples,
            "llm": client.name,
            "network": None if network is None else network.label,
        }
        write_json(run_dir / "reward.json", cached)
    expert = cached["expert_success"]
    steps.done(
        f"best reward {cached['best_success']:.0%} success"
        + (f" (expert {expert:.0%})" if expert is not None else "")
        + f" → {best_reward_file(run_dir, cached)}"
        + (f"; candidates trained {cached['network']}" if cached.get("network") else ""),
        was_cached,
    )
    return cached


def _sources(task: str, b: LearnBudget, steps: _Steps) -> dict[str, list[dict[str, Any]]]:
    """The retrieved skills and those the method uses (PST keeps a subset)."""
    from itskill.transfer import get_method, load_transfer_config, resolve_sources

    cached = steps.cached("sources.json", _SOURCES_SHAPE)
    was_cached = cached is not None
    if cached is None:
        method = get_method(b.transfer.method)
        retrieved = used = []
        if method.uses_sources:
            config = replace(load_transfer_config(), k=b.transfer.k)
            retrieved = resolve_sources(task, "auto", config)
            used = method.select(retrieved, config)
        cached = {
            "retrieved": [s.to_dict() for s in retrieved],
            "used": [s.to_dict() for s in used],
        }
        write_json(steps.run_dir / "sources.json", cached)
    names = ", ".join(s["name"] for s in cached["used"])
    steps.done(names or f"none ({b.transfer.method} uses no source)", was_cached)
    return cached


def _source_request(sources: dict[str, list[dict[str, Any]]]) -> list[str] | str:
    """The sources the transfer network is asked for: the skills retrieved in the sources step
    (by name, so a skill added since does not change them)."""
    return [s["name"] for s in sources["retrieved"]] or "auto"


def _analyze(
    task: str,
    b: LearnBudget,
    seed: int,
    sources: dict[str, list[dict[str, Any]]],
    client: Any,
    steps: _Steps,
) -> dict[str, Any] | None:
    """The analyzer's contribution matrix: the one in the transfer run's record, written here
    (``transfer/transfer.json``), which the reward search's network and the training then read."""
    from itskill.transfer import get_method, prepare_transfer

    cached = steps.cached("analysis.json", _ANALYSIS_SHAPE, _ANALYSIS_FIELDS)
    was_cached = cached is not None
    if cached is None:
        cached = {}
        if get_method(b.transfer.method).uses_prior and sources["used"]:
            record = prepare_transfer(
                task,
                b.transfer.method,
                _source_request(sources),
                seed,
                b.transfer.algo,
                steps.run_dir / TRANSFER_DIR,
                client,
            )
            cached = record["contribution"]
        write_json(steps.run_dir / "analysis.json", cached)
    if not cached:
        steps.done(f"not used by {b.transfer.method}", was_cached)
        return None
    rows = [
        f"{seg}: " + " ".join(f"{v:.2f}" for v in row)
        for seg, row in zip(cached["segments"], cached["matrix"], strict=True)
    ]
    steps.done(f"columns {', '.join(cached['sources'])}; " + "; ".join(rows), was_cached)
    return cached


def _train(
    task: str,
    b: LearnBudget,
    seed: int,
    sources: dict[str, list[dict[str, Any]]],
    reward: dict[str, Any],
    client: Any,
    run_dir: Path,
    steps: _Steps,
) -> dict[str, Any]:
    """The final training, in a child process under the sandbox's memory limit, as the reward's
    candidates trained: the generated code runs nowhere else."""
    from itskill.experiments.sandboxed import train_transfer_sandboxed
    from itskill.reward.limited import ChildFailed
    from itskill.reward.sandbox import SandboxError, SandboxTimeout
    from itskill.rl.checkpoint import best_policy_dir
    from itskill.tasks import get_task
    from itskill.transfer import prepare_transfer, read_transfer

    out = run_dir / TRANSFER_DIR
    t = b.transfer
    # The network's record (sources, the analyzer's matrix) is written before the child starts,
    # so the child never needs the LLM client.
    prepare_transfer(task, t.method, _source_request(sources), seed, t.algo, out, client)
    reward_file = best_reward_file(run_dir, reward)
    try:
        res = train_transfer_sandboxed(
            reward_file,
            "generated",
            b.search_config().sandbox,
            "the final training's process",
            target=task,
            method=t.method,
            sources=_source_request(sources),
            seed=seed,
            steps=t.steps,
            algo=t.algo,
            out=out,
            num_envs=t.num_envs,
            eval_every=t.eval_every,
            eval_episodes=t.eval_episodes,
        )
    except (ChildFailed, SandboxError, SandboxTimeout) as err:
        kept = (
            f"the training's last checkpoint is kept in {out}; --resume continues from it"
            if (out / "checkpoint.json").is_file()
            else "it failed before its first checkpoint; --resume starts it again"
        )
        raise LearnError(
            f"the generated reward {reward_file} failed in the final training: {err}; " + kept
        ) from err
    curve = read_curve(out, t.steps)
    wall = float(curve.wall_s[-1])
    record = read_transfer(out)  # what was trained: PST keeps only some of the sources
    names = [s["name"] for s in record["sources"]]
    performers = record.get("performers")
    summary = {
        "run_dir": TRANSFER_DIR,
        "method": t.method,
        "algo": t.algo,
        "steps": int(res.num_timesteps),
        "wall_s": wall,
        "sources": names,
        "contribution": record.get("contribution"),
        # Each stage and the source whose action the head adds to (None: the head alone).
        "residual": None
        if performers is None
        else [
            [st.name, names[k] if k >= 0 else None]
            for st, k in zip(get_task(task).stages, performers, strict=True)
        ],
        "final_success": float(curve.success[-1]),
        # The policy evaluated and kept: the best of the evaluations during training.
        "policy_dir": best_policy_dir(out).relative_to(run_dir).as_posix(),
        "selection": res.best,
    }
    kept = ""
    if res.best is not None:
        kept = f"; best {res.best['success']:.0%} at {int(res.best['env_steps']):,}, kept"
    steps.done(
        f"{res.num_timesteps:,} env-steps{res.resume_note}, {wall / 60:.1f} min of training; last "
        f"evaluation {curve.success[-1]:.0%}{kept} → {policy_dir(run_dir, summary)}"
    )
    return summary


def _evaluate(task: str, kept: Path, episodes: int, steps: _Steps) -> dict[str, Any]:
    from itskill.rl.checkpoint import as_policy
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import HELD_OUT_ENVS, HELD_OUT_SEED, evaluate

    cached = steps.cached("evaluation.json", _EVALUATION_SHAPE)
    was_cached = cached is not None
    if cached is None:
        res = evaluate(
            get_task(task), as_policy(kept), episodes, seed=HELD_OUT_SEED, num_envs=HELD_OUT_ENVS
        )
        cached = res.to_dict()
        write_json(steps.run_dir / "evaluation.json", cached)
    steps.done(
        f"{cached['success_rate']:.1%} success over {cached['episodes']} episodes "
        f"(95% CI {cached['ci_low']:.1%}–{cached['ci_high']:.1%})",
        was_cached,
    )
    return cached


def _free_name(base: str, taken: set[str]) -> str:
    """``base``, or ``base-2``, ``base-3``, ... : the first not in ``taken``."""
    name, i = base, 2
    while name in taken:
        name, i = f"{base}-{i}", i + 1
    return name


def _added_record(skill: Any, space: Any) -> dict[str, Any]:
    """What ``skill.json`` records of ``skill``, added to the skill space ``space``."""
    return {
        "added": True,
        "id": skill.id,
        "name": skill.name,
        "task": skill.task_id,
        "checkpoint": skill.checkpoint,
        "skill_space": str(space.path),
        "success_rate": skill.success_rate,
    }


def _add_skill(
    command: str,
    plan: dict[str, Any],
    b: LearnBudget,
    seed: int,
    transfer: dict[str, Any],
    evaluation: dict[str, Any],
    run_dir: Path,
    steps: _Steps,
) -> dict[str, Any]:
    from itskill.rl.checkpoint import META_FILE, POLICY_FILE
    from itskill.skills import Skill, itskill_home, open_skill_space

    cached = steps.cached("skill.json", _SKILL_SHAPE, _SKILL_FIELDS)
    kept_out = cached is not None and not cached.get("added", True)
    if kept_out and cached["min_success"] != b.min_success:
        cached = None  # resumed with another threshold: decided again, the policy as it was
    gone = ""
    if cached is not None and not kept_out and not _still_in_space(cached):
        # Removed since: "kept from the previous session" named a skill that `itskill skills
        # show` did not know.
        gone = f" (skill {cached['name']!r} was no longer in {cached['skill_space']})"
        cached = None
    was_cached = cached is not None
    pending = steps.run_dir / "skill.pending.json"
    below = evaluation["success_rate"] < b.min_success
    if cached is None and below and pending.is_file():
        # An add cut short, resumed with a threshold the policy misses: kept if it went through
        # (the skill is in the space), else dropped.
        with open_skill_space() as space:
            name = read_json(pending)["name"]
            added = next((s for s in space.list() if s.name == name), None)
            if added is not None:
                cached = _added_record(added, space)
        if cached is None:
            pending.unlink()
    if cached is None and below:
        cached = {
            "added": False,
            "min_success": b.min_success,
            # Relative to the run, as its other records are: a moved run names its own.
            "policy": in_run(policy_dir(run_dir, transfer), run_dir),
        }
    elif cached is None:
        with open_skill_space() as space:
            if pending.is_file():
                # Interrupted between adding the skill and recording it: the same name again,
                # and no second copy if the add went through.
                name = read_json(pending)["name"]
            else:
                name = _free_name(f"learned-{slugify(command)}", {s.name for s in space.list()})
                write_json(pending, {"name": name})
            store = itskill_home() / "learned" / name
            store.mkdir(parents=True, exist_ok=True)
            # The kept policy's directory describes itself (transfer.json included).
            src = policy_dir(run_dir, transfer)
            for file in (POLICY_FILE, META_FILE, "transfer.json"):
                if (src / file).is_file():
                    copy_whole(src / file, store / file)
            selection = transfer["selection"] or {}
            skill = Skill(
                name=name,
                task_id=plan["task"],
                description=command,
                actions=tuple(plan["actions"]),
                checkpoint=str(store / POLICY_FILE),
                success_rate=evaluation["success_rate"],
                success_ci=(evaluation["ci_low"], evaluation["ci_high"]),
                # The kept policy's budget: its env-steps and the training time up to them.
                train_steps=int(selection.get("env_steps", transfer["steps"])),
                train_wall_s=round(selection.get("wall_s", transfer["wall_s"]), 1),
                algo=b.transfer.algo,
                seed=seed,
            )
            cached = _added_record(space.add_many([skill], on_conflict="replace")[0], space)
    if not was_cached:
        write_json(steps.run_dir / "skill.json", cached)
    # Whenever skill.json is there: a kill between the two left it with the step recorded.
    pending.unlink(missing_ok=True)
    cached.setdefault("added", True)  # a skill.json from before the threshold: it was added
    if cached["added"]:
        done = f"skill {cached['id']} {cached['name']!r} in {cached['skill_space']}"
        if below:
            done += (
                f" (added by an earlier session; it stays, below this threshold of "
                f"{b.min_success:.0%}: `itskill skills remove` takes it out)"
            )
    else:
        done = (
            f"not added: success {evaluation['success_rate']:.0%} is below "
            f"{cached['min_success']:.0%}; the policy stays in "
            f"{kept_policy_words(run_dir, transfer)} "
            "(--resume --min-success X adds it at a lower threshold X)"
        )
    steps.done(done + gone, was_cached)
    return cached


def _still_in_space(record: dict[str, Any]) -> bool:
    """Whether the skill ``skill.json`` records as added is still in the skill space it was
    added to (a resume under another ``ITSKILL_HOME`` does not copy it there)."""
    from itskill.skills import open_skill_space

    path = Path(record["skill_space"])
    if not path.is_file():
        return False
    with open_skill_space(path) as space:
        return any(s.id == record["id"] and s.name == record["name"] for s in space.list())
