"""Choosing source skills: retrieval for a target, explicit ids and names, clear errors."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from transfer_helpers import make_source

from itskill.rl.checkpoint import POLICY_FILE
from itskill.sim.layout import OBSERVATION_VERSION
from itskill.skills import open_skill_space, search
from itskill.tasks import get_task
from itskill.transfer import SourceError, TransferConfig, load_transfer_config, resolve_sources
from itskill.transfer.sources import SourceWarning


def _config(**changes: object) -> TransferConfig:
    """The packaged transfer settings with ``changes``."""
    return replace(load_transfer_config(), **changes)


def test_auto_sources_for_pick_and_place_are_the_pick_and_place_skills(home: Path) -> None:
    sources = resolve_sources("pickplace_nut_m12", "auto")
    names = [s.name for s in sources]
    assert "pick_nut_m12" in names and "place_nut_m12" in names
    assert len(names) == 3
    # One skill per action sequence: not place_nut_m12 *and* place_nut_m16.
    assert len({s.actions for s in sources}) == 3
    assert all(s.task_id != "pickplace_nut_m12" for s in sources)
    # The skill that performs the longest run of the target's steps (pick: approach, grasp, lift)
    # leads, whatever its similarity score.
    assert names[0] == "pick_nut_m12"
    for s in sources:
        assert (s.run_dir / "checkpoint.json").is_file()
        assert s.to_dict()["weights_sha256"]
    # The second pick would add no step the first does not perform; the place adds two.
    plain = [
        s.name
        for s in resolve_sources("pickplace_nut_m12", "auto", _config(k=2, distinct_actions=False))
    ]
    assert plain == ["pick_nut_m12", "place_nut_m12"]
    # Once every step is covered, the rest follow by similarity; without de-duplication that
    # may be a second skill of the same steps.
    more = resolve_sources("pickplace_nut_m12", "auto", _config(k=6, distinct_actions=False))
    assert len({s.actions for s in more}) < 6


def test_auto_sources_come_from_the_targets_own_family_first(home: Path) -> None:
    # A nut's place skill performs two of the peg task's steps, but the peg skills come first.
    sources = resolve_sources("pickplaceinsert_peg_round", "auto")
    assert {s.task_id.split("_")[1] for s in sources} == {"peg"}, [s.name for s in sources]
    assert "insert_peg_round" in [s.name for s in sources]


def test_each_auto_source_adds_steps_of_the_target_the_others_do_not_perform(home: Path) -> None:
    # Pick-place-insert: approach, grasp, lift, approach, place, insert. The pick performs the
    # first three, the place the next two, the insert the last (a lift or a carry, though
    # similar to the command, repeats a step the others perform).
    sources = resolve_sources("pickplaceinsert_peg_round", "auto")
    assert [s.actions for s in sources] == [("approach", "grasp", "lift"), ("approach", "place"),
                                            ("insert",)]  # fmt: skip


def test_the_first_steps_go_to_a_skill_of_the_same_part_and_start(home: Path) -> None:
    # Three library skills approach, grasp and lift: removing the round peg from its hole (the
    # most similar to the command), picking the rectangular peg and picking the round one. Only
    # the last starts as the target does, with the round peg standing on the table.
    with open_skill_space() as space:
        same = {s.name for s in space.list() if s.actions == ("approach", "grasp", "lift")}
    assert {"remove_peg_round", "pick_peg_rect", "pick_peg_round"} <= same
    sources = resolve_sources("pickplaceinsert_peg_round", "auto")
    assert sources[0].name == "pick_peg_round"
    assert [s.name for s in sources[1:]] == ["place_peg_round", "insert_peg_round"]


def test_once_every_step_is_covered_a_skill_of_the_targets_steps_comes_next(home: Path) -> None:
    # "Screw the M12 nut onto the bottom of the bolt" reads closest to the pick-and-place
    # command, but screwing is none of its steps; carrying the nut over the bolt is one.
    with open_skill_space() as space:
        command = get_task("pickplace_nut_m12").command
        ranked = [s.name for s, _ in search(space, command, k=len(space))]
    assert ranked.index("screw_nut_m12") < ranked.index("carry_nut_m12")
    sources = resolve_sources("pickplace_nut_m12", "auto")
    assert [s.name for s in sources] == ["pick_nut_m12", "place_nut_m12", "carry_nut_m12"]
    # Where screwing is a step, the screw skill is a source.
    assert "screw_nut_m12" in [s.name for s in resolve_sources("pickplacescrew_nut_m12", "auto")]


def test_named_sources_by_name_and_id(home: Path) -> None:
    with open_skill_space() as space:
        pick_id = space.get("pick_nut_m12").id
    by_name = resolve_sources("pickplace_nut_m12", "place_nut_m12, pick_nut_m12")
    assert [s.name for s in by_name] == ["place_nut_m12", "pick_nut_m12"]
    assert all(s.score is None for s in by_name)
    by_id = resolve_sources("pickplace_nut_m12", [pick_id])
    assert [s.name for s in by_id] == ["pick_nut_m12"]
    assert resolve_sources("pickplace_nut_m12", str(pick_id))[0].name == "pick_nut_m12"
    # A serial number from NumPy (ids read into an array) names the skill too.
    assert resolve_sources("pickplace_nut_m12", [np.int64(pick_id)])[0].name == "pick_nut_m12"


def test_source_errors_name_the_problem(home: Path, tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r"unknown skill 'pick_nut_m13'.*pick_nut_m12"):
        resolve_sources("pickplace_nut_m12", "pick_nut_m13")
    with pytest.raises(SourceError, match="more than once: pick_nut_m12"):
        resolve_sources("pickplace_nut_m12", "pick_nut_m12,pick_nut_m12")
    with pytest.raises(SourceError, match="empty skill name"):
        resolve_sources("pickplace_nut_m12", "pick_nut_m12,")
    with pytest.raises(KeyError, match="unknown task"):
        resolve_sources("pickplace_nut_m99", "auto")
    # True == 1 named skill 1.
    with pytest.raises(SourceError, match="serial number or name, got bool True"):
        resolve_sources("pickplace_nut_m12", [True])
    with pytest.raises(SourceError, match=r"serial number or name, got bool np\.True_"):
        resolve_sources("pickplace_nut_m12", [np.bool_(True)])


def test_a_serial_number_is_ascii_digits(home: Path) -> None:
    # int("²") raised a ValueError with no skill in it.
    with pytest.raises(SourceError, match="unknown skill '²'"):
        resolve_sources("pickplace_nut_m12", "²")


def test_auto_passes_over_a_skill_from_a_stable_baselines3_zip(tmp_path: Path, monkeypatch) -> None:
    # `skills add` takes an SB3 .zip (for eval); retrieval chose it, and every auto transfer it
    # ranked for failed on it.
    from itskill.skills import Skill, SkillSpace

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    zipped = tmp_path / "pick.zip"
    zipped.write_bytes(b"an SB3 checkpoint")
    make_source(tmp_path / "place", seed=0)
    with SkillSpace() as space:
        pick = ("approach", "grasp", "lift")
        space.add(Skill("zipped", "pick_nut_m12", "Pick up the M12 nut", pick, str(zipped)))
        with pytest.raises(SourceError, match=r"no skill to transfer.*passed over.*: zipped\)"):
            resolve_sources("pickplace_nut_m12", "auto", space=space)
        place = ("approach", "place")
        weights = str(tmp_path / "place" / "policy.safetensors")
        space.add(Skill("place", "place_nut_m12", "Place the M12 nut on the bolt", place, weights))
        assert [s.name for s in resolve_sources("pickplace_nut_m12", "auto", space=space)] == [
            "place"
        ]
        # A skill of an older observation layout too: ranked first, it failed every retrieval.
        make_source(tmp_path / "old", seed=1)
        meta = json.loads((tmp_path / "old" / "checkpoint.json").read_text())
        meta["obs_version"] = OBSERVATION_VERSION - 1
        (tmp_path / "old" / "checkpoint.json").write_text(json.dumps(meta))
        old = str(tmp_path / "old" / "policy.safetensors")
        space.add(Skill("old_pick", "pick_nut_m12", "Pick up the M12 nut", pick, old))
        # Said, unlike the .zip: a damaged or outdated checkpoint is the user's to mend.
        with pytest.warns(
            SourceWarning, match="skill 'old_pick' passed over: .*observation layout"
        ):
            chosen = resolve_sources("pickplace_nut_m12", "auto", space=space)
        assert [s.name for s in chosen] == ["place"]
        with pytest.raises(SourceError, match=r"skill 'zipped'.*not a directory"):
            resolve_sources("pickplace_nut_m12", "zipped", space=space)


def test_a_skill_whose_checkpoint_is_gone(tmp_path: Path, monkeypatch) -> None:
    from itskill.skills import Skill, SkillSpace

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    run = tmp_path / "run"
    run.mkdir()
    (run / "policy.safetensors").write_bytes(b"x")
    with SkillSpace() as space:
        space.add(
            Skill(
                "half",
                "pick_nut_m12",
                "Pick up the nut",
                ("grasp",),
                str(run / "policy.safetensors"),
            )
        )
        with pytest.raises(SourceError, match=r"skill 'half'.*checkpoint\.json: missing"):
            resolve_sources("pickplace_nut_m12", "half", space=space)
        space.remove("half")
        with pytest.raises(SourceError, match="no skill to transfer"):
            resolve_sources("pickplace_nut_m12", "auto", space=space)


@pytest.mark.parametrize("policy", [{}, {"stages": 5}, {"stages": [256, "wide"]}])
def test_a_skill_whose_policy_description_is_damaged_is_named(
    tmp_path: Path, monkeypatch, policy: dict
) -> None:
    # The networks read the source's stages when they are built: a KeyError or a TypeError.
    from itskill.skills import Skill, SkillSpace

    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "home"))
    run = tmp_path / "run"
    make_source(run, seed=0)
    meta = json.loads((run / "checkpoint.json").read_text())
    (run / "checkpoint.json").write_text(json.dumps({**meta, "policy": policy}))
    with SkillSpace() as space:
        space.add(Skill("bent", "pick_nut_m12", "Pick up the nut", ("grasp",),
                        str(run / POLICY_FILE)))  # fmt: skip
        with pytest.raises(SourceError, match=r"skill 'bent'.*corrupt policy description"):
            resolve_sources("pickplace_nut_m12", "bent", space=space)


def test_a_weak_skill_comes_after_the_working_skills_it_would_displace(
    skill_home: Path, tmp_path: Path, monkeypatch
) -> None:
    # `itskill learn --budget tiny` adds its pick-and-place at any success. Performing five of
    # the pick-place-screw's six steps, it took the first source slot from the library's pick
    # and place, which work.
    import shutil

    from itskill.skills import Skill

    home = tmp_path / "home"
    shutil.copytree(skill_home, home)
    monkeypatch.setenv("ITSKILL_HOME", str(home))
    make_source(tmp_path / "weak", seed=0)
    actions = ("approach", "grasp", "lift", "approach", "place")
    weights = str(tmp_path / "weak" / POLICY_FILE)
    command = "Pick up the nut and place it on the bolt"
    weak = Skill("learned-pick-and-place", "pickplace_nut_m12", command, actions, weights,
                 success_rate=0.02)  # fmt: skip
    with open_skill_space() as space:
        space.add(weak)
    names = [s.name for s in resolve_sources("pickplacescrew_nut_m12", "auto")]
    assert names == ["pick_nut_m12", "place_nut_m12", "screw_nut_m12"]
    # With a threshold it passes, it leads again.
    allowed = resolve_sources("pickplacescrew_nut_m12", "auto", _config(min_success=0.0))
    assert allowed[0].name == "learned-pick-and-place"
