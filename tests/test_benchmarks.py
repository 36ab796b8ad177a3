"""Every benchmark script still starts: they import the library directly, and a rename there
would otherwise only show when someone next measures something."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from itskill.tasks import get_task

BENCHMARK_DIR = Path(__file__).resolve().parents[1] / "benchmarks"
BENCHMARKS = sorted(BENCHMARK_DIR.glob("*.py"))


@pytest.mark.parametrize("script", BENCHMARKS, ids=lambda p: p.stem)
def test_benchmark_parses_its_arguments(script: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, BENCHMARK_DIR / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pull_jam_tells_a_straight_pull_from_a_sideways_drag() -> None:
    """docs/skills.md explains Remove's hold-still optimum with these two pulls: straight up, a
    freshly grasped peg comes out held; dragged sideways, the fingers lose it in the hole."""
    pull = _load("pull_jam").pull
    straight = pull("remove_peg_rect", 0.0, 1.0, envs=4, seed=0)
    dragged = pull("remove_peg_rect", -1.0, 1.0, envs=4, seed=0)
    assert straight["pulling"] == 1.0 and dragged["pulling"] == 1.0
    assert straight["out_held"] == 1.0 and straight["lost_in_hole"] == 0.0
    assert dragged["out_held"] == 0.0 and dragged["lost_in_hole"] == 1.0


def test_paired_policies_compares_the_two_policies_on_the_same_episodes(tmp_path, capsys) -> None:
    """Two policies with one exception each, at different episodes. Of the first 8
    reach_nut_m12 episodes of seed 10,001 the M16 nut's Reach skill misses only episode 3 (it
    ends 21 mm from the nut, success is within 15) and the round peg's reaches only episode 7
    (5 mm), so paired, the M16 skill wins the 6 others. Measuring one policy twice would find 0;
    another seed for either (neither has an exception on 10,000 or 10,002), 7."""
    from itskill.skills import SHIPPED_LIBRARY

    before, after = SHIPPED_LIBRARY / "reach_peg_round", SHIPPED_LIBRARY / "reach_nut_m16"
    out = tmp_path / "paired.json"
    args = ["reach_nut_m12", str(before), str(after), "--episodes", "8", "--seed", "10001"]
    assert _load("paired_policies").main([*args, "--json", str(out)]) == 0
    assert "after won 6 episodes and lost 0; one-sided exact McNemar p = 0.016" in (
        capsys.readouterr().out
    )
    result = json.loads(out.read_text())
    assert result["before"]["success"] == 1 / 8 and result["after"]["success"] == 7 / 8
    assert (result["episodes_won"], result["episodes_lost"]) == (6, 0)
    assert result["p"] == pytest.approx(0.5**6)
    # Noise of 0.5 on both policies' actions: the round peg's Reach loses its one success and
    # the M16 nut's two of seven, on the same episodes.
    out_noisy = tmp_path / "noisy.json"
    assert _load("paired_policies").main([*args, "--noise", "0.5", "--json", str(out_noisy)]) == 0
    noisy = json.loads(out_noisy.read_text())
    assert "action noise 0.5" in capsys.readouterr().out and noisy["noise"] == 0.5
    assert (noisy["before"]["success"], noisy["after"]["success"]) == (0.0, 5 / 8)


def _curve(seed: int, success: list[float], budget: int = 300) -> dict:
    """A run_one result of learn_basic: evaluations every 100 env-steps, one minute apart."""
    steps = [100 * (k + 1) for k in range(len(success))]
    return {
        "seed": seed,
        "budget": budget,
        "steps": steps,
        "wall_s": [60.0 * (k + 1) for k in range(len(success))],
        "success": success,
    }


def test_learn_basic_counts_a_seed_that_never_reached_a_threshold_at_its_budget() -> None:
    """Seeds 0 and 1 reach 80% at 100 and 200 env-steps; seed 2 never does. Averaging the two
    that did would say 150; counted at its budget (300) seed 2 makes it at least 200. Seed 1's
    90% comes at 400, past its budget of 300 (training ends a rollout late), so it is censored."""
    summarise = _load("learn_basic").summarise
    curves = [
        _curve(2, [0.1, 0.3, 0.5]),
        _curve(0, [0.9, 0.95, 0.9]),
        _curve(1, [0.5, 0.8, 0.85, 0.9]),
    ]
    s = summarise(curves, requested=4)
    assert (s["seeds"], s["seeds_requested"]) == (3, 4)
    to_80 = s["to_80"]
    assert to_80["reached"] == 2 and to_80["lower_bound"] is True
    assert to_80["env_steps_mean_censored"] == pytest.approx(200.0)
    assert to_80["wall_min_mean_censored"] == pytest.approx(2.0)
    assert to_80["per_seed"]["reached"] == [True, True, False]
    assert to_80["env_steps_text"].startswith("≥ 200 [")
    assert to_80["env_steps_text"].endswith("(1/3 never reached)")
    assert to_80["wall_min_text"].startswith("≥ 2.0 [")
    to_90 = s["to_90"]
    assert to_90["reached"] == 1 and to_90["per_seed"]["env_steps"] == [100.0, 300.0, 300.0]
    assert s["final_success"]["seeds"] == [0, 1, 2]
    assert s["final_success"]["per_seed"] == [0.9, 0.9, 0.5]


def test_learn_basic_reports_failed_runs_and_exits_non_zero(tmp_path, monkeypatch, capsys) -> None:
    """One of three seeds fails: the cell is summarised over the two that completed, says so,
    and main returns 1; with every run done it returns 0."""
    from itskill.executors import JobResult

    module = _load("learn_basic")
    fail_seed: list[int] = [1]

    def fake_run_jobs(fn, jobs, executor, workers):
        for index, job in enumerate(jobs):
            seed = job[2]
            if seed in fail_seed:
                yield JobResult(index, error=RuntimeError("simulator crashed"))
            else:
                yield JobResult(index, value=_curve(seed, [0.5, 0.9, 0.9], budget=job[3]))

    monkeypatch.setattr(module, "run_jobs", fake_run_jobs)
    args = ["--algos", "ppo", "--seeds", "0", "1", "2", "--steps", "300", "--out", str(tmp_path)]
    assert module.main(args) == 1
    captured = capsys.readouterr()
    assert "pick_nut_m12 ppo seed 1: FAILED RuntimeError: simulator crashed" in captured.err
    assert "1 of 3 runs failed" in captured.err
    assert "pick_nut_m12 ppo: 2/3 seeds completed" in captured.out
    result = json.loads((tmp_path / "summary.json").read_text())["results"]["pick_nut_m12/ppo"]
    assert (result["seeds"], result["seeds_requested"]) == (2, 3)

    fail_seed.clear()
    assert module.main(args) == 0
    assert "pick_nut_m12 ppo: 3/3 seeds completed" in capsys.readouterr().out
    # Every run failed: the summary of the runs that measured something stays.
    kept = (tmp_path / "summary.json").read_text()
    fail_seed.extend([0, 1, 2])
    assert module.main(args) == 1
    assert "no run completed" in capsys.readouterr().err
    assert (tmp_path / "summary.json").read_text() == kept


def test_reward_search_reports_the_best_and_the_last_evaluation() -> None:
    """The search's per-seed "success" is each run's best evaluation, "final_success" its last:
    the two columns must not be confused."""
    interval = _load("reward_search")._interval
    band = {"success": [0.8, 0.8, 0.8], "final_success": [0.4, 0.5, 0.6], "mean": 0.8}
    assert interval(band, "success") == "80% (all 3 seeds)"  # not a zero-width interval
    assert interval(band, "final_success").startswith("50% [")
    assert interval(None, "final_success") == "-"
    assert interval({"success": [], "final_success": []}, "success") == "-"


def _fake_reward_at_budget(monkeypatch, out: Path, finals: dict, heldout: list[float]):
    """reward_at_budget with training and held-out evaluation replaced by hand-made curves
    (final success ``finals[reward, seed]``) and held-out rates, in the order evaluated."""
    from types import SimpleNamespace

    from itskill.executors import JobResult

    module = _load("reward_at_budget")
    for (reward, seed), final in finals.items():
        run_dir = out / f"{reward}_seed{seed}"
        run_dir.mkdir(parents=True)
        (run_dir / "eval.csv").write_text(
            f"env_steps,wall_s,success\n100,10.0,0.2\n200,20.0,{final}\n"
        )

    def fake_run_jobs(fn, jobs, workers):
        yield from (JobResult(k, value=job[3]) for k, job in enumerate(jobs))

    rates = iter(heldout)
    monkeypatch.setattr(module, "run_jobs", fake_run_jobs)
    monkeypatch.setattr(module, "as_policy", lambda path: None)
    monkeypatch.setattr(
        module,
        "evaluate",
        lambda *a, **k: SimpleNamespace(
            success_rate=(rate := next(rates)),
            stage_steps=[1.0],
            to_dict=lambda: {"success_rate": rate, "stage_steps": [1.0]},
        ),
    )
    return module


def test_reward_at_budget_prints_the_final_and_held_out_means(
    tmp_path, monkeypatch, capsys
) -> None:
    """The final training evaluation's mean is printed beside the held-out one, and each run's
    eval.csv is kept whole."""
    out, results = tmp_path / "runs", tmp_path / "results"
    finals = {("generated", 1): 0.6, ("generated", 2): 0.8, ("expert", 1): 0.4, ("expert", 2): 0.4}
    module = _fake_reward_at_budget(monkeypatch, out, finals, [0.5, 0.7, 0.3, 0.3])
    reward = tmp_path / "reward.py"
    reward.write_text("")
    argv = ["--reward", str(reward), "--seeds", "1", "2", "--steps", "200"]
    assert module.main([*argv, "--out", str(out), "--results", str(results)]) == 0
    printed = capsys.readouterr().out
    assert "generated: final 60%, 80%, mean 70% [" in printed
    assert "held-out 50%, 70%, mean 60% [" in printed
    # Seeds that agree say so, not a zero-width "interval".
    assert (
        "expert: final 40%, 40%, mean 40% (all 2 seeds); held-out 30%, 30%, mean 30% (all 2 "
        "seeds)" in printed
    )
    kept = results / "generated" / "seed_2" / "eval.csv"
    assert kept.read_bytes() == (out / "generated_seed2" / "eval.csv").read_bytes()
    assert [p.name for p in kept.parent.iterdir() if p.name.startswith(".")] == []


def test_reward_at_budget_pools_seeds_added_later(tmp_path, monkeypatch, capsys) -> None:
    """Seeds run in a later call join the earlier call's in one summary, from the files it kept
    in --results (its run directories may be gone); a summary of other settings is refused."""
    results, reward = tmp_path / "results", tmp_path / "reward.py"
    reward.write_text("")
    argv = ["--reward", str(reward), "--steps", "200", "--results", str(results)]
    first = {("generated", 1): 0.6, ("expert", 1): 0.4}
    module = _fake_reward_at_budget(monkeypatch, tmp_path / "a", first, [0.5, 0.3])
    assert module.main([*argv, "--seeds", "1", "--out", str(tmp_path / "a")]) == 0
    second = {("generated", 2): 0.8, ("expert", 2): 0.2}
    module = _fake_reward_at_budget(monkeypatch, tmp_path / "b", second, [0.7, 0.1])
    later = [*argv, "--seeds", "2", "--out", str(tmp_path / "b"), "--with-earlier"]
    capsys.readouterr()
    assert module.main(later) == 0
    printed = capsys.readouterr().out
    assert "generated: final 60%, 80%, mean 70% [" in printed and "held-out 50%, 70%" in printed
    assert "expert: final 40%, 20%, mean 30% [" in printed and "held-out 30%, 10%" in printed
    summary = json.loads((results / "summary.json").read_text())
    assert summary["rewards"]["generated"]["seeds"] == [1, 2]
    assert summary["earlier_seeds"] == [1]
    with pytest.raises(SystemExit, match="other settings \\(steps\\)"):
        module.main([*later[:3], "300", *later[4:]])
    # The reward rewritten in place (a search's best_reward.py) is another reward.
    reward.write_text("# another search's choice\n")
    with pytest.raises(SystemExit, match="other settings \\(reward_sha256\\)"):
        module.main(later)


def test_reward_at_budget_does_not_pool_seeds_a_replaced_summary_left(
    tmp_path, monkeypatch, capsys
) -> None:
    # A call without --with-earlier replaced the summary; its predecessor's seed folders stayed
    # in --results and a later --with-earlier pooled them, whatever their settings.
    results, reward = tmp_path / "results", tmp_path / "reward.py"
    reward.write_text("")
    argv = ["--reward", str(reward), "--results", str(results)]
    module = _fake_reward_at_budget(monkeypatch, tmp_path / "a", {("generated", 1): 0.6,
                                    ("expert", 1): 0.4}, [0.5, 0.3])  # fmt: skip
    assert module.main([*argv, "--steps", "300", "--seeds", "1", "--out", str(tmp_path / "a")]) == 0
    module = _fake_reward_at_budget(monkeypatch, tmp_path / "b", {("generated", 2): 0.8,
                                    ("expert", 2): 0.2}, [0.7, 0.1])  # fmt: skip
    assert module.main([*argv, "--steps", "200", "--seeds", "2", "--out", str(tmp_path / "b")]) == 0
    module = _fake_reward_at_budget(monkeypatch, tmp_path / "c", {("generated", 3): 0.8,
                                    ("expert", 3): 0.2}, [0.7, 0.1])  # fmt: skip
    later = [*argv, "--steps", "200", "--seeds", "3", "--out", str(tmp_path / "c")]
    assert module.main([*later, "--with-earlier"]) == 0
    summary = json.loads((results / "summary.json").read_text())
    assert summary["earlier_seeds"] == [2]  # not seed 1, trained for 300 env-steps
    assert summary["rewards"]["generated"]["seeds"] == [2, 3]


def test_library_success_refuses_to_write_figures_of_other_episodes(tmp_path, capsys) -> None:
    """The manifest's success is the 400 held-out episodes of seed 10,000: a figure measured on
    others must not replace it silently."""
    # A library that is not there: a check that let the update through fails differently, and
    # never touches the shipped manifest.
    library = tmp_path / "library"
    main = _load("library_success").main
    for extra in (["--episodes", "50", "--seed", "0"], ["--seed", "0"]):
        with pytest.raises(SystemExit) as stop:
            main(["--update", "--library", str(library), *extra])
        assert stop.value.code == 2
        assert "--update writes the manifest's success" in capsys.readouterr().err
    assert not library.exists()


@pytest.mark.parametrize(
    "argv", [["--contact", "--task", "screw_nut_m12"], ["--contact", "--policy", "x"]]
)
def test_thread_turns_refuses_a_contact_measurement_it_cannot_make(argv, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        _load("thread_turns").main(argv)
    assert stop.value.code == 2 and "error:" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("script", "extra"),
    [
        ("learn_basic", ["--algos", "ppo", "a2c"]),
        ("best_policy", ["--task", "pickplace_nut_m12"]),
        ("reward_at_budget", ["--reward", __file__, "--results", "unused"]),
    ],
)
def test_training_benchmarks_refuse_a_bad_hyperparameter_file_before_training(
    script, extra, tmp_path, monkeypatch, capsys
) -> None:
    bad = tmp_path / "hp.toml"
    bad.write_text('[nutbolt]\nnum_envs = "many"\n')
    module = _load(script)
    trained = []
    # Every script trains through run_jobs (in spawned workers, which a patch of the training
    # function itself would not reach).
    monkeypatch.setattr(module, "run_jobs", lambda *a, **k: trained.append(a) or iter(()))
    with pytest.raises(SystemExit) as stop:
        module.main([*extra, "--hyperparams", str(bad), "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "nutbolt.num_envs: expected an integer" in err, err
    assert not trained and not (tmp_path / "runs").exists()


def test_source_chaining_with_action_noise_measures_a_fragile_skill(tmp_path, capsys) -> None:
    """The shipped insert of the rectangular peg, a clone of its script, inserts without noise
    and not at the exploration noise of log-std -0.5 (its transfer target's until 2026-12-06);
    the record says which noise it was measured at."""
    chaining = _load("source_chaining")
    args = ["insert_peg_rect", "--chain", "insert_peg_rect", "--episodes", "8"]
    out = tmp_path / "chain.json"
    assert chaining.main(args) == 0
    assert "success 100%" in capsys.readouterr().out
    assert chaining.main([*args, "--noise", "0.61", "--json", str(out)]) == 0
    assert "action noise 0.61)\nsuccess 0%" in capsys.readouterr().out
    record = json.loads(out.read_text())
    assert record["noise"] == 0.61 and record["success_rate"] == 0.0


def test_source_chaining_shows_the_skills_the_targets_stage_as_the_transfer_network_does(
    monkeypatch,
) -> None:
    # --target-stage showed each skill the target's raw stage index (the place skill of a
    # pick-and-place saw stages 3 and 4, which its task does not have); the transfer network
    # shows a source the target's stage mapped onto its own by their names.
    chaining = _load("source_chaining")
    spec = get_task("pickplace_nut_m12")
    chain = chaining.StageChain(spec, ["pick_nut_m12"] * 3 + ["place_nut_m12"] * 2, False)
    seen = {}

    def recorder(name):
        def act(view):
            seen[name] = view["stage"].copy()
            return np.zeros((len(view["stage"]), 5))

        return act

    chain.actors = [recorder(name) for name in chain.names]
    chain({"stage": np.arange(len(spec.stages))})
    assert seen["pick_nut_m12"].tolist() == [0, 1, 2, 2, 2]
    assert seen["place_nut_m12"].tolist() == [0, 0, 0, 0, 1]


class _GripPolicy:
    """Holds the arm still with the fingers commanded open (``grip < 0``) or closed."""

    def __init__(self, grip: float) -> None:
        self.grip = grip

    def reset(self, env_ids=None) -> None:
        pass

    def __call__(self, ctx):
        actions = np.zeros((len(ctx["stage"]), 5))
        actions[:, 4] = self.grip
        return actions


def test_handover_trace_says_where_failed_episodes_lost_their_part() -> None:
    """carry_nut_m12 starts with the nut in the closed fingers: opening them lets it go in the
    first stage in every (failed) episode; keeping them closed and not moving loses nothing."""
    chaining = _load("source_chaining")
    spec = get_task("carry_nut_m12")
    trace = chaining.trace_handovers(spec, _GripPolicy(-1.0), episodes=4, seed=0)
    assert (trace["episodes"], trace["successes"]) == (4, 0)
    (opened,) = trace["stages"]
    assert (opened["let_go"], opened["slipped"]) == (4, 0)
    # Let go where the episode started: the grip point still about the nut's height above it.
    assert abs(opened["let_go_obj_to_ee_mean"][2]) < 0.02
    (kept,) = chaining.trace_handovers(spec, _GripPolicy(1.0), episodes=4, seed=0)["stages"]
    assert (kept["let_go"], kept["slipped"], kept["reached"]) == (0, 0, 4)


class _ScriptedEnv:
    """Stands in for a batch of environments: each one's grasp, grip command and stage follow a
    script, one entry per state, the last the state its episode ends in."""

    def __init__(self, scripts: list[list[tuple[bool, bool, int]]], successes: list[bool]):
        from itskill.sim.layout import OBSERVATION_LAYOUT

        self.layout, self.scripts, self.successes, self.t = (
            OBSERVATION_LAYOUT,
            scripts,
            successes,
            0,
        )

    def reset(self):
        self.t = 0

    def close(self):
        pass

    def _state(self, t: int):
        rows = [script[t] for script in self.scripts]
        return (np.array([r[0] for r in rows], float), np.array([r[1] for r in rows], float),
                np.array([r[2] for r in rows]))  # fmt: skip

    def context(self):
        grasped, closed, stage = self._state(self.t)
        n = len(self.scripts)
        offsets = np.tile(np.arange(n, dtype=float)[:, None, None], (1, 2, 3)) / 1000
        return {"grasped": np.stack([grasped, grasped], 1), "grip_closed": closed,
                "stage": stage, "obj_to_ee": offsets, "obj_to_fix": offsets}  # fmt: skip

    def step(self, actions):
        self.t += 1
        n, last = len(self.scripts), self.t == len(self.scripts[0]) - 1
        infos = [{} for _ in range(n)]
        if last:
            grasped, closed, stage = self._state(self.t)
            for e in range(n):
                obs = np.zeros(self.layout.size)
                obs[self.layout["obj0_grasped"]] = grasped[e]
                obs[self.layout["grip_closed"]] = closed[e]
                obs[self.layout["obj0_to_ee"]] = e / 1000
                obs[self.layout["obj0_to_fix"]] = e / 1000
                infos[e] = {"stages_done": int(stage[e]), "is_success": self.successes[e],
                            "terminal_observation": obs}  # fmt: skip
        return None, None, np.full(n, last), infos


def test_handover_trace_counts_where_a_failed_episode_last_lost_its_part(monkeypatch) -> None:
    held, slip, opened = (True, True, 0), (False, True, 0), (False, False, 0)
    scripts = [
        [held, held, held, held],  # fails holding the part
        [held, slip, held, opened],  # dropped, grasped again, let go on its last step
        [held, opened, opened, opened],  # succeeds: letting go at its goal is not a loss
        [opened, opened, opened, opened],  # fails, never held
        [held, held, (False, True, 1), (False, True, 1)],  # slips in stage 1, never regained
    ]
    chaining = _load("source_chaining")
    fake = _ScriptedEnv(scripts, [False, False, True, False, False])
    monkeypatch.setattr(chaining, "make_batch_env", lambda *a, **k: fake)
    trace = chaining.trace_handovers(
        get_task("pickplace_nut_m12"), _GripPolicy(1.0), episodes=5, seed=0
    )
    assert (trace["successes"], trace["failed_held"], trace["failed_never_held"]) == (1, 1, 1)
    first, second = trace["stages"][:2]
    assert (first["let_go"], first["slipped"], second["slipped"]) == (1, 0, 1)
    # Each loss with the offsets of its own moment: the last step's, read from the episode's end.
    assert first["let_go_obj_to_ee_mean"] == [0.001] * 3
    assert second["slipped_obj_to_fix_mean"] == [0.004] * 3


def test_learn_basic_learns_a_task_that_clones_its_script_from_scratch_with_demos_0(
    tmp_path,
) -> None:
    # place_nut_m12's packaged hyper-parameters clone 500 scripted episodes first: without
    # --demos 0 the benchmark would time that warm start, not learning from scratch.
    module = _load("learn_basic")
    module.run_one("place_nut_m12", "ppo", 0, 256, 256, 2, str(tmp_path), "expert", None, 0)
    run = tmp_path / "runs" / "place_nut_m12" / "ppo" / "seed0"
    assert (run / "checkpoint.json").is_file() and not (run / "demos.json").exists()


def test_a_trial_search_does_not_replace_the_results_of_a_full_one(
    tmp_path, monkeypatch, capsys
) -> None:
    # The docstring's quick example, run with the defaults, replaced the committed full search's
    # summary, figure and best_reward.py (the reward reward_at_budget reads).
    results = tmp_path / "results"
    shutil.copytree(
        BENCHMARK_DIR.parent / "results/reward_search/pick_nut_m12", results / "pick_nut_m12"
    )
    module = _load("reward_search")
    monkeypatch.setattr(module, "generate_reward", lambda *a, **k: pytest.fail("it searched"))
    argv = ["reward_search.py", "--tasks", "pick_nut_m12", "--iterations", "1", "--samples", "2"]
    monkeypatch.setattr(sys, "argv", [*argv, "--results", str(results), "--runs", str(tmp_path)])
    with pytest.raises(SystemExit) as stop:
        module.main()
    assert stop.value.code == 2
    assert "holds the results of a 5 x 10 search, this one is 1 x 2" in capsys.readouterr().err
