"""The optimisation loop against a local OpenAI-compatible server serving scripted replies."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from fake_openai import FakeOpenAIServer
from replies import (
    CONSTANT,
    EMPTY,
    ENDLESS,
    ESCAPE,
    GOOD,
    RAISES,
    RAISES_LATER,
    SYNTAX_ERROR,
)
from search_helpers import tiny_config

from itskill.files import directory_lock
from itskill.llm import LLMUnavailableError
from itskill.llm.openai_client import RetryConfig
from itskill.reward import (
    CandidateNetwork,
    RewardSearchError,
    generate_reward,
    load_search,
    search,
    search_client,
)
from itskill.reward.generator import Attempt, Sample, extract_code, fenced
from itskill.reward.plan import PlanError
from itskill.reward.sandbox import compile_reward
from itskill.reward.search import _feedback, _rank, _tagged, _write_sample, plan_target
from itskill.rl.policy import StagedActorCriticPolicy
from itskill.tasks import UnknownTaskError


def _search(
    run: Path, server: FakeOpenAIServer, config, console, target: str = "pick_nut_m12", **kw
):
    """The search for ``target`` in ``run``, asking the scripted ``server``, without the expert
    reward's comparison."""
    client = search_client(run, "openai:fake-model", server.base_url)
    return generate_reward(target, client, run, config, compare_expert=False, console=console, **kw)


def _status(run: Path, k: int) -> dict:
    return json.loads((run / "iter_0" / f"sample_{k}" / "status.json").read_text())


def test_every_broken_reply_is_handled_and_the_good_one_wins(tmp_path: Path, quiet) -> None:
    script = [
        *(GOOD, SYNTAX_ERROR, RAISES, ENDLESS, ESCAPE, EMPTY),  # the 6 samples, in one request
        CONSTANT,  # sample 1 rewritten after its syntax error: trains, but nothing to learn
        RAISES_LATER,  # sample 2 rewritten after its KeyError: passes the probe, fails in training
        ENDLESS,  # sample 3 again: rejected after max_regenerations = 1
        ESCAPE,  # sample 4 again: rejected
        EMPTY,  # sample 5 again: rejected
    ]
    run = tmp_path / "run"
    with FakeOpenAIServer(script) as server:
        result = _search(run, server, tiny_config(samples=6), quiet)
        requests = server.requests

    # One request for the 6 samples, then one regeneration per broken reply, with its error.
    assert [r.get("n", 1) for r in requests] == [6, 1, 1, 1, 1, 1]
    errors = [r["messages"][-1]["content"] for r in requests[1:]]
    assert all("<execution_error>" in e for e in errors)
    assert "syntax error" in errors[0]
    assert "KeyError: 'no_such_key'" in errors[1]
    assert "ran longer than 0.5 s" in errors[2]
    assert "import 'os' is not allowed" in errors[3]
    assert "contains no code" in errors[4]

    statuses = [e["status"] for e in result.history[0]["samples"]]
    assert statuses == ["ok", "ok", "failed", "rejected", "rejected", "rejected"]
    assert _status(run, 1)["regenerations"] == 1 and _status(run, 1)["accepted"]
    assert "timed out" in _status(run, 3)["error"]
    assert "import 'os'" in _status(run, 4)["error"]
    # Every reply is kept with the reason it was rejected.
    assert [a["reply"] for a in _status(run, 4)["attempts"]] == [ESCAPE, ESCAPE]
    failed = json.loads((run / "iter_0" / "sample_2" / "result.json").read_text())
    assert "non-finite" in failed["error"]

    # Nothing is learned at this budget, so GOOD and CONSTANT tie and the first sample wins; the
    # choice on merit is the next tests' (planted successes).
    assert (result.best["iteration"], result.best["sample"]) == (0, 0)
    assert result.best_code.strip() == extract_code(GOOD)
    assert (run / "best_reward.py").read_text().strip() == extract_code(GOOD)
    assert result.expert_success is None
    assert (run / "fig6.png").stat().st_size > 0
    usage = json.loads((run / "usage.json").read_text())
    assert usage["total"]["requests"] == 6 and usage["total"]["prompt_tokens"] > 0
    assert load_search(run).best == result.best

    # Resumed once finished: nothing is asked, trained or written again (its duration included).
    files = {path: path.read_bytes() for path in run.rglob("*") if path.is_file()}
    client = search_client(run, "openai:fake-model", "http://127.0.0.1:9/v1")
    again = generate_reward("pick_nut_m12", client, run, tiny_config(samples=6),
                            resume=True, compare_expert=False, console=quiet)  # fmt: skip
    assert again.best == result.best
    assert {path: path.read_bytes() for path in run.rglob("*") if path.is_file()} == files


def test_feedback_carries_the_best_code_and_its_statistics() -> None:
    best = {"code": "def compute_reward(ctx): ...", "success": 0.25,
            "stats": {"0.approach/reach": {"max": 0.9, "mean": 0.5, "min": 0.1}}}  # fmt: skip
    assistant, user = _feedback(best, None)
    assert assistant["role"] == "assistant" and best["code"] in assistant["content"]
    assert "0.250" in user["content"] and "0.approach/reach" in user["content"]
    assert "temperature" in user["content"]
    _, error = _feedback(None, ("x = (", "line 1: syntax error"))
    assert "<execution_error>" in error["content"]
    assert _feedback(None, None) == []


def test_ranking_is_by_success_then_expert_correlation() -> None:
    entries = [
        {"sample": 0, "success": 0.2, "correlation": None},
        {"sample": 1, "success": 0.2, "correlation": 0.1},
        {"sample": 2, "success": 0.1, "correlation": 0.99},
        {"sample": 3, "success": 0.2, "correlation": -0.5},
    ]
    assert max(entries, key=_rank)["sample"] == 1


def test_unreachable_model_and_unusable_run_dirs(tmp_path: Path, quiet) -> None:
    run = tmp_path / "run"
    client = search_client(run, "openai:fake-model", "http://127.0.0.1:9/v1")
    client.retry = RetryConfig(max_retries=0, timeout_s=2.0)
    with pytest.raises(LLMUnavailableError, match=r"127\.0\.0\.1:9"):
        generate_reward("Pick up the M12 nut", client, run, tiny_config(), console=quiet)
    assert not run.exists()  # the command was never planned: no run to be refused or resumed
    # A task id needs no model to plan: the run is recorded, then its first samples fail.
    with pytest.raises(LLMUnavailableError):
        generate_reward("pick_nut_m12", client, run, tiny_config(), console=quiet)
    taken = f"{run} already holds a reward search: continue it with --resume {run} or choose"
    with pytest.raises(RewardSearchError, match=re.escape(taken)):
        generate_reward("pick_nut_m12", client, run, tiny_config(), console=quiet)
    with pytest.raises(RewardSearchError, match=r"other settings: samples=2 \(now 3\)"):
        generate_reward(
            "pick_nut_m12", client, run, tiny_config(samples=3), resume=True, console=quiet
        )
    with pytest.raises(RewardSearchError, match="made with target="):
        generate_reward("pick_nut_m16", client, run, tiny_config(), resume=True, console=quiet)
    other = CandidateNetwork(StagedActorCriticPolicy, None, "another network")
    with pytest.raises(RewardSearchError, match="made with network=None"):
        generate_reward("pick_nut_m12", client, run, tiny_config(), resume=True,
                        console=quiet, network=other)  # fmt: skip
    with pytest.raises(RewardSearchError, match="not a reward search run"):
        generate_reward("pick_nut_m12", client, tmp_path, tiny_config(), resume=True)
    with pytest.raises(RewardSearchError, match="has not finished"):
        load_search(run)
    with pytest.raises(RewardSearchError, match="no such run directory"):
        load_search(tmp_path / "absent")
    with pytest.raises(RewardSearchError, match="a file, not a run directory"):
        load_search(run / "config.json")


def test_tokens_paid_for_before_an_outage_are_on_record(tmp_path: Path, quiet) -> None:
    # The first sample request is answered, the regeneration after its syntax error is not: the
    # answered request's tokens must be in usage.json (a resume replays it from the cache free).
    from fake_openai import Status

    run = tmp_path / "run"
    with FakeOpenAIServer([GOOD, SYNTAX_ERROR, *[Status(503)] * 5]) as server:
        client = search_client(run, "openai:fake-model", server.base_url)
        client.retry = RetryConfig(max_retries=1, backoff_initial_s=0.01, timeout_s=2.0)
        with pytest.raises(LLMUnavailableError):
            generate_reward(
                "pick_nut_m12", client, run, tiny_config(), compare_expert=False, console=quiet
            )
    usage = json.loads((run / "usage.json").read_text())["total"]
    assert usage["requests"] == 1 and usage["completion_tokens"] > 0


def test_unknown_task_and_ungroundable_command(tmp_path: Path, quiet) -> None:
    client = search_client(tmp_path / "a", "offline")
    with pytest.raises(UnknownTaskError, match="pick_nut_m21"):
        generate_reward("pick_nut_m21", client, tmp_path / "a", tiny_config(), console=quiet)
    assert not (tmp_path / "a" / "config.json").exists()  # nothing to resume: nothing written
    with pytest.raises(PlanError, match=r"Known objects: .*nut_m12"):
        generate_reward("make me a sandwich", search_client(tmp_path / "b", "offline"),
                        tmp_path / "b", tiny_config(), console=quiet)  # fmt: skip
    assert not (tmp_path / "b").exists()  # nor the reply cache of the refused command


@pytest.mark.parametrize("command", ["", "  "])
def test_an_empty_command_leaves_no_run_behind(tmp_path: Path, quiet, command: str) -> None:
    # The run used to be recorded before the command was planned: the same --out was then
    # refused as taken, and --resume failed on the empty command again.
    run = tmp_path / "run"
    client = search_client(run, "offline")
    with pytest.raises(PlanError, match="the command is empty"):
        generate_reward(command, client, run, tiny_config(), console=quiet)
    assert not run.exists()
    with pytest.raises(RewardSearchError, match="not a reward search run"):
        generate_reward(command, client, run, tiny_config(), resume=True, console=quiet)


def test_a_search_in_use_by_another_session_is_refused_and_left_as_it_is(
    tmp_path: Path, quiet, monkeypatch, file_tree
) -> None:
    # Two sessions resuming one search trained the same candidates into the same files: both
    # failed, and the run could not be finished any more.
    def stopped(*args: object) -> None:
        raise RuntimeError("stopped before the samples")

    monkeypatch.setattr(search, "probe_contexts", stopped)
    run = tmp_path / "run"
    client = search_client(run, "offline")
    with pytest.raises(RuntimeError, match="stopped"):  # recorded, then stopped
        generate_reward("pick_nut_m12", client, run, tiny_config(), console=quiet)
    before = file_tree(run)
    new = tmp_path / "new"
    with directory_lock(run, "reward-search"), directory_lock(new, "reward-search"):
        for out, resume in ((run, True), (run, False), (new, False)):
            in_use = (
                f"{out} is in use by another itskill reward generate on this machine; wait for "
                f"it to end, or stop it and continue with --resume {out}"
            )
            with pytest.raises(RewardSearchError, match=re.escape(in_use)):
                generate_reward(
                    "pick_nut_m12", client, out, tiny_config(), resume=resume, console=quiet
                )
    assert file_tree(run) == before
    assert not new.exists()


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_a_search_holds_its_lock_until_it_ends_however_it_ends(
    tmp_path: Path, quiet, monkeypatch, error: type[BaseException], lock_held
) -> None:
    # itskill learn searches in <its run>/reward while it holds its own lock on <its run>: the
    # search's lock must not be refused for it.
    learn_run = tmp_path / "learn"
    run = learn_run / "reward"
    held = []

    def stopped(*args: object) -> None:
        held.append(lock_held(run, "reward-search"))
        raise error("stopped before the samples")

    monkeypatch.setattr(search, "probe_contexts", stopped)
    client = search_client(run, "offline")
    with directory_lock(learn_run, "learn"):
        with pytest.raises(error):
            generate_reward("pick_nut_m12", client, run, tiny_config(), console=quiet)
        # Let go: the next session resumes the run (and is stopped where the first one was).
        with pytest.raises(error):
            generate_reward("pick_nut_m12", client, run, tiny_config(), resume=True, console=quiet)
    assert held == [True, True]
    assert not lock_held(run, "reward-search")


def test_a_reward_repeated_in_a_later_iteration_is_not_trained_again(tmp_path: Path, quiet) -> None:
    # The model answers iteration 2 with the two rewards of iteration 1 (as a seeded or cached
    # model does when the best reward has not changed), one with a new comment: nothing new to
    # train.
    run = tmp_path / "run"
    again = GOOD.replace("def compute_reward", "# The same reward, said again.\ndef compute_reward")
    assert again != GOOD
    with FakeOpenAIServer([GOOD, CONSTANT, again, CONSTANT]) as server:
        result = _search(run, server, tiny_config(iterations=2), quiet)
        requests = server.requests
    assert "This is iteration 2 of the search" in requests[1]["messages"][-1]["content"]
    for k in (0, 1):
        first = json.loads((run / "iter_0" / f"sample_{k}" / "result.json").read_text())
        again = json.loads((run / "iter_1" / f"sample_{k}" / "result.json").read_text())
        assert again.pop("reused_from") == f"iter_0/sample_{k}"
        assert again == first
    assert [e["status"] for e in result.history[1]["samples"]] == ["ok", "ok"]


def test_a_reward_sampled_twice_in_one_iteration_is_trained_once(
    tmp_path: Path, quiet, monkeypatch
) -> None:
    # At a low temperature the K samples of one request are often the same code: each trained.
    run = tmp_path / "run"
    trained: list[str] = []
    real = search.run_candidate

    def counting(job):
        trained.append(Path(job.out).name)
        return real(job)

    monkeypatch.setattr(search, "run_candidate", counting)
    twin = GOOD.replace("def compute_reward", "# Sample 3.\ndef compute_reward")
    # The offline synthesiser's samples differ only in their temperatures: each is its own reward.
    retuned = GOOD.replace("temp_reach = 0.15", "temp_reach = 0.3")
    assert retuned != GOOD
    with FakeOpenAIServer([GOOD, CONSTANT, twin, retuned]) as server:
        result = _search(run, server, tiny_config(samples=4, workers=1), quiet)
    trained_samples = sorted(n for n in trained if n.startswith("sample_"))
    assert trained_samples == ["sample_0", "sample_1", "sample_3"]
    first = json.loads((run / "iter_0" / "sample_0" / "result.json").read_text())
    copy = json.loads((run / "iter_0" / "sample_2" / "result.json").read_text())
    assert copy.pop("reused_from") == "iter_0/sample_0" and copy == first
    own = json.loads((run / "iter_0" / "sample_3" / "result.json").read_text())
    assert "reused_from" not in own
    assert [e["status"] for e in result.history[0]["samples"]] == ["ok"] * 4


def test_a_later_iteration_replaces_the_best_only_when_it_beats_it(
    tmp_path: Path, quiet, monkeypatch
) -> None:
    # Iteration 0's reward succeeds most; the later ones, worse, must neither replace it as the
    # search's choice nor become the code the next iteration's feedback asks the model to improve.
    # Planted results fix the successes, as in the test above.
    monkeypatch.setattr(search, "check_new_run", lambda out: None)
    run = tmp_path / "run"
    retuned = GOOD.replace("temp_reach = 0.15", "temp_reach = 0.3")
    for i, success in enumerate((0.6, 0.3, 0.2)):
        (run / f"iter_{i}" / "sample_0").mkdir(parents=True)
        (run / f"iter_{i}" / "sample_0" / "result.json").write_text(
            json.dumps(_fake_result(success, 0.9))
        )
    with FakeOpenAIServer([GOOD, CONSTANT, retuned]) as server:
        result = _search(run, server, tiny_config(iterations=3, samples=1), quiet)
        requests = server.requests
    assert [h["best_success"] for h in result.history] == [0.6, 0.3, 0.2]
    assert [h["best_so_far"] for h in result.history] == [0.6, 0.6, 0.6]
    assert (result.best["iteration"], result.best["success"]) == (0, 0.6)
    assert (run / "best_reward.py").read_text().strip() == extract_code(GOOD)
    # Iteration 2 is asked to improve iteration 0's reward, not iteration 1's constant one.
    feedback = requests[2]["messages"][-1]["content"]
    assert "temp_reach = 0.15" in feedback and "np.zeros" not in feedback


def test_a_plan_made_by_the_caller_is_used_not_asked_for_again(tmp_path: Path, quiet) -> None:
    # `reward generate --transfer` plans the command to retrieve the network's sources; the
    # search asked the model for the same plan a second time.
    command = "Pick up the M12 nut"
    plan = plan_target(command, search_client(tmp_path / "planner", "offline"))
    run = tmp_path / "run"
    with FakeOpenAIServer([GOOD, CONSTANT]) as server:
        _search(run, server, tiny_config(), quiet, target=command, plan=plan)
        requests = server.requests
    assert len(requests) == 1 and requests[0]["n"] == 2  # the two samples, no plan request
    assert json.loads((run / "plan.json").read_text()) == plan.to_dict()


def test_a_sample_replayed_differently_on_resume_loses_the_old_codes_training(
    tmp_path: Path,
) -> None:
    # A probe that timed out only this time sends the model the error and gets new code; the
    # result of training the old code was read back as the new code's.
    def sample(code: str, error: str | None = None) -> Sample:
        return Sample(0, [Attempt(fenced(code), code, error)])

    good, other = extract_code(GOOD), extract_code(CONSTANT)
    sample_dir = tmp_path / "iter_0" / "sample_0"
    _write_sample(sample_dir, sample(good))
    (sample_dir / "result.json").write_text(json.dumps(_fake_result(0.9, 0.5)))
    (sample_dir / "train" / "seed_0").mkdir(parents=True)

    _write_sample(sample_dir, sample(good))  # replayed the same: the training stands
    assert (sample_dir / "result.json").is_file() and (sample_dir / "train").is_dir()
    _write_sample(sample_dir, sample(other))
    assert (sample_dir / "reward.py").read_text() == other + "\n"
    assert not (sample_dir / "result.json").exists() and not (sample_dir / "train").exists()


def _fake_result(success: float, correlation: float) -> dict:
    return {
        "status": "ok",
        "success": success,
        "final_success": success,
        "correlation": correlation,
        "env_steps": 128,
        "wall_s": 1.0,
        "sha256": "-",
        "stats": {},
    }


def test_the_choice_is_made_on_more_seeds_than_the_search_saw(
    tmp_path: Path, quiet, monkeypatch
) -> None:
    # Sample 0 wins the search on its one seed but fails on the selection seed; sample 1 holds
    # its success there. Finished results written beforehand are used as a resumed run uses
    # them, which fixes the successes without training to them; a new search would refuse a
    # directory holding them, so that check stands aside here.
    monkeypatch.setattr(search, "check_new_run", lambda out: None)
    run = tmp_path / "run"
    planted = {
        "iter_0/sample_0": _fake_result(0.6, 0.9),
        "iter_0/sample_1": _fake_result(0.5, 0.9),
        f"select/{_tagged('reward', extract_code(GOOD))}_seed2": _fake_result(0.1, 0.9),
        f"select/{_tagged('reward', extract_code(CONSTANT))}_seed2": _fake_result(0.5, 0.9),
        # Another reward's result where the chosen one's final run goes: not taken for it.
        "final/generated_seed1": _fake_result(0.99, 0.99),
    }
    for where, result in planted.items():
        (run / where).mkdir(parents=True)
        (run / where / "result.json").write_text(json.dumps(result))
    config = tiny_config(select_top=2, select_seeds=1)
    assert (config.final_seed_list, config.select_seed_list) == ([1], [2])
    with FakeOpenAIServer([GOOD, CONSTANT]) as server:
        result = _search(run, server, config, quiet)
    assert result.history[0]["best_sample"] == 0
    selection = json.loads((run / "summary.json").read_text())["selection"]
    assert [(c["sample"], c["mean"]) for c in selection["candidates"]] == [(0, 0.35), (1, 0.5)]
    assert (result.best["sample"], result.best["selected_success"]) == (1, 0.5)
    assert result.best_code.strip() == extract_code(CONSTANT).strip()
    final_dir = run / "final" / f"{_tagged('generated', result.best_code.strip())}_seed1"
    final = json.loads((final_dir / "result.json").read_text())
    assert final["status"] == "ok"  # the chosen reward, trained for real on the final seed
    assert final["sha256"] == compile_reward(result.best_code.strip(), config.sandbox).sha256


def test_a_worker_failure_stops_the_search_until_a_resume_trains_it_again(
    tmp_path: Path, quiet, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A full disk in sample 1's worker reached the next prompt as the reward's failure (a paid
    # request to mend code with nothing wrong with it), and the finished search never trained
    # that sample again.
    import itskill.reward.search as search_module
    from itskill.executors import JobResult

    real = search_module.run_jobs

    def disk_full_for_sample_1(fn, jobs, *args, **kwargs):
        for res in real(fn, jobs, *args, **kwargs):
            out = Path(jobs[res.index][0].out)
            if out.name == "sample_1":
                (out / "result.json").unlink()  # the worker died before writing it
                res = JobResult(res.index, error=OSError(28, "No space left on device"))
            yield res

    run = tmp_path / "run"
    config = tiny_config(iterations=2, samples=2)
    with FakeOpenAIServer([RAISES_LATER, GOOD, GOOD, GOOD]) as server:
        monkeypatch.setattr(search_module, "run_jobs", disk_full_for_sample_1)
        with pytest.raises(RewardSearchError, match=r"1 job\(s\) failed in their worker.*iter_0/"
                           r"sample_1: OSError.*No space left.*--resume"):  # fmt: skip
            _search(run, server, config, quiet)
        assert len(server.requests) == 1  # the model was not asked again
        assert (run / "iter_0" / "sample_0" / "result.json").is_file()
        assert not (run / "iter_0" / "sample_1" / "result.json").exists()

        monkeypatch.setattr(search_module, "run_jobs", real)
        _search(run, server, config, quiet, resume=True)
        requests = server.requests
    sample_1 = json.loads((run / "iter_0" / "sample_1" / "result.json").read_text())
    assert sample_1["status"] == "ok" and (run / "summary.json").is_file()
    assert all("No space left" not in m["content"] for r in requests for m in r["messages"])


def test_each_paid_request_is_on_record_before_the_next(tmp_path: Path, quiet) -> None:
    # Usage was written once a whole iteration's samples were in: killed with -9 in between, the
    # requests already paid for were replayed from the cache on resume and counted as free.
    run = tmp_path / "run"

    class Watching:
        """The run's client, noting the requests usage.json holds when each request starts."""

        def __init__(self, inner) -> None:
            self.inner, self.on_record = inner, []

        def __getattr__(self, name: str):
            return getattr(self.inner, name)

        def complete(self, messages, n=1, *, purpose, temperature=1.0):
            usage = run / "usage.json"
            recorded = json.loads(usage.read_text())["total"]["requests"] if usage.is_file() else 0
            self.on_record.append(recorded)
            return self.inner.complete(messages, n, purpose=purpose, temperature=temperature)

    with FakeOpenAIServer([SYNTAX_ERROR, GOOD]) as server:
        client = Watching(search_client(run, "openai:fake-model", server.base_url))
        generate_reward("pick_nut_m12", client, run, tiny_config(samples=1),
                        compare_expert=False, console=quiet)  # fmt: skip
    assert client.on_record == [0, 1]  # the regeneration starts with the first request on record
