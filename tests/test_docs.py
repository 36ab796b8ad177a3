"""The tables and blocks in docs/ that are a command's or the code's output stay that output: a
task, a shipped skill or the reward context changed without regenerating them would otherwise show
users stale stages, success rates or context keys."""

from __future__ import annotations

from pathlib import Path

from itskill.cli.skills import skills_markdown
from itskill.cli.tasks import tasks_markdown
from itskill.sim.context import CONTEXT_DOC
from itskill.skills.manifest import read_manifest
from itskill.skills.store import SHIPPED_LIBRARY

DOCS = Path(__file__).resolve().parents[1] / "docs"


def shipped_skills() -> list:
    """The skills a new skill space holds: exactly the shipped ones, in the manifest's order."""
    return [e.to_skill(e.checkpoint) for e in read_manifest(SHIPPED_LIBRARY)]


def test_the_task_table_is_itskill_tasks_list() -> None:
    assert tasks_markdown() in (DOCS / "tasks.md").read_text(), (
        "docs/tasks.md: regenerate its table with `itskill tasks list --markdown`"
    )


def test_the_library_table_is_the_shipped_library() -> None:
    skills = shipped_skills()
    assert len(skills) >= 30
    assert skills_markdown(skills) in (DOCS / "skills.md").read_text(), (
        "docs/skills.md: regenerate its library table with `itskill skills list --markdown` "
        "on a new skill space (ITSKILL_HOME pointing at an empty directory)"
    )


def test_the_library_table_shows_each_skills_measured_success() -> None:
    skills = shipped_skills()
    table = skills_markdown(skills).splitlines()
    assert len(table) == 2 + len(skills)
    row = next(r for r in table if r.startswith("| pick_nut_m12 |"))
    pick = next(s for s in skills if s.name == "pick_nut_m12")
    assert f"{pick.success_rate:.1%} [{pick.success_ci[0]:.1%}, {pick.success_ci[1]:.1%}]" in row
    assert f"{pick.train_steps:,}" in row


def test_the_reward_context_block_is_context_doc() -> None:
    text = (DOCS / "simulation.md").read_text()
    start = text.index("```text\nReward context `ctx`") + len("```text\n")
    block = text[start : text.index("```", start)]
    assert block == CONTEXT_DOC, (
        "docs/simulation.md: paste itskill.sim.context.CONTEXT_DOC into its reward context block"
    )
