"""A reward search's run directory as the commands read it back: `itskill reward show` on files
edited into another shape, and `itskill reward generate --out` on a directory holding another
kind of run."""

from __future__ import annotations

import io
import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console
from search_helpers import tiny_config
from typer.testing import CliRunner

from itskill.cli import app
from itskill.reward import RewardSearchError, generate_reward, load_search, search_client
from itskill.reward.search import check_new_run

# The files `show` reads; the trainings' directories are left behind when a test copies the run.
RUN_FILES = ["config.json", "plan.json", "usage.json", "summary.json", "best_reward.py",
             "iter_0/summary.json"]  # fmt: skip


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished search with a selection and the expert's comparison, at the smallest budget."""
    run = tmp_path_factory.mktemp("search") / "run"
    generate_reward(
        "pick_nut_m12",
        search_client(run, "offline"),
        run,
        tiny_config(samples=1, select_top=1),
        console=Console(file=io.StringIO()),
    )
    return run


def _copy(run: Path, to: Path) -> Path:
    for name in RUN_FILES:
        (to / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run / name, to / name)
    return to


def _show(run: Path) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["reward", "show", str(run)], env={"COLUMNS": "200"})
    return result.exit_code, " ".join(result.output.split())


def _set(*keys: Any, value: Any) -> Callable[[Any], Any]:
    """An edit setting the field at ``keys`` to ``value``."""

    def edit(data: Any) -> Any:
        inner = data
        for key in keys[:-1]:
            inner = inner[key]
        inner[keys[-1]] = value
        return data

    return edit


def _drop(*keys: str) -> Callable[[Any], Any]:
    """An edit removing the field at ``keys``."""

    def edit(data: Any) -> Any:
        inner = data
        for key in keys[:-1]:
            inner = inner[key]
        del inner[keys[-1]]
        return data

    return edit


@pytest.mark.parametrize(
    ("file", "edit", "message"),
    [
        ("summary.json", lambda _: {}, "summary.json: plan: missing"),
        ("summary.json", _drop("final"), "summary.json: final: missing"),
        ("summary.json", _set("final", "generated", "mean", value="high"),
         "summary.json: final.generated.mean: expected a number or null, got \"high\""),
        ("summary.json", _set("selection", "candidates", 0, "select_success", value=[None, "x"]),
         "summary.json: selection.candidates[0].select_success[1]: expected a number or null"),
        ("summary.json", _set("plan", "subtasks", value="lift it"),
         "summary.json: plan.subtasks: expected a list of strings"),
        ("usage.json", lambda _: {"total": {}}, "usage.json: total.requests: missing"),
        ("usage.json", lambda _: [], "usage.json: expected a JSON object, got []"),
        ("usage.json", _set("sessions", value=2), "usage.json: sessions: expected a list, got 2"),
        ("iter_0/summary.json", _set("accepted", value="2"),
         "iter_0/summary.json: accepted: expected a whole number, got \"2\""),
        ("plan.json", _drop("task"), "plan.json: plan.task: expected a string, got None"),
        ("config.json", _drop("target"), "config.json: target: missing"),
    ],
)  # fmt: skip
def test_a_run_file_of_another_shape_is_a_one_line_error_naming_it(
    finished_run: Path, tmp_path: Path, file: str, edit, message: str
) -> None:
    # Each was valid JSON that show or load_search then failed on with a KeyError or TypeError.
    run = _copy(finished_run, tmp_path)
    assert _show(run)[0] == 0  # the search's own files are read as written
    path = run / file
    path.write_text(json.dumps(edit(json.loads(path.read_text()))))
    code, output = _show(run)
    assert code == 2 and output.startswith("error: ") and message in output, output
    assert "Traceback" not in output
    with pytest.raises(RewardSearchError, match=re.escape(message)):
        load_search(run)


def test_a_final_retraining_on_one_seed_shows_no_interval(finished_run: Path) -> None:
    # It showed "(95% CI 0%–0%)": the zero-width interval of a single value, read as certainty.
    code, output = _show(finished_run)
    assert code == 0, output
    for label in ("generated (best)", "expert"):
        assert re.search(
            rf"{re.escape(label)}: success \d+% \(1 seed, no interval\) over seeds \[\d+\]", output
        ), output
    assert "95% CI" not in output
    # The messages count iterations from 1, the folders from 0: both are named.
    best = json.loads((finished_run / "summary.json").read_text())["best"]
    folder = f"iter_{best['iteration']}/sample_{best['sample']}"
    assert (
        f"chosen: iteration {best['iteration'] + 1}, sample {best['sample']} ({folder};" in output
    )
    assert (finished_run / folder).is_dir()


def test_a_final_retraining_on_several_seeds_shows_its_interval(
    finished_run: Path, tmp_path: Path
) -> None:
    run = _copy(finished_run, tmp_path)
    path = run / "summary.json"
    summary = json.loads(path.read_text())
    band = {"seeds": [5, 6, 7], "success": [0.2, 0.3, 0.4], "mean": 0.3, "ci_low": 0.05,
            "ci_high": 0.55}  # fmt: skip
    summary["final"]["generated"].update(band)
    path.write_text(json.dumps(summary))
    code, output = _show(run)
    assert code == 0, output
    assert "generated (best): success 30% [5%, 55%] over seeds [5, 6, 7]" in output
    assert re.search(r"expert: success \d+% \(1 seed, no interval\)", output), output
    # A t-interval over three seeds of 0, 100 and 0% reaches past both ends: it showed
    # "95% CI -110%–177%", where no rate can lie.
    wide = {"seeds": [5, 6, 7], "success": [0.0, 1.0, 0.0], "mean": 1 / 3, "ci_low": -1.1,
            "ci_high": 1.77}  # fmt: skip
    summary["final"]["generated"].update(wide)
    path.write_text(json.dumps(summary))
    assert "generated (best): success 33% [0%, 100%] over seeds" in _show(run)[1]


@pytest.mark.parametrize(
    "config",
    [
        '{"tasks": ["pick_nut_m12"], "methods": ["scratch"], "seeds": [0]}',  # an experiment's
        '{"kind": "itskill-training", "task": "pick_nut_m12"}',
        "not JSON",
    ],
)
def test_a_directory_holding_another_kind_of_run_is_not_offered_to_resume(
    tmp_path: Path, config: str
) -> None:
    # It said "already holds a reward search: continue it with --resume", and --resume then
    # refused it as not a reward search run.
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(config)
    with pytest.raises(RewardSearchError) as err:
        generate_reward("pick_nut_m12", search_client(run, "offline"), run, tiny_config())
    assert str(err.value) == (
        f"{run} holds another kind of run, or files that are not a reward search (its "
        "config.json is not a reward search's): choose another --out"
    )
    assert [p.name for p in run.iterdir()] == ["config.json"]
    assert (run / "config.json").read_text() == config


def test_a_new_search_refuses_a_directory_of_other_files(tmp_path: Path) -> None:
    # A learn run there (plan.json, summary.json) was overwritten and could not be resumed.
    run = tmp_path / "learn_run"
    run.mkdir()
    (run / "plan.json").write_text('{"task": "pickplace_nut_m12"}')
    result = CliRunner().invoke(app, ["reward", "generate", "pick_nut_m12", "--out", str(run)])
    assert result.exit_code == 2
    assert "holds plan.json and is not a reward search" in " ".join(result.output.split())
    assert [p.name for p in run.iterdir()] == ["plan.json"]


def test_a_search_whose_model_never_answered_leaves_nothing_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The directory held the search's plan and settings, so the same command again, with the
    # server started or another --llm, was refused as taken.
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{sock.getsockname()[1]}/v1"
    monkeypatch.setenv("OPENAI_API_KEY", "unused")
    run = tmp_path / "run"
    args = ["reward", "generate", "pick_nut_m12", "--llm", "openai:llama3", "--base-url", url,
            "--out", str(run)]  # fmt: skip
    for _ in range(2):
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 2
        text = " ".join(result.output.split())
        assert "connection refused" in text and "nothing was kept: run the command again" in text
        assert not run.exists()
    # A folder that was there stays, with what it held: only what the search wrote goes.
    run.mkdir()
    (run / ".DS_Store").write_bytes(b"\0")
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "nothing was kept" in " ".join(result.output.split())
    assert [p.name for p in run.iterdir()] == [".DS_Store"]


def test_a_new_search_takes_a_folder_a_file_browser_has_shown(tmp_path: Path) -> None:
    (tmp_path / ".DS_Store").write_bytes(b"\0")
    check_new_run(tmp_path)
    (tmp_path / "plan.json").write_text("{}")
    with pytest.raises(RewardSearchError, match=r"holds plan\.json and is not a reward search"):
        check_new_run(tmp_path)


def test_a_finished_search_without_its_chosen_reward_says_where_it_is(
    finished_run: Path, tmp_path: Path
) -> None:
    # load_search (and so `generate --resume` on a finished run) read the file without a check:
    # a FileNotFoundError traceback.
    run = _copy(finished_run, tmp_path / "run")
    (run / "best_reward.py").unlink()
    with pytest.raises(RewardSearchError, match=r"best_reward.py: missing.*sample_<k>/reward.py"):
        load_search(run)


def test_a_chosen_reward_that_is_not_text_is_named(finished_run: Path, tmp_path: Path) -> None:
    # `reward show` said only "'utf-8' codec can't decode byte 0xff", naming no file.
    run = _copy(finished_run, tmp_path / "run")
    (run / "best_reward.py").write_bytes(b"\xff\xfe")
    code, output = _show(run)
    assert code == 2 and "best_reward.py: not UTF-8 text (byte 0)" in output, output
    assert "Traceback" not in output


def test_a_search_in_use_is_refused_before_its_network_is_built(tmp_path: Path) -> None:
    # `--transfer` builds the candidates' network into the run before the search starts: a
    # second session wrote it (and asked the model for its analysis) while the first ran.
    from itskill.files import directory_lock

    run = tmp_path / "run"
    with directory_lock(run, "reward-search"):
        result = CliRunner().invoke(
            app, ["reward", "generate", "pick_nut_m12", "--transfer", "itn", "--out", str(run)]
        )
    assert result.exit_code == 2, result.output
    assert f"{run} is in use by another itskill reward generate" in " ".join(result.output.split())
    assert not run.exists()


def test_a_run_whose_reward_prompt_changed_is_not_resumed(
    finished_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Every request missed the reply cache and was paid for again, and each finished candidate
    # whose new code differed was trained again in place of its result, without a word.
    from itskill.llm import prompts

    run = _copy(finished_run, tmp_path / "run")
    (run / "summary.json").unlink()  # unfinished: a resume goes on with it
    assert json.loads((run / "config.json").read_text())["prompt_sha256"]
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    # The base prompt, and a feedback template that only the later iterations' requests carry.
    for name in ("reward_system", "policy_feedback"):
        shipped = Path(str(prompts._template_path(name))).read_text(encoding="utf-8")
        mine = tmp_path / f"prompts_{name}"
        mine.mkdir()
        (mine / f"{name}.txt").write_text("Be brief. " + shipped, encoding="utf-8")
        monkeypatch.setenv(prompts.PROMPTS_DIR_ENV, str(mine))
        with pytest.raises(RewardSearchError, match="reward prompt changed since the run began"):
            generate_reward("pick_nut_m12", search_client(run, "offline"), run,
                            tiny_config(samples=1, select_top=1), resume=True,
                            console=Console(file=io.StringIO()))  # fmt: skip
        assert sorted(p.relative_to(run) for p in run.rglob("*")) == before
