"""`itskill transfer`: train a task with a transfer method, show the analyzer's matrix, trace W.

Imports of itskill.transfer stay inside the commands: the other commands should not pay for them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.table import Table

from itskill.cli.common import (
    EvalEpisodesOpt,
    EvalEveryOpt,
    HyperparamsOpt,
    JsonOpt,
    TaskArg,
    console,
    episodes_option,
    print_json,
    print_trained,
    run_dir_option,
    seed_option,
    steps_option,
    user_errors,
)
from itskill.limits import NUM_ENVS_MAX, SOURCES_MAX

if TYPE_CHECKING:
    from itskill.transfer import TransferConfig

transfer_app = typer.Typer(
    no_args_is_help=True,
    help="Transfer learned skills to a new task: ITN and its ablations, the analyzer.",
)

SourcesOpt = Annotated[
    str,
    typer.Option(
        help="'auto' (retrieved for the task's command) or skill ids/names, comma-separated."
    ),
]
KOpt = Annotated[
    int | None,
    typer.Option(
        "-k",
        "--k",
        min=1,
        max=SOURCES_MAX,
        help=escape("Sources 'auto' retrieves (default: --config's [sources] k, packaged 3)."),
    ),
]
LLMOpt = Annotated[
    str | None,
    typer.Option(
        "--llm",
        help="Analyzer: 'offline' or 'openai:MODEL' (default $ITSKILL_LLM_MODEL, else offline).",
    ),
]
ConfigOpt = Annotated[
    Path | None, typer.Option(help="A transfer settings TOML instead of the packaged one.")
]


def _config(path: Path | None, k: int | None, sources: str) -> TransferConfig:
    """The transfer settings of ``path`` (None: the packaged ones), with ``-k`` if given."""
    from dataclasses import replace

    from itskill.transfer import load_transfer_config
    from itskill.transfer.sources import AUTO

    if k is not None and sources.strip() != AUTO:
        # Else ignored: the named skills are the sources, however many -k asks for.
        raise typer.BadParameter(
            f"-k sets how many skills --sources auto retrieves; --sources {sources!r} names "
            "them: give one or the other",
            param_hint="-k",
        )
    config = load_transfer_config(path)
    return config if k is None else replace(config, k=k)


@transfer_app.command("train")
def transfer_train(
    target: TaskArg,
    method: Annotated[str, typer.Option(help="itn, nia, dfs, pst or no_transfer.")] = "itn",
    sources: SourcesOpt = "auto",
    k: KOpt = None,
    seed: Annotated[int, seed_option("Seed of the run.")] = 0,
    steps: Annotated[int, steps_option("Total env-steps (a rerun resumes).")] = 200_000,
    algo: Annotated[
        str, typer.Option(help="ppo, or a2c (the paper's algorithm; it learns less from sources).")
    ] = "ppo",
    reward: Annotated[
        str, typer.Option(help="'expert' or a .py file defining compute_reward(ctx).")
    ] = "expert",
    out: Annotated[Path, run_dir_option("Run directory.")] = Path("runs/transfer"),
    num_envs: Annotated[
        int | None, typer.Option(min=1, max=NUM_ENVS_MAX, help="Environments stepped together.")
    ] = None,
    eval_every: EvalEveryOpt = None,
    eval_episodes: EvalEpisodesOpt = 50,
    llm: LLMOpt = None,
    config: ConfigOpt = None,
    hyperparams: HyperparamsOpt = None,
) -> None:
    """Train TARGET with a transfer method; rerun the same command to resume."""
    from itskill.llm.client import LazyClient
    from itskill.rl.config import ALGOS
    from itskill.transfer import METHODS, get_method, train_transfer
    from itskill.transfer.sources import AUTO

    if method not in METHODS:
        raise typer.BadParameter(f"expected one of {', '.join(METHODS)}", param_hint="--method")
    if not get_method(method).uses_sources and (sources.strip() != AUTO or k is not None):
        # Else ignored: the run trained from scratch, whatever skills were named.
        raise typer.BadParameter(
            f"{method} uses no source skills: leave out --sources and -k", param_hint="--method"
        )
    if algo not in ALGOS:
        raise typer.BadParameter(f"expected one of {', '.join(ALGOS)}", param_hint="--algo")
    try:
        with user_errors():
            cfg = _config(config, k, sources)
            # Made only if the analyzer is asked: a run that asks no model needs no API key.
            client = LazyClient(llm)
            result = train_transfer(
                target,
                method,
                sources=sources,
                seed=seed,
                steps=steps,
                algo=algo,
                out=out,
                reward=reward,
                num_envs=num_envs,
                eval_every=eval_every,
                eval_episodes=eval_episodes,
                client=client,
                config=cfg,
                console=console,
                hyperparams=hyperparams,
            )
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    print_trained(f"{target} with {method} ({algo})", result, steps)


@transfer_app.command("analyze")
def transfer_analyze(
    target: TaskArg,
    sources: SourcesOpt = "auto",
    k: KOpt = None,
    llm: LLMOpt = None,
    config: ConfigOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Print the analyzer's contribution matrix: TARGET's stages x the source skills."""
    from itskill.llm.client import LazyClient
    from itskill.tasks import get_task
    from itskill.transfer import analyze_sources, resolve_sources

    with user_errors():
        cfg = _config(config, k, sources)
        spec = get_task(target)
        # Checks --llm before the sources' skill space is opened (which may create it).
        client = LazyClient(llm)
        chosen = resolve_sources(spec.id, sources, cfg)
        # As training does: one source takes every stage, and no model is asked (or needs a key).
        matrix = analyze_sources(spec, chosen, client, cfg)
    if as_json:
        print_json({**matrix.to_dict(), "source_skills": [s.to_dict() for s in chosen]})
        return
    # Titles, headers and cells are markup: skill and task names are escaped ('pick[/v2]').
    title = f"contribution of {len(chosen)} sources to {spec.id} ({matrix.client})"
    table = Table(title=escape(title))
    table.add_column("stage")
    for s in chosen:
        table.add_column(escape(s.name), justify="right")
    for i, segment in enumerate(matrix.segments):
        table.add_row(escape(f"{i} {segment}"), *(f"{v:.2f}" for v in matrix.matrix[i]))
    console.print(table)
    if matrix.reasoning:
        console.print(escape(matrix.reasoning), highlight=False)


@transfer_app.command("trace")
def transfer_trace(
    run_dir: Annotated[Path, typer.Argument(help="A transfer run directory (itn, pst, nia).")],
    episodes: Annotated[int, episodes_option("Deterministic episodes.")] = 1,
    seed: Annotated[int, seed_option("Seed of the initial states.")] = 0,
    as_json: JsonOpt = False,
) -> None:
    """The contribution weights W at every step of an episode of a trained transfer policy."""
    from itskill.transfer import attention_trace

    with user_errors():
        trace = attention_trace(run_dir, episodes, seed)
    if as_json:
        print_json(trace)
        return
    for n, ep in enumerate(trace["episodes"]):
        table = Table(title=escape(f"{trace['task']} episode {n}: success {ep['success']}"))
        table.add_column("step", justify="right")
        table.add_column("stage")
        for name in trace["sources"]:
            table.add_column(escape(f"W {name}"), justify="right")
        previous = None
        for t, (stage, w) in enumerate(zip(ep["stage"], ep["weights"], strict=True)):
            # One row per stage change and every 10th step keeps an episode on one screen.
            if stage != previous or t % 10 == 0:
                segment = escape(trace["segments"][stage])
                table.add_row(str(t), segment, *(f"{v:.2f}" for v in w))
            previous = stage
        console.print(table)
