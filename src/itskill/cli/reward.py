"""`itskill plan` and `itskill reward generate|show`: the planner and the reward search.

Imports of itskill.reward and itskill.llm stay inside the commands: the other commands should not
pay for them.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.syntax import Syntax
from rich.table import Table

from itskill.cli.common import (
    JsonOpt,
    console,
    err_console,
    print_json,
    run_dir_option,
    steps_option,
    usage_error,
    user_errors,
    workers_option,
)

reward_app = typer.Typer(
    no_args_is_help=True,
    help="Reward generation with a language model: search a reward for a task, show a search.",
)

LlmOpt = Annotated[
    str | None,
    typer.Option(
        "--llm",
        help="'offline' (the embedded rule-based backend) or 'openai:MODEL' for any "
        "OpenAI-compatible server; default $ITSKILL_LLM_MODEL, else offline.",
    ),
]
BaseUrlOpt = Annotated[
    str | None,
    typer.Option(help="OpenAI-compatible endpoint (default $OPENAI_BASE_URL, else OpenAI's)."),
]


def plan_cmd(
    command: Annotated[
        str,
        typer.Argument(
            help='What the robot should do ("Pick up the M12 nut and place it on the bolt") or '
            "a task id."
        ),
    ],
    llm: LlmOpt = None,
    base_url: BaseUrlOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Plan a command: the task it means, its ordered subtasks, actions and objects."""
    from itskill.llm import make_client
    from itskill.llm.client import model_spec
    from itskill.reward.plan import plan_command, plan_for_task
    from itskill.reward.search import OFFLINE_NOTE, resolve_target

    with user_errors():
        task = resolve_target(command)
        client = None
        if task is not None:
            model_spec(llm)  # not asked, but a mistyped --llm is said, not ignored
            plan = plan_for_task(task)
        else:
            client = make_client(llm, base_url=base_url)
            plan = plan_command(command, client)
    if as_json:
        print_json(plan.to_dict())
        return
    console.print(f"[bold]{escape(plan.command)}[/bold] → task [bold]{escape(plan.task)}[/bold]")
    for sentence in plan.subtasks:
        console.print(f"  {escape(sentence)}", highlight=False)
    actions, objects = " → ".join(plan.actions), ", ".join(plan.objects)
    console.print(f"actions: {actions}; objects: {objects}", markup=False)
    if plan.notes:
        console.print(f"notes: {escape(plan.notes)}", highlight=False)
    if client is None:
        console.print("planned from the task file (no language model)", style="dim")
    elif client.offline:
        console.print(f"planned by {client.name}: {OFFLINE_NOTE}", style="dim", markup=False)


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:60] or "reward"


@reward_app.command("generate")
def generate_cmd(
    target: Annotated[
        str | None,
        typer.Argument(help="A task id or a command to plan (optional with --resume)."),
    ] = None,
    llm: LlmOpt = None,
    base_url: BaseUrlOpt = None,
    iterations: Annotated[int | None, typer.Option(min=1, help="Iterations (default 5).")] = None,
    samples: Annotated[
        int | None, typer.Option(min=1, help="Reward samples per iteration (default 10).")
    ] = None,
    steps: Annotated[int | None, steps_option("Env-steps per candidate and seed.")] = None,
    executor: Annotated[
        str | None, typer.Option(help="local (process pool) or ray (default local).")
    ] = None,
    workers: Annotated[
        int | None,
        workers_option(
            "Parallel candidates (default: one per core; with Ray, as many as it takes)."
        ),
    ] = None,
    ray_address: Annotated[
        str | None, typer.Option(help="Ray cluster address (default: a local Ray instance).")
    ] = None,
    select_top: Annotated[
        int | None,
        typer.Option(
            min=0,
            help="Best rewards retrained on more seeds before the choice (default 3; 0: none).",
        ),
    ] = None,
    final_seeds: Annotated[
        int | None, typer.Option(min=1, help="Seeds of the final retraining (default 3).")
    ] = None,
    config_file: Annotated[
        Path | None,
        typer.Option(
            "--config",
            help="A search settings TOML file, of the shape of the packaged search.toml "
            "(itskill/reward/data).",
        ),
    ] = None,
    expert: Annotated[
        bool | None,
        typer.Option(
            "--expert/--no-expert",
            help="Retrain the expert reward with the same budget to compare (default: yes, or "
            "what the resumed run did).",
        ),
    ] = None,
    transfer: Annotated[
        str | None,
        typer.Option(
            metavar="METHOD",
            help="Train the candidates with this transfer method (itn, nia, dfs, pst) over the "
            "skills retrieved for the task, as `itskill learn` does (default: the task family's "
            "network from scratch; a resumed run keeps its own).",
        ),
    ] = None,
    out: Annotated[
        Path | None, run_dir_option("Run directory (default runs/reward/<target>).")
    ] = None,
    resume: Annotated[
        Path | None, typer.Option(help="Continue the search in this run directory.")
    ] = None,
) -> None:
    """Search a reward for a task or command: plan, generate, train candidates, keep the best,
    compare it with the expert reward (Fig. 6). Rerun with --resume RUN after an interruption."""
    from itskill.executors import check_executor
    from itskill.llm.client import LLMError, Usage
    from itskill.reward.search import (
        CONFIG_FILE,
        NETWORK_DIR,
        check_new_run,
        config_from_run,
        generate_reward,
        load_search_config,
        read_run,
        search_client,
        search_lock,
    )

    overrides: dict[str, Any] = {
        "iterations": iterations,
        "samples": samples,
        "steps": steps,
        "executor": executor,
        "workers": workers,
        "ray_address": ray_address,
        "select_top": select_top,
        "final_seeds": final_seeds,
    }
    with user_errors():
        if resume is not None:
            if out is not None and out != resume:
                raise typer.BadParameter("give --resume RUN or --out, not both", param_hint="--out")
            stored = read_run(resume)["config"]
            target = target or stored["target"]
            llm = llm or stored["llm"]
            expert = stored["compare_expert"] if expert is None else expert
            if config_file is not None:
                raise typer.BadParameter("a resumed run keeps its settings", param_hint="--config")
            if transfer is not None:
                raise typer.BadParameter("a resumed run keeps its network", param_hint="--transfer")
            if stored.get("network") is not None:
                transfer = _network_method(resume / NETWORK_DIR)
            config = _flags_named(overrides, lambda: config_from_run(resume, overrides))
            run_dir = resume
        else:
            if target is None:
                raise typer.BadParameter(
                    "give a task id or a command (or --resume RUN)", param_hint="TARGET"
                )
            config = _flags_named(overrides, lambda: load_search_config(config_file, overrides))
            run_dir = out or Path("runs/reward") / _slug(target)
        # Before the plan and the network's analysis are asked of the model: the search would
        # refuse an unusable executor only after them.
        check_executor(config.executor, config.workers, config.ray_address)
        # Held from here, not only by the search: the transfer network is built into the run.
        with search_lock(run_dir):
            if resume is None:
                # Before the network is built into it: a directory of another run is refused.
                check_new_run(run_dir)
            before = set(run_dir.iterdir()) if run_dir.is_dir() else None
            client = search_client(run_dir, llm, base_url)
            network = plan = None
            if transfer is not None:
                plan, network = _network(
                    target, transfer, run_dir / NETWORK_DIR, client, config.algo
                )
            try:
                result = generate_reward(
                    target,
                    client,
                    run_dir,
                    config,
                    resume=resume is not None,
                    compare_expert=expert is not False,
                    console=console,
                    network=network,
                    plan=plan,
                    # The plan and the analysis for the network were asked of this client first.
                    usage_since=Usage(),
                )
            except KeyboardInterrupt:
                # Stopped while planning, a new search leaves no run (--resume would find none).
                if (run_dir / CONFIG_FILE).is_file():
                    hint = (
                        "finished candidates are saved; continue with "
                        f"itskill reward generate --resume {run_dir}"
                    )
                else:
                    hint = "nothing was kept; run the same command again"
                err_console.print(f"interrupted: {hint}", markup=False)
                raise typer.Exit(130) from None
            except LLMError as err:
                # The directory now holds this search, so the same command again (with the
                # model fixed, or --llm offline) was refused as taken. No reply paid for: it
                # holds nothing of value, and what this call wrote goes.
                new = resume is None and client.usage.requests == 0
                if new and _remove_added(run_dir, before):
                    raise usage_error(f"{err} (nothing was kept: run the command again)") from err
                if not (run_dir / CONFIG_FILE).is_file():
                    raise
                kept = "the replies paid for" + (
                    " and the candidates trained" if any(run_dir.glob("iter_*")) else ""
                )
                raise usage_error(
                    f"{err}; the search in {run_dir} keeps {kept}: continue it with itskill "
                    f"reward generate --resume {run_dir} (it keeps its --llm {client.name}), or "
                    "start again with another --out"
                ) from err
    console.print(
        f"best reward: {result.best_path}; details: itskill reward show {run_dir}", markup=False
    )


def _remove_added(run_dir: Path, before: set[Path] | None) -> bool:
    """Remove what a new search wrote in ``run_dir``: the folder if it did not exist
    (``before`` None), else the entries not in ``before``; whether all of it went."""
    try:
        if before is None:
            shutil.rmtree(run_dir)
            return True
        for entry in set(run_dir.iterdir()) - before:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
    except OSError:
        return False
    return True


def _rate(band: dict[str, Any]) -> str:
    """A final retraining's success with its 95% interval, cut to [0, 100%] as every rate is,
    or why there is none: one seed has no spread to estimate, and the zero-width interval
    stored for it would read as certainty."""
    from itskill.stats import format_rate, format_rate_interval

    if len(band["seeds"]) < 2:
        return f"{format_rate(band['mean'])} ({len(band['seeds'])} seed, no interval)"
    return format_rate_interval(band["mean"], band["ci_low"], band["ci_high"])


def _flags_named(overrides: dict[str, Any], load: Callable[[], Any]) -> Any:
    """``load()``'s search settings; a value a flag gave that does not validate is a usage error
    naming that flag (the settings reader calls the flags "overrides")."""
    from itskill.reward.config import SearchConfigError

    try:
        return load()
    except SearchConfigError as err:
        # A flag left out is None here: a stored setting that no longer validates is not its.
        if err.path == "overrides" and overrides.get(err.setting) is not None:
            flag = "--" + err.setting.replace("_", "-")
            raise typer.BadParameter(err.problem, param_hint=flag) from err
        raise


def _network_method(record_dir: Path) -> str:
    from itskill.transfer import read_transfer

    return read_transfer(record_dir)["method"]


def _network(target: str, method: str, out: Path, client: Any, algo: str) -> tuple[Any, Any]:
    """The target's plan, and the transfer network the candidates train over the skills
    retrieved for the planned task. The search is given that plan, so the model is asked once."""
    from itskill.reward.search import plan_target
    from itskill.transfer import METHODS, search_network

    # no_transfer is a method too, but trains no source skills: the search without --transfer.
    with_sources = [name for name, m in METHODS.items() if m.uses_sources]
    if method not in with_sources:
        raise typer.BadParameter(
            f"expected one of {', '.join(with_sources)}, got {method!r} (leave --transfer "
            "out to search on the task's network from scratch)",
            param_hint="--transfer",
        )
    plan = plan_target(target, client)
    network = search_network(plan.task, method, out, algo=algo, client=client)
    assert network is not None  # a method with sources has a network
    return plan, network


@reward_app.command("show")
def show_cmd(
    run: Annotated[Path, typer.Argument(help="A reward search run directory.")],
    as_json: JsonOpt = False,
) -> None:
    """Show a reward search: plan, iterations, the best reward, the comparison, LLM usage."""
    from itskill.reward.search import OFFLINE_NOTE, read_run, sample_folder
    from itskill.stats import format_rate

    with user_errors():
        data = read_run(run)
    if as_json:
        print_json(data)
        return
    config, summary, usage = data["config"], data["summary"], data["usage"]
    llm = config["llm"]
    console.print(f"[bold]{escape(str(run))}[/bold]: target {escape(config['target'])}")
    if config.get("offline"):
        console.print(f"replies by {llm}: {OFFLINE_NOTE}", style="yellow", markup=False)
    else:
        console.print(f"replies by {llm}", markup=False)
    if config.get("network"):
        label = config["network"]["label"]
        console.print(f"candidates trained {label}", highlight=False, markup=False)
    plan = data["plan"]
    if plan:
        console.print(f"plan: task {plan['task']}", highlight=False, markup=False)
        for sentence in plan["subtasks"]:
            console.print(f"  {escape(sentence)}", highlight=False)
    table = Table(title="iterations")
    for column in ("iteration", "accepted", "trained", "best sample", "best success",
                   "correlation", "best so far"):  # fmt: skip
        table.add_column(column)
    settings = config.get("settings", {})
    for it in data["iterations"]:
        corr = it.get("best_correlation")
        table.add_row(
            str(it["iteration"] + 1),
            f"{it['accepted']}/{len(it['samples'])}",
            str(it["trained"]),
            "-" if it["best_sample"] is None else str(it["best_sample"]),
            format_rate(it["best_success"]),
            "-" if corr is None else f"{corr:+.2f}",
            format_rate(it["best_so_far"]),
        )
    console.print(table)
    if data["best_code"]:
        console.print("best reward so far:" if summary is None else "best reward:")
        console.print(Syntax(data["best_code"], "python", word_wrap=True))
    if summary is None:
        done = len(data["iterations"])
        console.print(
            f"unfinished: {done}/{settings.get('iterations', '?')} iterations done; continue "
            f"with itskill reward generate --resume {run}",
            style="yellow",
            markup=False,
        )
    else:
        final = summary["final"]
        for key, label in (("generated", "generated (best)"), ("expert", "expert")):
            band = final.get(key)
            if band and band.get("mean") is not None:
                console.print(
                    f"{label}: success {_rate(band)} "
                    f"over seeds {band['seeds']}, "
                    f"{final['steps']} env-steps each",
                    highlight=False,
                )
        selection = summary.get("selection")
        if selection:
            console.print(
                f"selection: the {len(selection['candidates'])} best rewards retrained on seeds "
                f"{selection['seeds']}",
                highlight=False,
            )
            for row in selection["candidates"]:
                per_seed = ", ".join(format_rate(v) for v in row["select_success"])
                console.print(
                    f"  iteration {row['iteration'] + 1}, sample {row['sample']}: search "
                    f"{format_rate(row['search_success'])}, more seeds {per_seed}, "
                    f"mean {format_rate(row['mean'])}",
                    highlight=False,
                )
        best = summary["best"]
        console.print(
            f"chosen: iteration {best['iteration'] + 1}, sample {best['sample']} "
            f"({sample_folder(best)}; search success {format_rate(best['success'])}"
            + (
                f", over every seed {format_rate(best['selected_success'])}"
                if "selected_success" in best
                else ""
            )
            + f"); figure: {Path(run) / 'fig6.png'}",
            highlight=False,
            markup=False,
        )
    if usage:
        total = usage["total"]
        console.print(
            f"LLM usage ({llm}): {total['requests']} requests, {total['prompt_tokens']} prompt + "
            f"{total['completion_tokens']} completion tokens, ${total['cost_usd']:.4f}, "
            f"{total['cache_hits']} cache hits; {len(usage['sessions'])} session(s), "
            f"{total['wall_s'] / 60:.1f} min",
            highlight=False,
            markup=False,
        )
