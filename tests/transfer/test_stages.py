"""Which stage each source sees, and which source performs each target stage."""

from __future__ import annotations

import pytest

from itskill.tasks import get_task
from itskill.transfer.stages import fill_performers, stage_map, stage_performers


def names(task: str) -> list[str]:
    return [st.name for st in get_task(task).stages]


def test_pick_and_place_sources_see_their_own_stages() -> None:
    target = names("pickplace_nut_m12")  # approach, grasp, lift, approach, place
    # Pick does stages 0-2 and stays in its lift stage afterwards.
    assert stage_map(target, names("pick_nut_m12")) == (0, 1, 2, 2, 2)
    # Place approaches the bolt in stage 3 and places in 4; before that it waits in its first.
    assert stage_map(target, names("place_nut_m12")) == (0, 0, 0, 0, 1)
    # A one-stage skill is always in its only stage.
    assert stage_map(target, names("carry_nut_m12")) == (0, 0, 0, 0, 0)


def test_a_repeated_run_restarts_the_source() -> None:
    pick = names("pick_nut_m12")
    target = [*names("pickplace_nut_m12"), *names("pickplace_nut_m12")]
    assert stage_map(target, pick) == (0, 1, 2, 2, 2, 0, 1, 2, 2, 2)


def test_without_a_contiguous_run_names_match_in_order() -> None:
    # "approach, place" does not occur in "approach, grasp, place" as a run; matched in order,
    # the grasp keeps the source in its approach stage.
    assert stage_map(["approach", "grasp", "place"], ["approach", "place"]) == (0, 0, 1)
    # A later name never sends the source back to an earlier stage.
    assert stage_map(["lift", "approach"], ["approach", "lift"]) == (1, 1)
    with pytest.raises(ValueError, match="stage names of both"):
        stage_map([], ["approach"])


def test_performers_are_the_first_source_covering_each_stage() -> None:
    target = names("pickplace_nut_m12")
    sources = [names("pick_nut_m12"), names("place_nut_m12"), names("carry_nut_m12")]
    assert stage_performers(target, sources) == (0, 0, 0, 1, 1)
    # Carry listed first takes both approaches; a source of unknown stages covers nothing.
    assert stage_performers(target, [names("carry_nut_m12"), None]) == (0, -1, -1, 0, -1)
    peg = names("pickplaceinsert_peg_round")  # approach, grasp, lift, approach, place, insert
    peg_sources = [names("pick_peg_rect"), names("insert_peg_round"), names("carry_peg_round")]
    assert stage_performers(peg, peg_sources) == (0, 0, 0, 2, -1, 1)
    # The sources `auto` takes for it perform every stage: the place skill both of its own.
    peg_sources = [names("pick_peg_round"), names("place_peg_round"), names("insert_peg_round")]
    assert stage_performers(peg, peg_sources) == (0, 0, 0, 1, 1, 2)


def test_a_stage_no_stage_name_covers_goes_to_the_source_whose_actions_do() -> None:
    target = get_task("pickplaceinsert_peg_rect")
    sources = [get_task(n) for n in ("pick_peg_rect", "place_peg_rect", "insert_peg_rect")]
    by_name = stage_performers(names(target.id), [names(s.id) for s in sources])
    # place_peg_rect has one stage, named place: no stage name covers the approach to the hole.
    assert by_name == (0, 0, 0, -1, 1, 2)
    # Its actions are approach, place: it performs the approach too.
    filled = fill_performers(by_name, target.actions, [s.actions for s in sources])
    assert filled == (0, 0, 0, 1, 1, 2)
    # Stages covered by name keep their performer, and without one action per stage nothing
    # is filled.
    assert fill_performers((0, -1), ("approach", "grasp"), [("grasp",), ("approach",)]) == (0, 0)
    assert fill_performers((0, -1), ("approach",), [("approach",)]) == (0, -1)
