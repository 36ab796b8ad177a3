"""`itskill skills`: the skill space (list, show, search, add, remove, install, pretrain).

Imports of itskill.skills and itskill.tasks stay inside the functions: the other commands should
not pay for them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from itskill.cli.common import (
    JsonOpt,
    MarkdownOpt,
    check_one_format,
    console,
    episodes_option,
    err_console,
    print_json,
    run_dir_option,
    seed_option,
    steps_option,
    user_errors,
    workers_option,
)
from itskill.errors import FieldError

skills_app = typer.Typer(
    no_args_is_help=True, help="The skill space: learned skills, their checkpoints, retrieval."
)


SkillArg = Annotated[str, typer.Argument(help="Skill id or name (see `itskill skills list`).")]


def _skill_table(rows: list[tuple[Any, float | None]], title: str) -> Table:
    """Skills (with their search scores, if any) as a table; every cell and the title are printed
    as they are, not read as Rich markup (a name may contain "[/b]")."""
    table = Table(title=escape(title))
    scored = any(score is not None for _, score in rows)
    columns = ("score",) if scored else ()
    for column in (*columns, "id", "name", "task", "success", "actions", "checkpoint"):
        table.add_column(column)
    for s, score in rows:
        success = "" if s.success_rate is None else f"{s.success_rate:.1%}"
        cells = (f"{score:.3f}",) if scored else ()
        text = (str(s.id), s.name, s.task_id, success, " → ".join(s.actions), s.checkpoint)
        table.add_row(*cells, *map(escape, text))
    return table


def skills_markdown(skills: Sequence[Any]) -> str:
    """Skills as a Markdown table: what each does, how well and what it cost to learn (the
    library table in docs/skills.md is this output on a new skill space)."""
    from itskill.stats import format_rate_interval

    rows = [
        "| name | task | actions | success [95% CI] | env-steps | wall-min | algorithm, seed |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in skills:
        if s.success_rate is None:
            success = ""
        elif s.success_ci:
            success = format_rate_interval(s.success_rate, *s.success_ci, decimals=1)
        else:
            success = f"{s.success_rate:.1%}"
        steps = "" if s.train_steps is None else f"{s.train_steps:,}"
        wall = "" if s.train_wall_s is None else f"{s.train_wall_s / 60:.1f}"
        trained = ", ".join(
            part
            for part in (s.algo, None if s.seed is None else f"seed {s.seed}")
            if part is not None
        )
        rows.append(
            f"| {s.name} | `{s.task_id}` | {' → '.join(s.actions)} | {success} | {steps} "
            f"| {wall} | {trained} |"
        )
    return "\n".join(rows)


@skills_app.command("list")
def skills_list(
    as_json: JsonOpt = False,
    markdown: MarkdownOpt = False,
) -> None:
    """List every skill in the skill space ($ITSKILL_HOME/skills.sqlite)."""
    check_one_format(as_json, markdown)
    from itskill.skills import open_skill_space

    with user_errors(), open_skill_space() as space:
        skills = space.list()
        path = space.path
    if as_json:
        print_json([s.to_dict() for s in skills])
        return
    if markdown:
        typer.echo(skills_markdown(skills))
        return
    console.print(_skill_table([(s, None) for s in skills], f"{len(skills)} skills in {path}"))


@skills_app.command("show")
def skills_show(skill: SkillArg, as_json: JsonOpt = False) -> None:
    """Show one skill: its description, actions, checkpoint and metrics."""
    from itskill.skills import open_skill_space

    with user_errors(), open_skill_space() as space:
        found = space.get(skill)
        ckpt = space.checkpoint_path(found)
    data = {**found.to_dict(), "checkpoint_path": str(ckpt), "checkpoint_exists": ckpt.is_file()}
    if as_json:
        print_json(data)
        return
    kv = Table.grid(padding=(0, 2))
    kv.add_column(style="cyan")
    kv.add_column()
    for key, value in data.items():
        kv.add_row(key, escape(" → ".join(value) if key == "actions" else str(value)))
    console.print(kv)


@skills_app.command("search")
def skills_search(
    query: Annotated[str, typer.Argument(help="A task command, e.g. 'Pick up the round peg'.")],
    k: Annotated[int, typer.Option("-k", min=1, help="How many skills to return.")] = 5,
    exclude_task: Annotated[
        list[str] | None, typer.Option(help="Leave out skills of this task id (repeatable).")
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """The skills most similar to QUERY (cosine similarity of sentence embeddings, of a skill's
    command or of its command with its actions, whichever is closer)."""
    from itskill.skills import open_skill_space, search
    from itskill.skills.retrieval import check_search

    exclude = set(exclude_task or ())
    with user_errors():
        check_search(query, exclude)  # before the space is opened, which may create it
        with open_skill_space() as space:
            hits = search(space, query, k=k, exclude_tasks=exclude, match_description=True)
    if as_json:
        print_json([{"score": score, **s.to_dict()} for s, score in hits])
        return
    console.print(_skill_table(list(hits), f"top {len(hits)} for {query!r}"))


_MEASUREMENT_OPTIONS = {
    "success": "--success",
    "success_ci": "--ci-low",
    "train_steps": "--steps",
    "train_wall_s": "--wall-s",
}
"""The ``skills add`` option of each :class:`~itskill.skills.Skill` field the space checks."""


@skills_app.command("add")
def skills_add(
    task: Annotated[str, typer.Option(help="Task id the skill solves.")],
    checkpoint: Annotated[
        Path,
        typer.Option(
            help="The trained policy: a training run directory (its kept, best evaluated "
            "policy), its policy.safetensors, or a Stable-Baselines3 .zip (which itskill eval "
            "loads but a transfer cannot use as a source).",
        ),
    ],
    name: Annotated[str | None, typer.Option(help="Unique name (default: the task id).")] = None,
    description: Annotated[
        str | None, typer.Option(help="Task command (default: the task's command).")
    ] = None,
    actions: Annotated[
        str | None, typer.Option(help="Comma-separated actions (default: the task's actions).")
    ] = None,
    success: Annotated[float | None, typer.Option(min=0, max=1, help="Success rate.")] = None,
    ci_low: Annotated[float | None, typer.Option(min=0, max=1, help="95% CI low.")] = None,
    ci_high: Annotated[float | None, typer.Option(min=0, max=1, help="95% CI high.")] = None,
    steps: Annotated[int | None, steps_option("Training env-steps.", least=0)] = None,
    wall_s: Annotated[float | None, typer.Option(min=0, help="Training wall seconds.")] = None,
    algo: Annotated[str | None, typer.Option(help="Algorithm, e.g. ppo or a2c.")] = None,
    seed: Annotated[int | None, seed_option("Training seed.")] = None,
    as_json: JsonOpt = False,
) -> None:
    """Add a learned skill (its checkpoint must exist and load as a policy)."""
    from itskill.rl.checkpoint import POLICY_FILE, best_policy_dir
    from itskill.skills import Skill, open_skill_space
    from itskill.skills.admission import InadmissibleSkillError, check_admissible
    from itskill.skills.store import (
        InvalidMeasurementError,
        InvalidSkillNameError,
        check_measurements,
        check_skill_name,
    )
    from itskill.tasks import get_task

    if (ci_low is None) != (ci_high is None):
        raise typer.BadParameter("give both --ci-low and --ci-high, or neither")
    if name is not None:
        try:
            check_skill_name(name)  # before the policy loads, which takes seconds
        except InvalidSkillNameError as err:
            raise typer.BadParameter(str(err), param_hint="--name") from err
    with user_errors():  # a --checkpoint too long to look up, ...
        checkpoint = checkpoint.expanduser().resolve()
        if checkpoint.is_dir():
            checkpoint = best_policy_dir(checkpoint) / POLICY_FILE
        spec = get_task(task)
        acts = spec.actions if actions is None else tuple(a.strip() for a in actions.split(","))
        # What the run recorded fills what the options leave out: a skill added from a run
        # showed no budget, algorithm or seed.
        run = _recorded_run(checkpoint)
        if steps is None and wall_s is None:  # a pair: one given is another budget's
            steps, wall_s = run.get("steps"), run.get("wall_s")
        algo = run.get("algo") if algo is None else algo
        seed = run.get("seed") if seed is None else seed
        skill = Skill(
            name=name or spec.id,
            task_id=spec.id,
            description=description or spec.command,
            actions=tuple(a for a in acts if a),
            checkpoint=str(checkpoint),
            success_rate=success,
            success_ci=None if ci_low is None or ci_high is None else (ci_low, ci_high),
            train_steps=steps,
            train_wall_s=wall_s,
            algo=algo,
            seed=seed,
        )
        try:
            # As the space will, but naming the option, and before the policy loads (seconds).
            check_measurements(skill)
        except InvalidMeasurementError as err:
            hint = _MEASUREMENT_OPTIONS[err.field]
            raise typer.BadParameter(err.problem, param_hint=hint) from err
        # Before the space opens: a refused add must not create it (with the shipped library
        # in it).
        if not checkpoint.exists():
            raise typer.BadParameter(
                f"{checkpoint} does not exist (only learned skills, with a trained policy, go "
                "into the skill space)",
                param_hint="--checkpoint",
            )
        try:
            check_admissible(spec.id, checkpoint, acts)
        except InadmissibleSkillError as err:
            hint = "--checkpoint" if any(acts) else "--actions"
            raise typer.BadParameter(str(err), param_hint=hint) from err
        with open_skill_space() as space:
            if skill.name in space:  # the space's error, but naming the option and the default
                taken = f"a skill named {skill.name!r} already exists"
                if name is None:
                    taken += " (without --name a skill takes its task's name)"
                raise typer.BadParameter(f"{taken}: give another --name", param_hint="--name")
            # Inside the space's or the shipped library, relative to it, as installs and
            # pretraining store theirs (either may move); absolute anywhere else: a path
            # relative to the shell's directory means nothing to other processes.
            added = space.add(replace(skill, checkpoint=space.checkpoint_ref(checkpoint)))
    if as_json:
        print_json(added.to_dict())
        return
    console.print(escape(f"added skill {added.id}: {added.name} ({added.task_id})"))
    if added.success_rate is None:
        console.print(
            escape(
                f"its success is unknown (retrieval treats it as working): measure it with "
                f"itskill eval {added.task_id} --policy skill:{added.name}, then "
                f"itskill skills remove {added.name} and add it again, with the same --task "
                "and --checkpoint, and --success (and --ci-low, --ci-high)"
            ),
            highlight=False,
        )


def _recorded_run(checkpoint: Path) -> dict[str, Any]:
    """The training budget, algorithm and seed the ``checkpoint.json`` beside a
    ``policy.safetensors`` records (read and checked by :func:`read_meta`): the budget of the
    kept policy where its evaluation chose it (``selection``, when both its env-steps and its
    seconds are well formed), else the checkpoint's own. Empty for any other checkpoint (a
    Stable-Baselines3 ``.zip`` is added without its run's record)."""
    from itskill.datafile import is_number
    from itskill.rl.checkpoint import META_FILE, read_meta
    from itskill.rl.clock import TRAIN_WALL_KEY
    from itskill.rl.eval_callback import SELECTION_KEY

    if checkpoint.suffix != ".safetensors" or not (checkpoint.parent / META_FILE).is_file():
        return {}
    meta = read_meta(checkpoint.parent)
    chosen = meta.get(SELECTION_KEY)
    steps, wall_s = (
        (chosen.get("env_steps"), chosen.get("wall_s"))
        if isinstance(chosen, dict)
        else (None, None)
    )
    # A pair, or neither: the wall time of one budget beside the steps of another misleads.
    if not (
        is_number(steps) and steps >= 0 and float(steps).is_integer()
        and is_number(wall_s) and wall_s >= 0
    ):  # fmt: skip
        steps, wall_s = meta["num_timesteps"], meta.get(TRAIN_WALL_KEY)
    found = {
        "steps": int(steps),
        "wall_s": wall_s,
        "algo": meta.get("algo"),
        "seed": meta.get("seed"),
    }
    return {key: value for key, value in found.items() if value is not None}


@skills_app.command("remove")
def skills_remove(skill: SkillArg, as_json: JsonOpt = False) -> None:
    """Remove a skill from the skill space (its checkpoint file is left in place)."""
    from itskill.skills import open_skill_space

    with user_errors(), open_skill_space() as space:
        removed = space.remove(skill)
    if as_json:
        print_json(removed.to_dict())
        return
    console.print(escape(f"removed skill {removed.id}: {removed.name}"))


@skills_app.command("install")
def skills_install(
    library: Annotated[Path, typer.Argument(help="Library directory with a manifest.json.")],
    as_json: JsonOpt = False,
) -> None:
    """Register every skill of a library directory (skipping names already present)."""
    from itskill.skills import install_library, open_skill_space, read_manifest

    with user_errors():
        # A bad manifest fails before the space opens, which may create it.
        names = [e.name for e in read_manifest(library)]
        with open_skill_space() as space:
            added = install_library(space, library)
    if as_json:
        print_json([s.to_dict() for s in added])
        return
    console.print(escape(f"installed {len(added)} skill(s) from {library}"))
    installed = {s.name for s in added}
    skipped = [n for n in names if n not in installed]
    if skipped:
        console.print(
            escape(f"skipped {len(skipped)} whose name the skill space has: {', '.join(skipped)}")
        )


_PRETRAIN_FLAGS = {
    "algo": "--algo",
    "seeds": "--seed/--seeds",
    "min_success": "--min-success",
    "replace_p": "--replace-p",
    "select_episodes": "--eval-episodes",
    "steps": "--steps",
}
"""The flag behind each :class:`PretrainConfig` field its errors name."""


@skills_app.command("pretrain")
def skills_pretrain(
    tasks: Annotated[
        list[str] | None,
        typer.Option(
            "--tasks",
            help="Tasks to train, comma-separated or repeated (default: every basic task).",
        ),
    ] = None,
    steps: Annotated[
        int | None,
        steps_option(
            "Env-steps per skill (default: the budget the shipped library records for the "
            "skill, 300,000 for a task it lacks)."
        ),
    ] = None,
    algo: Annotated[str, typer.Option(help="a2c or ppo.")] = "ppo",
    seed: Annotated[int, seed_option("The first seed each skill tries.")] = 0,
    seeds: Annotated[
        int,
        typer.Option(
            min=1,
            help="Runs a skill may use: while every run so far ends below --min-success, "
            "the next seed trains; the best run is kept.",
        ),
    ] = 3,
    episodes: Annotated[
        int | None,
        episodes_option("Held-out evaluation episodes per skill (default: 400)."),
    ] = None,
    eval_every: Annotated[
        int,
        typer.Option(
            min=0,
            help="Evaluate every N env-steps while training and export the best policy "
            "(0: the last one).",
        ),
    ] = 50_000,
    eval_episodes: Annotated[
        int | None,
        episodes_option(
            "Episodes of each evaluation during training (--eval-every), which chooses "
            "the policy exported (default: 50)."
        ),
    ] = None,
    min_success: Annotated[
        float,
        typer.Option(min=0.0, max=1.0, help="Success a skill needs to be added to the library."),
    ] = 0.5,
    executor: Annotated[str, typer.Option(help="local (one job per core) or ray.")] = "local",
    workers: Annotated[
        int | None,
        workers_option(
            "Parallel jobs (default: one per core; with Ray, as many as the cluster takes)."
        ),
    ] = None,
    ray_address: Annotated[str | None, typer.Option(help="Ray cluster address.")] = None,
    runs: Annotated[Path, run_dir_option("Training run directories (resumable).")] = Path(
        "runs/pretrain"
    ),
    library: Annotated[
        Path | None,
        # An empty --library is "." to Typer: the manifest and skill folders among the user's
        # own files.
        run_dir_option("Library directory (default: the skill space's own)."),
    ] = None,
    refine: Annotated[
        bool,
        typer.Option(
            "--refine",
            help="Train each skill on from the library's own (default --steps 100,000); the "
            "result replaces it only if it succeeds significantly more often on the same "
            "held-out episodes (--replace-p).",
        ),
    ] = False,
    replace_p: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            max=1.0,
            help="With --refine: the one-sided p-value (exact McNemar test over the paired "
            "held-out episodes) a refined skill must be below to replace the library's, above "
            "0 (default: 0.05; 1 replaces on any higher success).",
        ),
    ] = None,
) -> None:
    """Train skills from scratch with expert rewards (or, with --refine, on from the library's
    or the shipped skill), evaluate each, add them to the skill space.

    Rerunning the same command resumes unfinished trainings from their last checkpoint.
    """
    if replace_p is not None and not refine:
        raise typer.BadParameter(
            "it decides whether a refined skill replaces the library's; add --refine",
            param_hint="--replace-p",
        )
    from itskill.executors import check_executor
    from itskill.rl.train import ResumeMismatchError
    from itskill.skills import open_skill_space
    from itskill.skills.library import shipped_budgets
    from itskill.skills.pretrain import (
        ABANDONED_KEY,
        REFINE_STEPS,
        REFINED_KEY,
        PretrainConfig,
        basic_tasks,
        pretrain,
    )
    from itskill.tasks import get_task

    names = [t.strip() for item in tasks or () for t in item.split(",") if t.strip()]
    if tasks is not None and not names:
        # Every basic task is the default for no --tasks, not for an empty list (a variable
        # that expanded to nothing would otherwise start hours of training).
        raise typer.BadParameter(
            f"{','.join(tasks)!r} names no task; leave --tasks out to train every basic task",
            param_hint="--tasks",
        )
    default_steps = REFINE_STEPS if refine else PretrainConfig.steps
    try:
        config = PretrainConfig(
            algo=algo,
            steps=default_steps if steps is None else steps,
            refine=refine,
            seed=seed,
            seeds=seeds,
            eval_episodes=PretrainConfig.eval_episodes if episodes is None else episodes,
            min_success=min_success,
            eval_every=eval_every,
            select_episodes=(
                PretrainConfig.select_episodes if eval_episodes is None else eval_episodes
            ),
            replace_p=PretrainConfig.replace_p if replace_p is None else replace_p,
        )
    except FieldError as err:  # the config validates what the options' ranges cannot say
        raise typer.BadParameter(str(err), param_hint=_PRETRAIN_FLAGS.get(err.field)) from err

    failed: list[str] = []
    mismatched: list[str] = []  # their runs hold other settings: a rerun fails them again

    def report(task: str, entry, added: bool, error) -> None:
        if error is not None:
            failed.append(task)
            if isinstance(error, ResumeMismatchError):
                mismatched.append(task)
            console.print(
                f"[red]{escape(f'{task}: failed: {type(error).__name__}: {error}')}[/red]"
            )
        else:
            lo, hi = entry.success_ci
            origin = entry.extra.get(REFINED_KEY)
            if added:
                learned = ""
            elif entry.success < config.min_success:
                learned = " - not learned, not added"
            else:
                learned = (
                    f" - not clearly better than the library's skill on the same episodes "
                    f"({origin['success']:.1%}; {origin['episodes_won']} won, "
                    f"{origin['episodes_lost']} lost, p = {origin['p']:.2g}), not replaced"
                )
            # A refined skill's budget counts both rounds; this run's share is what it cost now.
            steps, wall_s = entry.steps, entry.wall_s
            more = ""
            if origin:
                steps -= origin["steps"] or 0
                wall_s -= origin["wall_s"] or 0.0
                more = f" more ({entry.steps:,} in all)"
            console.print(
                f"{escape(task)}: success {entry.success:.1%} (95% CI {lo:.1%}-{hi:.1%}) after "
                f"{steps:,} env-steps{more}, {wall_s / 60:.1f} min, seed {entry.seed}{learned}"
            )
            for run in entry.extra.get(ABANDONED_KEY, []):
                console.print(
                    f"  not kept: seed {run['seed']}, success {run['success']:.1%} after "
                    f"{run['steps']:,} env-steps, {run['wall_s'] / 60:.1f} min"
                )

    with user_errors():
        # Before the space opens (which may create it) and pretrain makes the library directory.
        check_executor(executor, workers, ray_address)
        for name in names:
            get_task(name)
        with open_skill_space() as space:
            pretrain(
                basic_tasks() if tasks is None else names,
                config,
                runs,
                library or space.library_dir,
                space,
                executor=executor,
                workers=workers,
                ray_address=ray_address,
                on_result=report,
                budgets=shipped_budgets() if steps is None and not refine else None,
            )
    if failed:
        retried = [t for t in failed if t not in mismatched]
        ways = []
        if retried:
            ways.append(
                f"the same command tries {', '.join(retried)} again, from their last checkpoints"
            )
        if mismatched:
            ways.append(
                f"{', '.join(mismatched)}: their run directories under --runs hold runs of other "
                "settings; move those aside or give another --runs directory"
            )
        err_console.print(
            f"[red]error:[/red] {len(failed)} skill(s) failed: {escape(', '.join(failed))}; "
            + escape("; ".join(ways)),
            highlight=False,
        )
        raise typer.Exit(1)
