"""train_transfer: every method trains, the run directory evaluates, resumes and traces W."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from transfer_helpers import make_source
from typer.testing import CliRunner

from itskill.cli import app
from itskill.llm.client import make_client
from itskill.rl.checkpoint import CheckpointError, as_policy, load_policy, read_meta
from itskill.rl.config import HyperparamError
from itskill.rl.logger import LoggerConfig
from itskill.rl.policy import StagedActorCriticPolicy
from itskill.rl.train import ResumeMismatchError, train
from itskill.skills import open_skill_space
from itskill.tasks import get_task
from itskill.tasks.evaluate import evaluate
from itskill.transfer import (
    METHODS,
    DFSPolicy,
    ITNPolicy,
    NIAPolicy,
    TransferConfig,
    attention_trace,
    read_transfer,
    recorded_attention_trace,
    train_transfer,
)
from itskill.transfer.sources import IncompatibleSourceError

TARGET = "pickplace_nut_m12"
SOURCES = "pick_nut_m12,place_nut_m12"
QUIET = LoggerConfig(progress=False, tensorboard=False)


class CountingClient:
    """The offline analyzer, counting how often it is asked."""

    def __init__(self) -> None:
        self.inner, self.calls = make_client("offline"), 0
        self.name, self.offline = self.inner.name, True

    def complete(self, messages, n=1, *, purpose, temperature=1.0):
        self.calls += 1
        return self.inner.complete(messages, n, purpose=purpose, temperature=temperature)


def run(out: Path, method: str, steps: int = 16, client=None, **kw):
    return train_transfer(
        TARGET, method, SOURCES, seed=0, steps=steps, algo="a2c", out=out, num_envs=2,
        client=client or CountingClient(), logger=QUIET, **kw,
    )  # fmt: skip


EXPECTED = {
    "itn": (ITNPolicy, ["pick_nut_m12", "place_nut_m12"], 1),
    "nia": (NIAPolicy, ["pick_nut_m12", "place_nut_m12"], 1),
    "dfs": (DFSPolicy, ["pick_nut_m12", "place_nut_m12"], None),
    # One source takes every stage: the analyzer is not asked (an answer of 0 for a stage the
    # pick cannot do was refused, failing the run).
    "pst": (ITNPolicy, ["pick_nut_m12"], 0),
    "no_transfer": (StagedActorCriticPolicy, [], None),
}
"""Each method's network, sources, and how often it asks the analyzer (None: it has no matrix)."""


def test_every_method_is_listed() -> None:
    assert set(METHODS) == set(EXPECTED)


@pytest.mark.parametrize("method", list(EXPECTED))
def test_each_method_builds_and_trains_one_update(home: Path, tmp_path: Path, method: str) -> None:
    cls, sources, analyzed = EXPECTED[method]
    client = CountingClient()
    result = run(tmp_path / method, method, client=client)
    assert result.num_timesteps == 16  # A2C: n_steps 8 x 2 environments, one update
    policy = load_policy(tmp_path / method)
    assert type(policy) is cls
    record = read_transfer(tmp_path / method)
    assert record["method"] == method and record["target"] == TARGET
    assert [s["name"] for s in record["sources"]] == sources
    assert client.calls == (analyzed or 0)
    if analyzed is not None:
        matrix = np.asarray(record["contribution"]["matrix"])
        assert matrix.shape == (5, len(sources))
        np.testing.assert_allclose(policy.config.prior, matrix)
    else:
        assert record["contribution"] is None
    meta = read_meta(tmp_path / method)
    assert meta["policy_class"] == f"{cls.__module__}.{cls.__qualname__}"


def test_sources_see_their_own_stages_and_the_residual_knows_its_performers(
    home: Path, tmp_path: Path
) -> None:
    run(tmp_path / "itn", "itn")
    record = read_transfer(tmp_path / "itn")
    # pick does stages 0-2 of approach, grasp, lift, approach, place; place does 3-4.
    assert [s["stage_map"] for s in record["source_specs"]] == [[0, 1, 2, 2, 2], [0, 0, 0, 0, 1]]
    assert record["performers"] == [0, 0, 0, 1, 1]
    assert load_policy(tmp_path / "itn").config.performers == (0, 0, 0, 1, 1)

    run(tmp_path / "plain", "itn", config=TransferConfig(residual=False))
    assert read_transfer(tmp_path / "plain")["performers"] is None
    assert load_policy(tmp_path / "plain").config.performers is None


def test_an_untrained_network_with_the_residual_acts_like_its_sources(
    home: Path, tmp_path: Path
) -> None:
    # Trained with a negligible learning rate, the network is as built: the head adds almost
    # nothing to the shipped pick (stages 0-2) and place (3-4) skills, which chained by hand
    # succeed in about a quarter of the episodes; a network without the residual never does.
    out = tmp_path / "itn"
    run(out, "itn", overrides={"learning_rate": 1e-12})
    res = evaluate(get_task(TARGET), as_policy(out), episodes=20, seed=10_000, num_envs=4)
    assert res.success_rate >= 0.1
    assert res.mean_stages_done >= 2.0


def test_resume_continues_without_asking_the_analyzer_again(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "itn"
    first = run(out, "itn", steps=16)
    before = (out / "transfer.json").read_text()
    client = CountingClient()
    second = run(out, "itn", steps=48, client=client)
    assert second.resumed_from == first.num_timesteps == 16
    assert second.num_timesteps == 48
    assert client.calls == 0 and (out / "transfer.json").read_text() == before
    with pytest.raises(ResumeMismatchError, match=r"method='itn'.*method='nia'"):
        run(out, "nia", steps=64)
    with pytest.raises(ResumeMismatchError, match="sources_request"):
        train_transfer(TARGET, "itn", "pick_nut_m12", steps=64, algo="a2c", out=out, num_envs=2,
                       logger=QUIET)  # fmt: skip
    # The same skills written another way, and other analyzer retries (the record keeps its
    # matrix), are the same run.
    again = train_transfer(
        TARGET, "itn", [" pick_nut_m12", "place_nut_m12"], seed=0, steps=64, algo="a2c", out=out,
        num_envs=2, client=client, logger=QUIET, config=TransferConfig(analyzer_retries=5),
    )  # fmt: skip
    assert again.resumed_from == 48 and client.calls == 0
    # So are the skills by their serial numbers (refused as another run before).
    ids = ",".join(str(s["id"]) for s in read_transfer(out)["sources"])
    by_id = train_transfer(TARGET, "itn", ids, seed=0, steps=80, algo="a2c", out=out, num_envs=2,
                           client=client, logger=QUIET)  # fmt: skip
    assert by_id.resumed_from == 64
    # A run recorded before retrieval had a success threshold resumes: it keeps its sources.
    record = read_transfer(out)
    del record["config"]["min_success"]
    (out / "transfer.json").write_text(json.dumps(record))
    assert run(out, "itn", steps=96).resumed_from == 80


def test_a_run_from_before_the_residual_resumes_without_it(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "itn"
    run(out, "itn", config=TransferConfig(residual=False), steps=16)
    record = read_transfer(out)
    del record["config"]["residual"], record["performers"]  # as written by older releases
    for spec in record["source_specs"]:
        del spec["stage_map"]
    (out / "transfer.json").write_text(json.dumps(record))
    with pytest.raises(ResumeMismatchError, match=r"config\.residual=False"):
        run(out, "itn", steps=32)
    resumed = run(out, "itn", config=TransferConfig(residual=False), steps=32)
    assert resumed.resumed_from == 16 and resumed.num_timesteps == 32
    assert load_policy(out).config.performers is None


def test_the_kept_best_policy_describes_itself_like_its_run(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "itn"
    result = run(out, "itn", steps=16, eval_every=8, eval_episodes=2)
    # The sources' chain at the start (step 0) may be the best of the evaluations.
    assert result.best is not None and result.best["env_steps"] in (0, 8, 16)
    assert read_transfer(out / "best") == read_transfer(out)
    trace = attention_trace(out / "best")
    assert trace["method"] == "itn" and trace["sources"] == ["pick_nut_m12", "place_nut_m12"]


def test_run_dir_evaluates_and_traces_attention(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "itn"
    run(out, "itn")
    res = CliRunner().invoke(
        app, ["eval", TARGET, "--policy", str(out), "--episodes", "2", "--num-envs", "2", "--json"]
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["episodes"] == 2

    trace = attention_trace(out)
    assert trace["sources"] == ["pick_nut_m12", "place_nut_m12"]
    assert trace["segments"] == ["approach", "grasp", "lift", "approach", "place"]
    assert trace["method"] == "itn"
    (episode,) = trace["episodes"]
    assert episode["length"] == len(episode["stage"]) == len(episode["weights"]) == 100
    weights, raw = np.asarray(episode["weights"]), np.asarray(episode["raw"])
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-5)
    prior = np.asarray(read_transfer(out)["contribution"]["matrix"])
    np.testing.assert_allclose(weights - 0.5 * raw, 0.5 * prior[episode["stage"]], atol=1e-5)

    run(tmp_path / "dfs", "dfs")
    with pytest.raises(ValueError, match="no contribution weights"):
        attention_trace(tmp_path / "dfs")


def test_the_recorded_trace_outlives_the_weights_and_follows_their_changes(
    home: Path, tmp_path: Path
) -> None:
    out = tmp_path / "itn"
    run(out, "itn")
    first = recorded_attention_trace(out)
    assert first == json.loads(json.dumps(attention_trace(out)))
    assert (out / "attention.json").is_file()

    copy = tmp_path / "results"
    copy.mkdir()
    for name in ("checkpoint.json", "attention.json"):
        (copy / name).write_bytes((out / name).read_bytes())
    assert recorded_attention_trace(copy) == first  # no weights: the record is the figure's source
    # A damaged record is not the figure's source: traced again where the weights are (it was
    # returned as it was, and the report failed on its first index).
    episode = first["episodes"][0]
    damaged_episodes = (
        [],
        [{**episode, "weights": None}],
        [{**episode, "weights": [row[:1] for row in episode["weights"]]}],  # one source short
        [{**episode, "stage": ["pick"] * len(episode["stage"])}],
    )
    for episodes in damaged_episodes:
        damaged = {**json.loads((out / "attention.json").read_text())}
        damaged["trace"] = {**damaged["trace"], "episodes": episodes}
        (out / "attention.json").write_text(json.dumps(damaged))
        assert recorded_attention_trace(out) == first

    marked = json.loads((out / "attention.json").read_text())
    marked["trace"]["episodes"][0]["length"] = -1
    (out / "attention.json").write_text(json.dumps(marked))
    assert recorded_attention_trace(out)["episodes"][0]["length"] == -1  # same weights: reused
    run(out, "itn", steps=32)  # resumed: new weights, so the record no longer describes them
    assert recorded_attention_trace(out)["episodes"][0]["length"] == 100


def test_the_reward_search_network_is_the_one_the_run_then_trains(home: Path, tmp_path: Path):
    from itskill.transfer import search_network

    client = CountingClient()
    out = tmp_path / "transfer"
    network = search_network(TARGET, "itn", out, SOURCES, algo="a2c", client=client)
    assert network is not None and network.policy_class is ITNPolicy
    assert network.label == "itn over pick_nut_m12, place_nut_m12"
    assert [s["name"] for s in network.policy_kwargs["sources"]] == [
        "pick_nut_m12",
        "place_nut_m12",
    ]
    assert network.policy_kwargs["prior"] == read_transfer(out)["contribution"]["matrix"]
    run(out, "itn", client=client)  # the run finds the record: the analyzer is not asked again
    assert client.calls == 1 and type(load_policy(out)) is ITNPolicy
    assert search_network(TARGET, "no_transfer", tmp_path / "scratch", client=client) is None
    with pytest.raises(ResumeMismatchError, match="method="):
        search_network(TARGET, "dfs", out, SOURCES, algo="a2c", client=client)


def _files(directory: Path) -> dict[str, bytes]:
    return {
        str(f.relative_to(directory)): f.read_bytes() for f in directory.rglob("*") if f.is_file()
    }


def test_a_refused_run_leaves_its_directory_as_it_was(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    # A plain training run of another task: the transfer run is refused, and must not leave a
    # transfer.json claiming the directory for its own task, which would refuse the next command.
    plain = tmp_path / "plain"
    train("reach_nut_m12", "a2c", 16, seed=0, out=plain, num_envs=2, logger=QUIET)
    before = _files(plain)
    with pytest.raises(ResumeMismatchError, match="task='reach_nut_m12'"):
        train_transfer("pick_nut_m12", "no_transfer", steps=16, out=plain, num_envs=2, logger=QUIET)
    assert _files(plain) == before

    fresh = tmp_path / "fresh"
    with pytest.raises(ValueError, match="seed must be between 0 and"):
        train_transfer("pick_nut_m12", "no_transfer", seed=-1, steps=16, out=fresh, num_envs=2,
                       logger=QUIET)  # fmt: skip
    assert not fresh.exists()
    result = train_transfer("pick_nut_m12", "no_transfer", steps=16, algo="a2c", out=fresh,
                            num_envs=2, logger=QUIET)  # fmt: skip
    assert result.num_timesteps == 16 and read_transfer(fresh)["target"] == "pick_nut_m12"


def _read_back(run_dir: Path, record: dict) -> dict:
    (run_dir / "transfer.json").write_text(json.dumps(record))
    return read_transfer(run_dir)


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda r: r.pop("method"), "missing field(s) method"),
        (lambda r: r.update(sources=["pick_nut_m12"]), "sources: expected a list of objects"),
        (lambda r: r.update(contribution=[[1.0]]), "contribution: expected an object"),
        (lambda r: r.update(source_specs=None), "source_specs: expected a list of objects"),
        (lambda r: r["source_specs"][0].pop("policy"), "source_specs: expected a list of "),
        (lambda r: r.update(sources_request=5), 'sources_request: expected "auto", a list'),
        (lambda r: r.update(method="itn "), "method: expected one of itn, nia"),
        (lambda r: r.update(method=["itn"]), "method: expected one of itn, nia"),  # a TypeError
        (lambda r: r["source_specs"][0]["policy"].update(stages=[]), "source_specs: expected"),
        (lambda r: r.update(format=2), "transfer record format 2, this version reads 1"),
    ],
)
def test_a_record_with_a_field_its_readers_cannot_use_is_refused(
    tmp_path: Path, edit, problem: str
) -> None:
    # Each was a KeyError or TypeError wherever the field was first used.
    spec = {
        "name": "pick",
        "policy_class": "itskill.rl.policy.StagedActorCriticPolicy",
        "policy": {"stages": [8, 8, 8]},
    }
    record = {"target": TARGET, "method": "itn", "config": {}, "sources_request": "auto",
              "sources": [{"name": "pick"}], "source_specs": [spec],
              "contribution": None}  # fmt: skip
    assert _read_back(tmp_path, record) == record
    edit(record)
    message = f"{tmp_path / 'transfer.json'}: {problem}"
    with pytest.raises(CheckpointError, match=re.escape(message)):
        _read_back(tmp_path, record)


@pytest.mark.parametrize(
    ("method", "stages", "problem"),
    [
        ("itn", (8, 8), "has 2 stages, the target 3"),
        ("dfs", (8, 8, 8), "needs every source stage as wide as the target's"),
    ],
)
def test_a_source_that_cannot_join_the_network_is_refused_before_anything_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, method: str, stages: tuple, problem: str
) -> None:
    # The record was written (and the analyzer asked) before the network refused the source,
    # and that record then refused the corrected command.
    from itskill.skills import Skill, SkillSpace

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    make_source(tmp_path / "odd", seed=0, stages=stages)
    make_source(tmp_path / "pick", seed=1, stages=(256, 256, 128))
    with SkillSpace() as space:
        weights = "policy.safetensors"
        space.add(Skill("odd", "place_nut_m12", "Place the nut", ("approach", "place"),
                        str(tmp_path / "odd" / weights)))  # fmt: skip
        space.add(Skill("pick", "pick_nut_m12", "Pick up the nut", ("approach", "grasp", "lift"),
                        str(tmp_path / "pick" / weights)))  # fmt: skip
    client, out = CountingClient(), tmp_path / "run"
    with pytest.raises(IncompatibleSourceError, match=problem):
        train_transfer(TARGET, method, "pick,odd", steps=16, algo="a2c", out=out, num_envs=2,
                       client=client, logger=QUIET)  # fmt: skip
    assert client.calls == 0 and not (out / "transfer.json").exists()
    result = train_transfer(TARGET, method, "pick", steps=16, algo="a2c", out=out, num_envs=2,
                            client=client, logger=QUIET)  # fmt: skip
    assert result.num_timesteps == 16


def test_a_checkpoint_without_its_transfer_record_is_not_resumed_with_other_sources(
    home: Path, tmp_path: Path
) -> None:
    # It resumed with whatever sources the call named, and recorded them for the old network.
    out = tmp_path / "run"
    run(out, "itn")
    (out / "transfer.json").unlink()
    with pytest.raises(CheckpointError, match=r"transfer\.json: missing: the run's sources"):
        train_transfer(TARGET, "itn", "grasp_nut_m12,lift_nut_m12", seed=0, steps=32, algo="a2c",
                       out=out, num_envs=2, client=CountingClient(), logger=QUIET)  # fmt: skip
    assert not (out / "transfer.json").exists()


def test_a_resume_with_another_setting_names_the_setting(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    run(out, "itn")
    changed = TransferConfig(prior_weight=0.9)
    with pytest.raises(
        ResumeMismatchError, match=r"config\.prior_weight=0\.5.*config\.prior_weight=0\.9"
    ):
        run(out, "itn", steps=32, config=changed)


@pytest.mark.parametrize(
    ("method", "changed"),
    [
        # Each was refused as another run: the setting plays no part in the method's network.
        ("no_transfer", TransferConfig(k=5, pst_keep=2, prior_weight=0.9)),
        ("itn", TransferConfig(k=5, pst_keep=2)),  # sources named, not retrieved
        # Neither has attention; DFS has no fusion either: the loaded network is the same.
        ("dfs", TransferConfig(prior_weight=0.3, attention_hidden=16, fusion_hidden=(64,))),
        ("nia", TransferConfig(prior_weight=0.3, attention_hidden=16)),
    ],
)
def test_a_resume_ignores_the_settings_its_method_does_not_use(
    home: Path, tmp_path: Path, method: str, changed: TransferConfig
) -> None:
    out = tmp_path / "run"
    run(out, method)
    assert run(out, method, steps=32, config=changed).resumed_from == 16


def test_a_resume_of_pst_compares_what_pst_keeps(home: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    run(out, "pst")
    with pytest.raises(ResumeMismatchError, match=r"config\.pst_keep=1.*config\.pst_keep=2"):
        run(out, "pst", steps=32, config=TransferConfig(pst_keep=2))


def test_pst_resumes_with_its_sources_named_by_serial_number_or_by_name(
    home: Path, tmp_path: Path
) -> None:
    # PST keeps the pick of the two asked for; the place it dropped is the same skill however
    # it is named, so each way of writing the list resumes the other's run.
    with open_skill_space() as space:
        ids = ",".join(str(space.get(name).id) for name in SOURCES.split(","))
    for first, then in ((SOURCES, ids), (ids, SOURCES)):
        out = tmp_path / f"from_{first}"
        train_transfer(TARGET, "pst", first, seed=0, steps=16, algo="a2c", out=out, num_envs=2,
                       logger=QUIET)  # fmt: skip
        again = train_transfer(TARGET, "pst", then, seed=0, steps=32, algo="a2c", out=out,
                               num_envs=2, logger=QUIET)  # fmt: skip
        assert again.resumed_from == 16
        assert [s["name"] for s in read_transfer(out)["sources"]] == ["pick_nut_m12"]


def test_a_run_that_trained_nothing_yet_names_a_source_retrained_since_its_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Its network was built with the retrained source's shape and no weights, and every attempt
    # (the run, each of the reward search's candidates) failed at the first step, a traceback.
    from itskill.skills import Skill, SkillSpace
    from itskill.transfer import search_network
    from itskill.transfer.sources import SourceError

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    skill_dir = tmp_path / "pick"
    make_source(skill_dir, seed=1, stages=(256, 256, 128))
    with SkillSpace() as space:
        space.add(Skill("pick", "pick_nut_m12", "Pick up the nut", ("approach", "grasp", "lift"),
                        str(skill_dir / "policy.safetensors")))  # fmt: skip
    client, fresh, trained = CountingClient(), tmp_path / "fresh", tmp_path / "trained"

    def train_on(out: Path, steps: int):
        return train_transfer(TARGET, "itn", "pick", steps=steps, algo="a2c", out=out,
                              num_envs=2, client=client, logger=QUIET)  # fmt: skip

    # The record alone, as `itskill learn` writes it before its reward search.
    search_network(TARGET, "itn", fresh, "pick", algo="a2c", client=client)
    assert train_on(trained, 16).num_timesteps == 16
    shutil.rmtree(skill_dir)
    make_source(skill_dir, seed=2, stages=(256, 256, 128))  # the skill retrained in place
    before = _files(fresh)

    stale = (
        f"{fresh / 'transfer.json'}: the weights of source skill(s) 'pick' changed or are gone "
        "since this record chose them"
    )
    with pytest.raises(SourceError, match=re.escape(stale)) as raised:
        train_on(fresh, 16)
    assert "start it in another --out, or delete transfer.json there" in str(raised.value)
    with pytest.raises(SourceError, match=re.escape(stale)):
        search_network(TARGET, "itn", fresh, "pick", algo="a2c", client=client)
    args = ["transfer", "train", TARGET, "--sources", "pick", "--algo", "a2c", "--steps", "16",
            "--num-envs", "2", "--out", str(fresh)]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2 and "delete transfer.json there" in " ".join(res.output.split())
    assert _files(fresh) == before
    # A run with a checkpoint resumes: the checkpoint carries the weights it trained with.
    assert train_on(trained, 32).resumed_from == 16


def test_a_task_whose_hyperparameters_warm_start_it_transfers_from_its_sources_alone(
    home: Path, tmp_path: Path
) -> None:
    # place_nut_m12's packaged table asks for scripted demonstrations: every method with sources
    # was refused ("a warm start needs a StagedActorCriticPolicy").
    out = tmp_path / "itn"
    result = train_transfer("place_nut_m12", "itn", "auto", steps=16, algo="a2c", out=out,
                            num_envs=2, client=CountingClient(), logger=QUIET)  # fmt: skip
    assert result.num_timesteps == 16
    assert read_meta(out)["hyperparams"]["demos"]["episodes"] == 0
    # So does a reward search's candidate on the same network (the expert reward's, in process).
    from itskill.reward.candidate import CandidateJob, _train_and_measure
    from itskill.reward.sandbox import SandboxConfig
    from itskill.transfer import search_network

    network = search_network("place_nut_m12", "itn", tmp_path / "search", algo="a2c",
                             client=CountingClient())  # fmt: skip
    job = CandidateJob("place_nut_m12", tmp_path / "candidate", None, (0,), 16, 2, "a2c", 16, 1,
                       1, SandboxConfig(), 300.0, network)  # fmt: skip
    assert _train_and_measure(job)["env_steps"] == 16
    assert read_meta(job.train_dir(0))["hyperparams"]["demos"]["episodes"] == 0
    # Demonstrations the caller asks for are theirs to ask for.
    with pytest.raises(HyperparamError, match="a warm start needs a StagedActorCriticPolicy"):
        train_transfer("place_nut_m12", "itn", "auto", steps=16, algo="a2c",
                       out=tmp_path / "asked", num_envs=2, client=CountingClient(), logger=QUIET,
                       overrides={"demos": {"episodes": 5}})  # fmt: skip


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        # Three rows for five stages: stages 3 and 4 took row 2's weights, without a word.
        (
            lambda r: r["contribution"].update(
                matrix=r["contribution"]["matrix"][:3], segments=r["contribution"]["segments"][:3]
            ),
            "contribution: its segments",
        ),
        (lambda r: r["contribution"]["matrix"][0].__setitem__(0, float("nan")), "contribution: "),
        (lambda r: [row.append(0.0) for row in r["contribution"]["matrix"]], "contribution: "),
        # Each stopped the resumed run with a ValueError where the network was built, or (a
        # short list) gave the last stages the last entry's source without a word.
        (lambda r: r.update(performers=[0, 0, 9, 1, 1]), "performers: expected 5 source indices"),
        (lambda r: r.update(performers=[0, 0]), "performers: expected 5 source indices"),
        (lambda r: r.update(performers=[True, 0, 0, 1, 1]), "performers: expected 5"),
        (
            lambda r: r["source_specs"][0].update(stage_map=[0, 1, 99, 2, 2]),
            "source_specs: stage_map of ",
        ),
        (lambda r: r["source_specs"][0].update(stage_map="0,1"), "source_specs: stage_map of "),
        # The networks are built from source_specs: one more, or another, was a ValueError
        # (the matrix's shape) or another skill's weights.
        (lambda r: r["source_specs"].append(dict(r["source_specs"][0])), "source_specs: the "),
        (lambda r: r["source_specs"][1].update(name="other"), "source_specs: the networks of"),
        # Columns in another order than the sources weighted each source with another's.
        (lambda r: r["contribution"]["sources"].reverse(), "contribution: its columns are"),
    ],
)
def test_a_record_that_does_not_fit_its_task_is_refused_naming_the_record(
    home: Path, tmp_path: Path, edit, problem: str
) -> None:
    out = tmp_path / "run"
    run(out, "itn")
    record = json.loads((out / "transfer.json").read_text())
    assert record["performers"] is not None and "stage_map" in record["source_specs"][0]
    edit(record)
    (out / "transfer.json").write_text(json.dumps(record))
    with pytest.raises(CheckpointError, match=re.escape(problem)) as err:
        run(out, "itn", steps=32)
    assert str(err.value).startswith(f"{out / 'transfer.json'}: {problem}")
    assert "cannot be resumed" in str(err.value)


def test_no_transfer_on_a_plain_training_run_says_what_the_directory_holds(
    home: Path, tmp_path: Path
):
    # It said the run's sources and contribution matrix were unknown: No_Transfer has neither.
    out = tmp_path / "run"
    train(TARGET, "a2c", 16, 0, out=out, num_envs=2, logger=QUIET, n_threads=1)
    with pytest.raises(CheckpointError, match="a run not trained as a transfer"):
        run(out, "no_transfer", steps=32)


def test_sources_named_by_numpy_ids_are_recorded(home: Path, tmp_path: Path):
    # parse_keys takes NumPy's integers; the record kept them and could not be written (after
    # the analyzer was asked).
    with open_skill_space() as space:
        ids = [np.int64(space.get(name).id) for name in SOURCES.split(",")]
    out = tmp_path / "run"
    train_transfer(TARGET, "dfs", ids, seed=0, steps=16, algo="a2c", out=out, num_envs=2,
                   logger=QUIET)  # fmt: skip
    assert json.loads((out / "transfer.json").read_text())["sources_request"] == [
        int(i) for i in ids
    ]


def test_a_plain_training_run_is_not_resumed_as_a_transfer_network(home: Path, tmp_path: Path):
    out = tmp_path / "run"
    train(TARGET, "a2c", 16, 0, out=out, num_envs=2, logger=QUIET, n_threads=1)
    with pytest.raises(
        ResumeMismatchError,
        match="holds a run of another network, StagedActorCriticPolicy; this call trains ITNPolicy",
    ):
        run(out, "itn")
