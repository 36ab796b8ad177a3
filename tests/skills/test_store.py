from __future__ import annotations

import math
import multiprocessing as mp
import sqlite3
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from skill_helpers import make_skill

from itskill.skills import (
    CorruptDatabaseError,
    DuplicateSkillError,
    MissingCheckpointError,
    SchemaVersionError,
    SkillSpace,
    SkillSpaceError,
    UnknownSkillError,
    itskill_home,
)
from itskill.skills.manifest import read_manifest
from itskill.skills.store import (
    MIGRATIONS,
    SCHEMA_VERSION,
    SHIPPED_LIBRARY,
    InvalidMeasurementError,
    InvalidSkillNameError,
    MigrationError,
)


def test_home_defaults(monkeypatch, tmp_path):
    monkeypatch.delenv("ITSKILL_HOME", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert itskill_home() == tmp_path / "xdg" / "itskill"
    monkeypatch.delenv("XDG_DATA_HOME")
    assert itskill_home() == Path.home() / ".local" / "share" / "itskill"
    monkeypatch.setenv("ITSKILL_HOME", str(tmp_path / "h"))
    assert itskill_home() == tmp_path / "h"


def test_an_empty_home_variable_counts_as_unset(monkeypatch, tmp_path):
    # A template's `ITSKILL_HOME=${HOME_DIR:-}` must not put the skill space in the current
    # directory (Path("") is ".").
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ITSKILL_HOME", "")
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert itskill_home() == tmp_path / "xdg" / "itskill"
    monkeypatch.setenv("XDG_DATA_HOME", "")
    assert itskill_home() == Path.home() / ".local" / "share" / "itskill"


def test_a_relative_home_is_made_absolute(monkeypatch, tmp_path):
    # A relative checkpoint path in the database is read as inside the library directory, so
    # paths under a relative home were joined twice (`itskill learn` failed to add its skill).
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ITSKILL_HOME", "runs/home")
    assert itskill_home() == tmp_path.resolve() / "runs" / "home"


def test_add_get_list_update_remove(home, checkpoint):
    with SkillSpace() as space:
        assert space.path == home / "skills.sqlite"
        a = space.add(make_skill("a", checkpoint, seed=1, success_rate=0.5, train_steps=1000))
        b = space.add(make_skill("b", checkpoint, seed=2, algo="ppo"))
        assert (a.id, b.id) == (1, 2)
        got = space.get("a")
        assert got == a and space.get(1) == a and space.get("2") == b
        np.testing.assert_array_equal(got.embedding, a.embedding)
        assert [s.name for s in space.list()] == ["a", "b"]
        new = space.update("a", success_rate=0.9, success_ci=(0.8, 0.95))
        assert space.get("a").success_rate == 0.9
        assert space.get("a").success_ci == (0.8, 0.95) == new.success_ci
        assert space.get("a").train_steps == 1000  # Untouched fields are kept.
        # Said to be a corrupt database ("Move it aside"), or a bare TypeError from the actions.
        for field in ("task_id", "description", "actions"):
            with pytest.raises(TypeError, match=f"a skill's {field} cannot be None"):
                space.update("a", **{field: None})
        assert space.get("a") == replace(a, success_rate=0.9, success_ci=(0.8, 0.95))
        assert space.remove("b").name == "b"
        assert len(space) == 1
        with pytest.raises(DuplicateSkillError):
            space.add(make_skill("a", checkpoint))


def test_unknown_skill_lists_close_names(home, checkpoint):
    with SkillSpace() as space:
        space.add(make_skill("pick_nut_m12", checkpoint))
        with pytest.raises(UnknownSkillError, match="pick_nut_m12") as err:
            space.get("pick_nut_m16")
        assert err.value.close == ["pick_nut_m12"]
        with pytest.raises(UnknownSkillError):
            space.remove(99)


def test_checkpoint_must_exist_and_relative_paths_use_library(
    home, checkpoint, tmp_path, monkeypatch
):
    shipped = tmp_path / "site-packages" / "itskill" / "skills" / "library"
    monkeypatch.setattr("itskill.skills.store.SHIPPED_LIBRARY", shipped)
    with SkillSpace() as space:
        with pytest.raises(MissingCheckpointError, match=r"nope\.zip"):
            space.add(make_skill("x", checkpoint.parent / "nope.zip"))
        space.library_dir.mkdir(parents=True)
        (space.library_dir / "rel.zip").write_bytes(b"x")
        s = space.add(make_skill("rel", Path("rel.zip")))
        assert space.checkpoint_path(s) == home / "library" / "rel.zip"
        # Each stored form reads back as the file it was made from.
        for path in (home / "library" / "rel.zip", shipped / "x.zip", checkpoint):
            ref = space.checkpoint_ref(path)
            assert space.checkpoint_path(make_skill("y", Path(ref))) == path
        assert space.checkpoint_ref(shipped / "a" / "b.zip") == "package:a/b.zip"
        with pytest.raises(MissingCheckpointError, match=r"gone\.zip"):
            space.set_checkpoint("rel", "package:gone.zip")


def _add_many(args: tuple[str, str, int]) -> None:
    home, checkpoint, worker = args
    import os

    os.environ["ITSKILL_HOME"] = home
    with SkillSpace() as space:
        for i in range(25):
            # One transaction per skill, interleaved with the other writers.
            space.add(make_skill(f"w{worker}_{i}", Path(checkpoint), seed=worker * 100 + i))


def test_concurrent_adds_lose_nothing(home, checkpoint):
    ctx = mp.get_context("spawn")  # No inherited sqlite handles; the way real workers start.
    with ctx.Pool(4) as pool:
        pool.map(_add_many, [(str(home), str(checkpoint), w) for w in range(4)])
    with SkillSpace() as space:
        names = {s.name for s in space.list()}
        ids = [s.id for s in space.list()]
    assert names == {f"w{w}_{i}" for w in range(4) for i in range(25)}
    assert sorted(ids) == list(range(1, 101))


def test_a_name_taken_meanwhile_is_refused_skipped_or_replaced(home, checkpoint):
    with SkillSpace() as space:
        space.add(make_skill("taken", Path(checkpoint)))
        both = [make_skill("taken", Path(checkpoint), seed=9), make_skill("new", Path(checkpoint))]
        with pytest.raises(DuplicateSkillError, match="'taken' already exists"):
            space.add_many(both)
        assert [s.name for s in space.add_many(both, on_conflict="skip")] == ["new"]
        assert space.get("taken").seed != 9  # the first one stays
        newer = make_skill("taken", Path(checkpoint), success_rate=0.75)
        serial = space.get("taken").id
        [added] = space.add_many([newer], on_conflict="replace")
        assert added.success_rate == 0.75 and added.id == serial
        # Retrained by `skills pretrain`, it keeps the number `--sources 1` and notes name it by.
        assert [(s.id, s.success_rate) for s in space.list() if s.name == "taken"] == [
            (serial, 0.75)
        ]
        assert space.get(str(serial)).success_rate == 0.75


def _replace_many(args) -> None:
    home, checkpoint, worker = args
    import os

    os.environ["ITSKILL_HOME"] = home
    with SkillSpace() as space:
        for i in range(10):
            skill = make_skill("shared", Path(checkpoint), seed=worker * 100 + i)
            space.add_many([skill], on_conflict="replace")


def test_processes_replacing_one_skill_always_leave_exactly_one(home, checkpoint):
    # Retraining replaces a skill; a remove then an add let two processes interleave into a
    # duplicate-name error or, killed in between, into no skill at all.
    with mp.get_context("spawn").Pool(2) as pool:
        pool.map(_replace_many, [(str(home), str(checkpoint), w) for w in range(2)])
    with SkillSpace() as space:
        assert [s.name for s in space.list()] == ["shared"]


def test_a_name_of_digits_is_refused(home, checkpoint):
    # get("1") and remove("1") take a string of digits for a serial number.
    with SkillSpace() as space:
        with pytest.raises(InvalidSkillNameError, match="'1' is all digits"):
            space.add(make_skill("1", Path(checkpoint)))
        assert len(space) == 0


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("", "'' is blank"),
        ("  ", "'  ' is blank"),
        (" pick ", "give it as 'pick'"),
        # Accepted, then --sources read "mine,v2" as the skills "mine" and "v2".
        ("mine,v2", "has a comma, which --sources reads as two names; give it as 'mine-v2'"),
        # Printed raw, they split a table's row or recoloured the terminal.
        ("pick\nv2", "has a control character"),
        ("\x1b[31mred", "has a control character"),
        ("pick\u202ev2", "has a control character"),
    ],
)
def test_a_name_that_sources_cannot_name_is_refused(home, checkpoint, name, problem):
    # "  " was added, and no --sources list could then name it (each name there is stripped).
    with SkillSpace() as space:
        with pytest.raises(InvalidSkillNameError, match=problem):
            space.add(make_skill(name, Path(checkpoint)))
        assert len(space) == 0


def test_only_ascii_digits_read_as_a_serial_number(home, checkpoint):
    # "²" and "①" are digits to str.isdigit, which int() refuses: `skills show ²` crashed.
    with SkillSpace() as space:
        space.add(make_skill("①", Path(checkpoint)))
        assert space.get("①").name == "①"
        with pytest.raises(UnknownSkillError, match="unknown skill '²'"):
            space.get("²")


def test_a_serial_number_past_sqlites_integers_names_no_skill(home, checkpoint):
    # Binding it to the query raised OverflowError (`skills show 99999999999999999999999`).
    with SkillSpace() as space:
        space.add(make_skill("a", Path(checkpoint)))
        for key in ("9" * 23, 2**70, -(2**70), "9" * 5000, str(2**63)):
            with pytest.raises(UnknownSkillError, match="unknown skill"):
                space.get(key)
        with pytest.raises(UnknownSkillError):
            space.remove("9" * 23)
        assert space.get("0" * 30 + "1").name == "a"  # leading zeros still read as 1


@pytest.mark.parametrize(
    ("measurements", "problem"),
    [
        ({"train_wall_s": math.inf}, "train_wall_s: inf is not a finite number of seconds"),
        ({"train_wall_s": math.nan}, "train_wall_s: nan is not a finite number of seconds"),
        ({"train_wall_s": -1.0}, "train_wall_s: -1.0 is not a finite number of seconds"),
        ({"train_steps": -5}, "train_steps: -5 is not a whole number of env-steps"),
        # Past SQLite's integers: an OverflowError traceback from the insert.
        ({"train_steps": 2**64}, "train_steps: 18446744073709551616 is not a whole number"),
        ({"seed": 2**64}, "seed: 18446744073709551616 is not a whole number"),
        ({"seed": -3}, "seed: -3 is not a whole number"),
        ({"algo": 5}, "algo: 5 is not an algorithm's name"),
        (
            {"success_rate": 0.1, "success_ci": (0.9, 0.99)},
            "success: 0.1 is outside its own interval [0.9, 0.99]",
        ),
    ],
)
def test_every_write_refuses_measurements_no_run_gives(home, checkpoint, measurements, problem):
    # An infinite wall time was stored and `skills show --json` printed Infinity, which is not
    # JSON; a rate outside its own interval was stored as measured.
    with SkillSpace() as space:
        with pytest.raises(InvalidMeasurementError) as added:
            space.add(replace(make_skill("a", Path(checkpoint)), **measurements))
        assert str(added.value).startswith(problem) and len(space) == 0
        space.add(make_skill("a", Path(checkpoint)))
        with pytest.raises(InvalidMeasurementError) as updated:
            space.update("a", **measurements)
        assert str(updated.value).startswith(problem)
        assert space.get("a").train_wall_s is None and space.get("a").success_rate is None


def test_a_full_disk_is_named_and_loses_no_skill(home, checkpoint):
    # SQLite rolls a transaction back itself on a full disk; the ROLLBACK after it failed, and
    # its "no transaction is active" hid the cause.
    with SkillSpace() as space:
        space.add(make_skill("kept", Path(checkpoint)))
        pages = space._conn.execute("PRAGMA page_count").fetchone()[0]
        space._conn.execute(f"PRAGMA max_page_count = {pages + 2}")  # a full disk's error code
        with pytest.raises(SkillSpaceError, match="full") as err:
            for i in range(200):
                space.add(make_skill(f"s{i}", Path(checkpoint), seed=i, description="x" * 3000))
        assert "no transaction" not in str(err.value)
        assert "kept" in [s.name for s in space.list()]


def test_a_constraint_other_than_the_name_is_not_called_a_taken_name(home, checkpoint):
    with SkillSpace() as space, pytest.raises(SkillSpaceError) as err:
        space.add(replace(make_skill("fresh", Path(checkpoint)), task_id=None))
    assert not isinstance(err.value, DuplicateSkillError)
    assert "NOT NULL constraint failed: skills.task_id" in str(err.value)


def test_a_removed_skills_serial_number_is_never_given_again(home, checkpoint):
    # `itskill learn` records a skill's serial number; a later skill must not take it over.
    with SkillSpace() as space:
        space.add(make_skill("a", Path(checkpoint)))
        b = space.add(make_skill("b", Path(checkpoint)))
        space.remove("b")
        c = space.add(make_skill("c", Path(checkpoint)))
        assert c.id == b.id + 1
        with pytest.raises(UnknownSkillError):
            space.get(b.id)


def test_a_taken_name_is_refused_before_the_description_is_embedded(home, checkpoint, monkeypatch):
    # Embedding loads the model first: the duplicate was reported only half a minute later.
    def embed(texts):
        raise AssertionError("embedded a skill whose name is taken")

    monkeypatch.setattr("itskill.skills.embeddings.embed", embed)
    with SkillSpace() as space:
        space.add(make_skill("taken", Path(checkpoint)))
        with pytest.raises(DuplicateSkillError, match="'taken' already exists"):
            space.add(make_skill("taken", Path(checkpoint), embedding=None))


def test_a_new_description_clears_the_embedding(home, checkpoint):
    with SkillSpace() as space:
        space.add(make_skill("a", Path(checkpoint)))
        assert space.update("a", success_rate=0.5).embedding is not None
        updated = space.update("a", actions=["approach", "place"])
        assert updated.actions == ("approach", "place")
        assert space.get("a").embedding is None  # the next search embeds the new text
        with pytest.raises(TypeError, match="cannot update"):
            space.update("a", checkpoint="elsewhere")


def test_an_embedding_is_stored_only_for_the_text_it_was_made_from(home, checkpoint):
    # A search embeds rows outside any transaction; the text may change before it stores them.
    with SkillSpace() as space:
        read = space.add(make_skill("a", Path(checkpoint), embedding_model="old"))
        space.add(make_skill("b", Path(checkpoint), embedding_model="old"))
        space.update("a", actions=["approach", "place"])
        vec = make_skill("x", Path(checkpoint), seed=7).embedding
        space.set_embeddings(
            [
                replace(read, embedding=vec, embedding_model="m"),
                replace(space.get("b"), embedding=vec, embedding_model="m"),
            ]
        )
        assert (space.get("a").embedding, space.get("a").embedding_model) == (None, None)
        np.testing.assert_array_equal(space.get("b").embedding, vec)
        assert space.get("b").embedding_model == "m"


def _open_fresh_space(home: str) -> int:
    import os

    os.environ["ITSKILL_HOME"] = home
    from itskill.skills import open_skill_space

    with open_skill_space() as space:
        return len(space.list())


def test_two_processes_opening_a_new_skill_space_both_get_the_shipped_library(tmp_path):
    home = str(tmp_path / "fresh")
    with mp.get_context("spawn").Pool(2) as pool:
        counts = pool.map(_open_fresh_space, [home, home])
    shipped = len(read_manifest(SHIPPED_LIBRARY))
    assert counts == [shipped, shipped]


def _version_1_database(home):
    """A skill database as the first schema version left it; the caller commits and closes."""
    home.mkdir()
    conn = sqlite3.connect(home / "skills.sqlite")
    for statement in MIGRATIONS[0]:
        conn.execute(statement)
    conn.execute("PRAGMA user_version = 1")
    return conn


def test_old_version_is_upgraded_and_keeps_rows(home, checkpoint):
    conn = _version_1_database(home)
    conn.execute(
        "INSERT INTO skills (name, task_id, description, actions, checkpoint, success_rate, "
        "created) VALUES ('old', 'pick_nut_m12', 'Pick up the M12 nut', '[\"approach\"]', ?, "
        "0.7, 1.0)",
        (str(checkpoint),),
    )
    conn.commit()
    conn.close()
    with SkillSpace() as space:
        assert space.schema_version == SCHEMA_VERSION > 1
        old = space.get("old")
        assert (old.success_rate, old.actions, old.embedding) == (0.7, ("approach",), None)
        assert old.id == 1 and space.add(make_skill("new", Path(checkpoint))).id == 2
        space.update("old", train_steps=5, success_ci=(0.6, 0.8))
        assert space.get("old").train_steps == 5


def test_failed_migration_leaves_old_version(home, monkeypatch):
    conn = _version_1_database(home)
    conn.commit()
    conn.close()
    from itskill.skills import store

    broken = [*MIGRATIONS[:1], [*MIGRATIONS[1], "THIS IS NOT SQL"]]
    monkeypatch.setattr(store, "MIGRATIONS", broken)
    monkeypatch.setattr(store, "SCHEMA_VERSION", len(broken))
    with pytest.raises(MigrationError, match="schema version 2 failed"):
        SkillSpace()
    conn = sqlite3.connect(home / "skills.sqlite")
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 1
    columns = [r[1] for r in conn.execute("PRAGMA table_info(skills)")]
    assert "embedding" not in columns  # The half-applied step was rolled back.
    conn.close()


def test_newer_version_is_refused(home):
    home.mkdir()
    path = home / "skills.sqlite"
    conn = sqlite3.connect(path)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.close()
    with pytest.raises(SchemaVersionError, match="newer than this itskill supports") as err:
        SkillSpace()
    assert str(path) in str(err.value)


def test_corrupt_file_names_path(home):
    home.mkdir()
    path = home / "skills.sqlite"
    path.write_bytes(b"this is not an sqlite database" * 100)
    with pytest.raises(CorruptDatabaseError) as err:
        SkillSpace()
    assert str(path) in str(err.value)


def test_a_database_damaged_below_its_header_names_its_path(home, checkpoint):
    with SkillSpace() as space:
        space.add_many(make_skill(f"s{i}", Path(checkpoint), seed=i) for i in range(20))
    path = home / "skills.sqlite"
    data = path.read_bytes()
    page = 4096  # the first page (the header and the schema) stays: the file opens
    path.write_bytes(data[:page] + b"\xff" * (len(data) - page))
    with SkillSpace() as space, pytest.raises(CorruptDatabaseError) as err:
        space.list()
    assert str(path) in str(err.value) and "not a readable itskill skill database" in str(err.value)


def test_a_path_that_cannot_hold_a_database_is_named_as_such(home):
    # Not "not a readable skill database ... Move it aside": there is no database to move.
    (home / "skills.sqlite").mkdir(parents=True)
    with pytest.raises(SkillSpaceError) as err:
        SkillSpace()
    assert not isinstance(err.value, CorruptDatabaseError)
    assert f"cannot use {home / 'skills.sqlite'} as the skill database" in str(err.value)


def test_a_damaged_row_is_named_and_a_damaged_vector_embedded_again(home, checkpoint):
    # Unreadable actions were a JSONDecodeError traceback on every list; a short vector a
    # NumPy shape error on every search.
    from itskill.skills import search

    with SkillSpace() as space:
        space.add(make_skill("a", Path(checkpoint)))
        space.add(make_skill("b", Path(checkpoint)))
        path = space.path
    with sqlite3.connect(path) as conn:
        conn.execute("UPDATE skills SET embedding = ? WHERE name = 'b'", (bytes(8),))
    with SkillSpace() as space:
        assert len(search(space, "Pick up the nut", k=2)) == 2
        assert space.get("b").embedding.shape == (384,)
    with sqlite3.connect(path) as conn:
        conn.execute("""UPDATE skills SET actions = '["grasp"' WHERE name = 'a'""")
    with SkillSpace() as space, pytest.raises(CorruptDatabaseError, match=r"skill 'a' \(id 1\)"):
        space.list()
    # What the message advises works: the row is removed without being read.
    with SkillSpace() as space:
        assert space.remove(1).name == "a"
        assert [s.name for s in space.list()] == ["b"]


def test_a_database_another_process_holds_is_said_to_be_in_use(tmp_path, checkpoint) -> None:
    # It said "check the path, or point ITSKILL_HOME at a writable directory": nothing was wrong
    # with either.
    from itskill.skills.store import SkillSpaceConfig

    path = tmp_path / "skills.sqlite"
    SkillSpace(path).close()
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(SkillSpaceError, match="is in use by another process") as err:
            space = SkillSpace(path, SkillSpaceConfig(busy_timeout_s=0.2))
            space.add(make_skill("mine", checkpoint))
        assert "writable directory" not in str(err.value)
    finally:
        holder.rollback()
        holder.close()
