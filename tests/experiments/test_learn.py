"""`itskill learn`: the whole pipeline on a tiny budget, resume, budgets, and clear errors."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from itskill.cli import app
from itskill.experiments.learn import BudgetError, learn_dir, load_budgets, slugify
from itskill.reward import load_search_config

runner = CliRunner()
COMMAND = "Pick up the nut and place it on the bolt"

# Smaller than the packaged "tiny": every step runs, nothing is learned, in well under a minute.
TEST_BUDGETS = """
[test]
compare_expert = false
[test.reward]
iterations = 1
samples = 1
steps = 256
num_envs = 2
select_top = 0
final_seeds = 1
evaluations = 1
eval_episodes = 2
correlation_envs = 2
[test.transfer]
method = "itn"
algo = "a2c"
steps = 256
num_envs = 2
eval_every = 128
eval_episodes = 2
[test.evaluation]
episodes = 4
min_success = 0.0
"""


def flat(text: str) -> str:
    return " ".join(text.split())


@pytest.fixture
def budgets(tmp_path: Path) -> Path:
    path = tmp_path / "budgets.toml"
    path.write_text(TEST_BUDGETS)
    return path


def learn(*args: str):
    return runner.invoke(app, ["learn", *args])


def test_learn_completes_adds_a_skill_and_resumes_without_redoing(
    tmp_path, budgets, home, monkeypatch
):
    from itskill.reward import plan as plan_module
    from itskill.reward import search
    from itskill.rl.checkpoint import load_policy
    from itskill.skills import open_skill_space

    planned, original = [], plan_module.plan_command

    def counted(command, client):
        planned.append(command)
        return original(command, client)

    for module in (plan_module, search):  # learn's own step, and the reward search's
        monkeypatch.setattr(module, "plan_command", counted)

    out = tmp_path / "run"
    args = [COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out)]
    result = learn(*args, "--no-video")
    assert result.exit_code == 0, result.output
    # One plan for the whole run: asked again, a model could ground the command in another task
    # than the one the sources were retrieved for.
    assert planned == [COMMAND]
    text = flat(result.output)
    for i, step in enumerate(("plan", "sources", "analyze", "reward", "train", "evaluate"), 1):
        assert f"[{i}/8] {step}" in text
    summary = json.loads((out / "summary.json").read_text())
    # The reward's candidates trained the network the task is then trained with: the ITN over
    # the same sources (the record the transfer run resumed from).
    candidate = out / "reward" / "iter_0" / "sample_0" / "train" / "seed_0"
    meta = json.loads((candidate / "checkpoint.json").read_text())
    assert meta["policy_class"] == "itskill.transfer.itn.ITNPolicy"
    names = ", ".join(s["name"] for s in summary["sources"]["used"])
    assert summary["reward"]["network"] == f"itn over {names}"
    assert f"candidates trained itn over {names}" in text
    assert summary["plan"]["task"] == "pickplace_nut_m12"
    assert summary["transfer"]["steps"] >= 256 and summary["evaluation"]["episodes"] == 4
    assert summary["transfer"]["sources"] == [s["name"] for s in summary["sources"]["used"]]
    assert summary["transfer"]["contribution"]["sources"] == summary["transfer"]["sources"]
    pick, place, _ = summary["transfer"]["sources"]
    assert summary["transfer"]["residual"] == [
        ["approach", pick],
        ["grasp", pick],
        ["lift", pick],
        ["approach", place],
        ["place", place],
    ]

    with open_skill_space() as space:
        skill = space.get(summary["skill"]["name"])
        checkpoint = space.checkpoint_path(skill)
    assert skill.description == COMMAND and skill.task_id == "pickplace_nut_m12"
    assert skill.actions == ("approach", "grasp", "lift", "approach", "place")
    assert skill.success_rate == summary["evaluation"]["success_rate"]
    assert checkpoint.is_file() and str(home) in str(checkpoint)
    # The skill is the run's best evaluated policy, and the held-out evaluation measured it.
    chosen = summary["transfer"]["selection"]
    # Named relative to the run, which may be moved or copied to results/.
    assert summary["transfer"]["policy_dir"] == "transfer/best"
    assert summary["reward"]["best_path"] == "reward/best_reward.py"
    assert chosen["env_steps"] in (128, 256) and skill.train_steps == chosen["env_steps"]
    assert skill.train_wall_s == round(chosen["wall_s"], 1)  # the kept policy's, not the run's
    stored, best = load_policy(checkpoint.parent), load_policy(out / "transfer" / "best")
    assert stored.state_dict().keys() == best.state_dict().keys()
    assert all(torch.equal(v, best.state_dict()[k]) for k, v in stored.state_dict().items())
    # Measured on the held-out episodes, not on the evaluation episodes that chose best/.
    from itskill.rl.checkpoint import as_policy
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import HELD_OUT_ENVS, HELD_OUT_SEED, evaluate

    again = evaluate(
        get_task("pickplace_nut_m12"), as_policy(out / "transfer" / "best"), 4,
        seed=HELD_OUT_SEED, num_envs=HELD_OUT_ENVS,
    )  # fmt: skip
    measured = json.loads((out / "evaluation.json").read_text())
    for key in ("outcomes", "mean_length", "mean_stages_done", "stage_steps"):
        assert measured[key] == again.to_dict()[key], key  # each episode's own, not the run's

    md = (out / "report.md").read_text()
    for section in ("## Plan", "## Generated reward", "## Transfer", "## Evaluation",
                    "Policy evaluated: the policy that scored best in the evaluations",
                    "Attention over one episode", "## Skill added to the skill space",
                    f"Source-action residual: in each stage the action head's output is added to "
                    f"the action of the source that performs it (approach: {pick};"):  # fmt: skip
        assert section in md, section
    assert (out / "report.html").read_text().count("data:image/png;base64,") == 2

    again = learn(*args, "--no-video")
    assert again.exit_code == 2 and "--resume" in flat(again.output)

    model = out / "transfer" / "model.zip"
    stamp = model.stat().st_mtime_ns
    resumed = learn(*args, "--no-video", "--resume")
    assert resumed.exit_code == 0, resumed.output
    assert flat(resumed.output).count("kept from the previous session") >= 5
    # The training had nothing left to do: not "resumed from 256", which reads as training on.
    assert "finished in an earlier session; nothing trained now" in flat(resumed.output)
    assert model.stat().st_mtime_ns == stamp
    with open_skill_space() as space:
        assert [s.name for s in space.list(task_id="pickplace_nut_m12")] == [skill.name]

    # Interrupted after the skill went into the space but before the run recorded it: the resume
    # finds it under the same name instead of adding a second copy.
    (out / "skill.json").unlink()
    (out / "skill.pending.json").write_text(json.dumps({"name": skill.name}))
    resumed = learn(*args, "--no-video", "--resume")
    assert resumed.exit_code == 0, resumed.output
    with open_skill_space() as space:
        assert [s.name for s in space.list(task_id="pickplace_nut_m12")] == [skill.name]
    assert json.loads((out / "skill.json").read_text())["name"] == skill.name
    assert not (out / "skill.pending.json").exists()

    # The LLM usage adds up over the sessions (it was the last session's alone), and the reward
    # search's own record holds its requests, not the plan's and the analyzer's before it.
    usage = json.loads((out / "usage.json").read_text())
    assert len(usage["sessions"]) == 3
    assert json.loads((out / "summary.json").read_text())["usage"] == usage["total"]
    first = usage["sessions"][0]
    search = json.loads((out / "reward" / "usage.json").read_text())["sessions"][0]
    assert first["requests"] - search["requests"] == 2  # the plan and the analysis

    # The skill removed since: "kept from the previous session" named a skill the space no
    # longer had; the resume adds it again and says why.
    with open_skill_space() as space:
        space.remove(skill.name)
    resumed = learn(*args, "--no-video", "--resume")
    assert resumed.exit_code == 0, resumed.output
    assert f"skill {skill.name!r} was no longer in" in flat(resumed.output)
    with open_skill_space() as space:
        assert [s.name for s in space.list(task_id="pickplace_nut_m12")] == [skill.name]
        readded = space.get(skill.name).id
    assert json.loads((out / "skill.json").read_text())["id"] == readded

    # A step's file damaged between sessions is named when read, not a KeyError steps later.
    evaluation = json.loads((out / "evaluation.json").read_text())
    (out / "evaluation.json").write_text(json.dumps({**evaluation, "episodes": "four"}))
    damaged = learn(*args, "--no-video", "--resume")
    assert damaged.exit_code == 2, damaged.output
    assert "evaluation.json: episodes: expected a whole number" in flat(damaged.output)
    assert "delete it and --resume to run its step again" in flat(damaged.output)
    # The skill step's record: run again, it would add the skill a second time.
    (out / "evaluation.json").write_text(json.dumps(evaluation))
    recorded = json.loads((out / "skill.json").read_text())
    (out / "skill.json").write_text(json.dumps({**recorded, "id": "one"}))
    damaged = learn(*args, "--no-video", "--resume")
    assert damaged.exit_code == 2, damaged.output
    assert "skill.json: id: expected a whole number" in flat(damaged.output)
    assert "remove it first (`itskill skills remove NAME`)" in flat(damaged.output)

    # Moved elsewhere, the run still has its report: its records name files relative to it.
    moved = tmp_path / "moved"
    out.rename(moved)
    (moved / "report.md").unlink()
    from itskill.experiments.report import learn_report

    learn_report(moved, json.loads((moved / "summary.json").read_text()))
    assert "## Generated reward" in (moved / "report.md").read_text()


def test_a_new_run_refuses_a_folder_holding_other_files(tmp_path, budgets):
    # A step takes the file of its name from an earlier session: another run's plan.json was
    # kept as this run's ("kept from the previous session"), the user's files overwritten.
    out = tmp_path / "mine"
    out.mkdir()
    (out / "plan.json").write_text('{"task": "insert_peg_round"}')
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out))
    assert result.exit_code == 2
    assert "holds plan.json and is not a learn run" in flat(result.output)
    assert sorted(p.name for p in out.iterdir()) == ["plan.json"]


def test_a_skill_below_the_threshold_stays_out_of_the_skill_space(tmp_path, budgets, home):
    from itskill.skills import open_skill_space

    out = tmp_path / "run"
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                   "--no-video", "--min-success", "1.0")  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["evaluation"]["success_rate"] < 1.0  # 256 env-steps learn nothing
    assert summary["skill"]["added"] is False
    assert "not added to the skill space" in flat(result.output)
    # Not announced as learned (in green): nothing joined the skill space.
    assert f"trained '{COMMAND}'" in flat(result.output)
    assert f"learned '{COMMAND}'" not in flat(result.output)
    with open_skill_space() as space:
        assert space.list(task_id="pickplace_nut_m12") == []
    assert (out / summary["skill"]["policy"] / "checkpoint.json").is_file()  # the policy is kept
    report = (out / "report.md").read_text()
    assert "## Not added to the skill space" in report
    assert f"It stays in the run's {summary['skill']['policy']};" in report
    # A record from before policies were named relative to the run reads the same.
    record = json.loads((out / "skill.json").read_text())
    record["policy"] = str(out.resolve() / record["policy"])
    (out / "skill.json").write_text(json.dumps(record))
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                   "--no-video", "--min-success", "1.0", "--resume")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert f"the policy stays in the run's {summary['skill']['policy']} " in flat(result.output)
    assert f"It stays in the run's {summary['skill']['policy']};" in (out / "report.md").read_text()

    # An add cut short before the skill joined the space, resumed with a threshold the policy
    # misses, is dropped: nothing is added, and the record of it goes.
    (out / "skill.pending.json").write_text('{"name": "learned-never-added"}')
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                   "--no-video", "--min-success", "0.99", "--resume")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads((out / "skill.json").read_text())["added"] is False
    assert not (out / "skill.pending.json").exists()
    with open_skill_space() as space:
        assert space.list(task_id="pickplace_nut_m12") == []

    # A plain resume keeps the run's threshold, not the budget's; a lower one given on resume
    # adds the policy as it is, without training it again.
    resumed = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                    "--no-video", "--resume")  # fmt: skip
    assert resumed.exit_code == 0, resumed.output
    assert json.loads((out / "summary.json").read_text())["skill"]["added"] is False
    weights = (out / summary["skill"]["policy"] / "policy.safetensors").read_bytes()
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                   "--no-video", "--min-success", "0.0", "--resume")  # fmt: skip
    assert result.exit_code == 0, result.output
    kept = flat(result.output).count("(kept from the previous session)")
    assert kept == 5, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["skill"]["added"] is True
    with open_skill_space() as space:
        (skill,) = space.list(task_id="pickplace_nut_m12")
    assert Path(skill.checkpoint).read_bytes() == weights
    assert "## Skill added to the skill space" in (out / "report.md").read_text()
    # A higher one leaves it there, and says so.
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                   "--no-video", "--min-success", "1.0", "--resume")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "it stays, below this threshold of 100%" in flat(result.output)


def test_ungroundable_command_is_one_clear_line(tmp_path, budgets):
    result = learn("make me a sandwich", "--budgets", str(budgets), "--budget", "test",
                   "--out", str(tmp_path / "run"))  # fmt: skip
    assert result.exit_code == 2
    assert "error:" in result.output and "Traceback" not in result.output
    assert "sandwich" in result.output
    assert not (tmp_path / "run").exists()  # nothing to resume: a retry starts afresh


@pytest.mark.parametrize("command", ["asdf [/b]", "asdf [red]x"])
def test_a_command_with_brackets_is_printed_as_typed(tmp_path, budgets, command):
    # Rich read it as markup: "[/b]" ended in a MarkupError traceback, "[red]" vanished.
    result = learn(command, "--budgets", str(budgets), "--budget", "test",
                   "--out", str(tmp_path / "run"))  # fmt: skip
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert f"[1/8] plan: grounding {command!r} in the task catalogue" in text
    assert f"error: cannot plan {command!r}" in text and "Traceback" not in text


def test_step_results_print_skill_and_file_names_as_typed(tmp_path):
    import io

    from rich.console import Console

    from itskill.experiments.learn import _Steps

    out = io.StringIO()
    steps = _Steps(Console(file=out, emoji=False), tmp_path)
    steps.begin("sources", "retrieving source skills")
    steps.done("pick[/v2], reach[red]2", cached=True)
    assert "✓ (kept from the previous session) pick[/v2], reach[red]2" in out.getvalue()


@pytest.mark.parametrize(
    ("made", "why"), [(False, "no such directory"), (True, "the directory is empty")]
)
def test_resume_with_no_run_to_resume_is_refused(tmp_path, budgets, made, why):
    # It started a fresh run instead: hours of training where a continuation was asked for.
    out = tmp_path / "run"
    if made:
        out.mkdir()
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out),
                   "--resume")  # fmt: skip
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert f"nothing to resume: there is no learn run in {out} ({why})" in text
    assert "leave out --resume to start a new run" in text and "Traceback" not in text
    assert "[1/8]" not in text  # not even the plan was started
    assert out.exists() == made and not (made and any(out.iterdir()))


def test_long_commands_that_begin_alike_get_directories_of_their_own(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    stem = "Pick up the nut and place it on the bolt, then carry it over to "
    first, second = learn_dir(stem + "the left", None), learn_dir(stem + "the right", None)
    assert first != second
    assert first.parent == second.parent == Path("runs/learn")
    assert first.name.startswith("pick-up-the-nut-and-place-it-on-the-bolt-then-carry-it-over")
    assert learn_dir(" " + stem + "the left ", None) == first  # what learn runs is stripped
    assert learn_dir(COMMAND, None) == Path("runs/learn/pick-up-the-nut-and-place-it-on-the-bolt")
    assert learn_dir(stem + "the left", tmp_path / "mine") == tmp_path / "mine"


def test_a_long_command_run_made_before_the_hash_is_still_found(tmp_path, monkeypatch):
    # Such runs lived in the bare 60-character slug's directory: --resume must find them there.
    monkeypatch.chdir(tmp_path)
    command = "Pick up the nut and place it on the bolt, then carry it over to the left"
    bare = Path("runs/learn") / slugify(command)
    bare.mkdir(parents=True)
    (bare / "learn.json").write_text(json.dumps({"command": command, "seed": 0}))
    assert learn_dir(command, None) == bare
    other = command.replace("left", "right")
    assert learn_dir(other, None) != bare


@pytest.mark.parametrize("out", [False, True])
def test_empty_command_is_one_short_line(tmp_path, budgets, out):
    args = ["--out", str(tmp_path / "run")] if out else []
    result = learn("  ", "--budgets", str(budgets), "--budget", "test", *args)
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert "the command is empty: say what the robot should do" in text
    assert "pick_nut_m12" not in text and len(text) < 250
    assert not (tmp_path / "run").exists()


def test_a_seed_the_shifted_reward_search_cannot_take_is_refused_first(tmp_path, budgets):
    # It failed at the reward step with a traceback naming a seed the user never typed, after
    # the plan and the analysis (paid requests with a model) were made.
    top = load_budgets(budgets)["test"].max_seed
    out = tmp_path / "run"
    result = learn("pick up the nut", "--budgets", str(budgets), "--budget", "test",
                   "--seed", str(top + 1), "--out", str(out))  # fmt: skip
    assert result.exit_code == 2, result.output
    assert f"--seed must be between 0 and {top:,} with the 'test' budget" in flat(result.output)
    assert not out.exists()
    config = load_budgets(budgets)["test"].search_config(top)
    assert max(config.final_seed_list) <= 2**32 - 1


def test_unreachable_llm_is_one_clear_line(tmp_path, budgets, monkeypatch):
    from itskill.llm import openai_client

    class FastClient(openai_client.OpenAIClient):
        def __init__(self, *args, **kwargs):
            fast = openai_client.RetryConfig(max_retries=1, backoff_initial_s=0.01, timeout_s=2)
            super().__init__(*args, **{**kwargs, "retry": fast})

    monkeypatch.setattr(openai_client, "OpenAIClient", FastClient)
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("OPENAI_BASE_URL", f"http://127.0.0.1:{port}/v1")
    result = learn(COMMAND, "--llm", "openai:some-model", "--budgets", str(budgets),
                   "--budget", "test", "--out", str(tmp_path / "run"))  # fmt: skip
    assert result.exit_code == 2, result.output
    assert "error:" in result.output and "Traceback" not in result.output
    assert f"127.0.0.1:{port}" in flat(result.output)


def test_packaged_budgets_load_and_tiny_is_smallest():
    budgets = load_budgets()
    assert {"tiny", "default", "full"} <= set(budgets)
    assert budgets["tiny"].transfer.steps < budgets["default"].transfer.steps
    assert budgets["default"].transfer.steps < budgets["full"].transfer.steps
    assert budgets["full"].search_config().iterations == 5  # the paper's 5 x 10 samples
    assert budgets["full"].search_config().samples == 10
    assert budgets["default"].min_success == 0.5 and budgets["tiny"].min_success == 0.0


@pytest.mark.parametrize("name", ["tiny", "default", "full"])
def test_each_learn_seed_searches_rewards_on_seeds_of_its_own(name):
    budget = load_budgets()[name]

    def trained_on(seed: int) -> set[int]:
        config = budget.search_config(seed)
        selection = config.select_seed_list if config.select_top else []
        return {*config.seeds, *config.final_seed_list, *selection}

    # Seed 0 keeps the configured seeds, so its runs are the ones measured before.
    assert budget.search_config(0).seeds == load_search_config(overrides=budget.reward).seeds
    runs = [trained_on(seed) for seed in range(4)]
    for i, seeds in enumerate(runs):
        assert all(seeds.isdisjoint(other) for other in runs[i + 1 :])


def test_a_budget_without_algo_trains_ppo(tmp_path):
    path = tmp_path / "b.toml"
    path.write_text(TEST_BUDGETS.replace('algo = "a2c"\n', ""))
    assert load_budgets(path)["test"].transfer.algo == "ppo"


@pytest.mark.parametrize(
    ("field", "edit"),
    [
        ("steps", ("steps = 256\nnum_envs = 2\neval_every", "num_envs = 2\neval_every")),
        ("eval_every", ("eval_every = 128\n", "")),
    ],
)
def test_transfer_steps_and_eval_every_are_required(tmp_path, field, edit):
    path = tmp_path / "b.toml"
    path.write_text(TEST_BUDGETS.replace(*edit))
    with pytest.raises(BudgetError, match=rf"test\.transfer\.{field}: missing \(required\)"):
        load_budgets(path)


def test_budget_threshold_outside_zero_to_one_is_rejected(tmp_path):
    path = tmp_path / "b.toml"
    path.write_text(TEST_BUDGETS.replace("min_success = 0.0", "min_success = 50"))
    with pytest.raises(BudgetError, match=r"test\.evaluation\.min_success.*between 0 and 1"):
        load_budgets(path)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("steps = 256\nnum_envs = 2\neval_every", "steps = 0\nnum_envs = 2\neval_every"),
         "test.transfer.steps: must be positive"),
        (('method = "itn"', 'method = "xyz"'), "test.transfer.method: expected one of"),
        (('algo = "a2c"', 'algo = "sac"'), "test.transfer.algo: expected one of ['a2c', 'ppo']"),
        (("iterations = 1", "iterations = 0"), "test.reward"),
        (("[test.evaluation]", "[test.evaluation]\nseeds = 3"), "test.evaluation"),
        (("compare_expert = false", "compare_expert = 1"), "compare_expert: expected a boolean"),
    ],
)  # fmt: skip
def test_bad_budget_fields_are_named(tmp_path, edit, message):
    path = tmp_path / "b.toml"
    path.write_text(TEST_BUDGETS.replace(*edit))
    with pytest.raises(BudgetError) as info:
        load_budgets(path)
    assert message in str(info.value) and str(path) in str(info.value)


@pytest.mark.parametrize(
    ("edit", "where", "problem"),
    [
        # The reward search's fields named "test.reward: overrides: iterations".
        (("iterations = 1", "iterations = 0"), "test.reward.iterations", "a positive number"),
        (("select_top = 0", "select_top = -1"), "test.reward.select_top", "0 or more"),
        (("samples = 1", "sampels = 1"), "test.reward.sampels", "unknown field"),
        (
            ("[test.transfer]", "[test.reward.sandbox]\ncall_timeout_s = inf\n[test.transfer]"),
            "test.reward.sandbox.call_timeout_s",
            "expected a finite number",
        ),
        # Counts with no bound: MemoryError, or a crash at allocation, after the reward search.
        (
            ("eval_episodes = 2\ncorrelation", "eval_episodes = 100000000000000\ncorrelation"),
            "test.reward.eval_episodes",
            "at most 1,000,000",
        ),
        (
            ("num_envs = 2\nselect_top", "num_envs = 100000000000\nselect_top"),
            "test.reward.num_envs",
            "at most 1,024",
        ),
        (
            ("num_envs = 2\neval_every", "num_envs = 100000000000\neval_every"),
            "test.transfer.num_envs",
            "at most 1,024",
        ),
        (
            ("eval_episodes = 2\n[test.evaluation]", "eval_episodes = 1000001\n[test.evaluation]"),
            "test.transfer.eval_episodes",
            "at most 1,000,000",
        ),
        (
            ("episodes = 4", "episodes = 100000000000000"),
            "test.evaluation.episodes",
            "at most 1,000,000",
        ),
        # Trained on at an undecayed learning rate for ever, after the whole reward search.
        (
            (
                "steps = 256\nnum_envs = 2\neval_every",
                "steps = 1000000000000\nnum_envs = 2\neval_every",
            ),
            "test.transfer.steps",
            "at most 1,000,000,000",
        ),
    ],
)
def test_budget_fields_are_named_as_the_file_has_them(tmp_path, edit, where, problem):
    path = tmp_path / "b.toml"
    assert edit[0] in TEST_BUDGETS
    path.write_text(TEST_BUDGETS.replace(*edit, 1))
    with pytest.raises(BudgetError) as info:
        load_budgets(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert problem in info.value.problem


@pytest.mark.parametrize(
    ("edit", "where", "bound"),
    [
        # No upper bound: thousands of frozen sources, paid model calls or trainings, or days of
        # one, all found only once the run got there.
        (("eval_episodes = 2\n[test.evaluation]", "eval_episodes = 2\nk = {}\n[test.evaluation]"),
         "test.transfer.k", 32),
        (("iterations = 1", "iterations = {}"), "test.reward.iterations", 100),
        (("samples = 1", "samples = {}"), "test.reward.samples", 100),
        (("steps = 256\nnum_envs = 2\nselect_top", "steps = {}\nnum_envs = 2\nselect_top"),
         "test.reward.steps", 1_000_000_000),
        (("evaluations = 1", "evaluations = {}"), "test.reward.evaluations", 1000),
        (("final_seeds = 1", "final_seeds = {}"), "test.reward.final_seeds", 1000),
        (("[test.transfer]", "max_regenerations = {}\n[test.transfer]"),
         "test.reward.max_regenerations", 10),
        (("[test.transfer]", "probe_steps = {}\n[test.transfer]"), "test.reward.probe_steps", 1000),
        (("[test.transfer]", "workers = {}\n[test.transfer]"), "test.reward.workers", 1024),
    ],
)  # fmt: skip
def test_budget_counts_have_an_upper_bound(tmp_path, edit, where, bound):
    path = tmp_path / "b.toml"
    old, new = edit
    assert old in TEST_BUDGETS
    path.write_text(TEST_BUDGETS.replace(old, new.format(bound), 1))
    load_budgets(path)  # the bound itself loads
    path.write_text(TEST_BUDGETS.replace(old, new.format(bound + 1), 1))
    with pytest.raises(BudgetError) as info:
        load_budgets(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert f"at most {bound:,}, got {bound + 1:,}" in info.value.problem


def test_unknown_budget_is_a_clear_error(tmp_path, budgets):
    result = learn(COMMAND, "--budgets", str(budgets), "--budget", "huge",
                   "--out", str(tmp_path / "run"))  # fmt: skip
    assert result.exit_code == 2 and "unknown budget 'huge'" in flat(result.output)


def test_the_final_training_runs_the_generated_reward_under_the_memory_limit(tmp_path, home):
    """The reward search trained this code in a limited process; the final training, longer and
    seeing other states, must too: a reward whose allocation grows with what it is given fails
    there, in one line, and the CLI's own process keeps its limits."""
    import resource

    from rich.console import Console

    from itskill.experiments.learn import LearnBudget, LearnError, TransferBudget, _Steps, _train

    bomb = tmp_path / "best_reward.py"
    bomb.write_text(
        "import numpy as np\n\n"
        "def compute_reward(ctx):\n"
        "    big = np.ones(ctx['time_frac'].shape[0] * 600_000_000)  # 9.6 GB for two envs\n"
        "    return ctx['time_frac'] + big[:1], {}\n"
    )
    budget = LearnBudget(
        name="test",
        transfer=TransferBudget(steps=64, eval_every=64, method="no_transfer", num_envs=2),
        reward={"sandbox": {"memory_limit_mb": 4096}},
    )
    before = resource.getrlimit(resource.RLIMIT_AS)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with pytest.raises(LearnError) as info:
        _train("pick_nut_m12", budget, 0, {"retrieved": [], "used": []},
               {"best_path": str(bomb)}, None, run_dir, _Steps(Console(), run_dir))  # fmt: skip
    message = str(info.value)
    assert "ran out of memory" in message and str(bomb) in message and "--resume" in message
    assert resource.getrlimit(resource.RLIMIT_AS) == before


def recorded_run(tmp_path: Path, budgets: Path) -> tuple[Path, dict]:
    """A run directory holding only the record a session of the test budget starts with."""
    out = tmp_path / "run"
    out.mkdir()
    budget = load_budgets(budgets)["test"].to_dict()
    settings = {"command": COMMAND, "budget": budget, "seed": 0, "llm": "offline"}
    (out / "learn.json").write_text(json.dumps(settings))
    return out, settings


def test_resume_names_the_setting_that_differs_and_ignores_a_reworded_description(
    tmp_path, budgets
):
    # It dumped both budgets whole (1,500 characters), and refused a run whose budget's prose
    # description had been reworded, as any release rewording it would.
    out, settings = recorded_run(tmp_path, budgets)
    args = [COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out), "--resume"]
    result = learn(*args, "--steps", "512")
    assert result.exit_code == 2
    assert "started with budget.transfer.steps=256, this call gives 512" in flat(result.output)
    settings["budget"]["description"] = "Reworded."
    (out / "learn.json").write_text(json.dumps(settings))
    result = learn(*args, "--steps", "512")
    assert "budget.transfer.steps=256" in flat(result.output)  # still the one difference


def test_a_mistyped_task_id_is_refused_before_any_step(tmp_path, budgets):
    # The planner grounded "pick_nut_m1" as a command; the reward search, step 4, then refused
    # it as a task id, leaving a run that could neither resume nor start again.
    out = tmp_path / "run"
    result = learn("pick_nut_m1", "--budgets", str(budgets), "--budget", "test", "--out", str(out))
    assert result.exit_code == 2
    assert "unknown task 'pick_nut_m1'" in flat(result.output)
    assert not out.exists()


def test_a_run_in_use_by_another_session_is_refused(tmp_path, budgets):
    # Two sessions on one run trained the same candidates into the same files: both failed,
    # and the run could not be finished any more.
    from itskill.files import directory_lock

    out, _ = recorded_run(tmp_path, budgets)
    args = [COMMAND, "--budgets", str(budgets), "--budget", "test", "--out", str(out), "--resume"]
    with directory_lock(out, "learn"):
        result = learn(*args)
    assert result.exit_code == 2
    assert "in use by another itskill learn" in flat(result.output)
    assert sorted(p.name for p in out.iterdir()) == ["learn.json"]


def test_a_chosen_reward_that_failed_on_every_final_seed_stops_learn_with_its_errors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # best_success None reached a "{:.0%}" format: a TypeError after reward.json was written
    # with null, which a resume then refused as damaged, and deleting it led back to the same.
    from types import SimpleNamespace

    from rich.console import Console

    import itskill.reward
    import itskill.transfer
    from itskill.experiments.learn import LearnError, _reward, _Steps

    failed = SimpleNamespace(
        best_success=None,
        final={"generated": {"failed": {"1": "SandboxError: the reward code raised"}}},
    )
    monkeypatch.setattr(itskill.transfer, "search_network", lambda *a, **k: None)
    monkeypatch.setattr(itskill.reward, "generate_reward", lambda *a, **k: failed)
    budget = load_budgets()["tiny"]
    plan = {"task": "pick_nut_m12", "command": "Pick up the M12 nut", "subtasks": [],
            "actions": ["approach", "grasp", "lift"], "objects": ["nut_m12"]}  # fmt: skip
    console = Console(file=None, quiet=True)
    with pytest.raises(LearnError, match=r"failed on every final seed.*the reward code raised"):
        _reward("Pick up the M12 nut", plan, budget, 0, {"retrieved": []}, None, tmp_path,
                _Steps(console, tmp_path), console)  # fmt: skip
    assert not (tmp_path / "reward.json").exists()
