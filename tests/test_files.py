"""Atomic writes: a file is either its old self or complete, and a failed write leaves nothing."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from itskill.files import (
    foreign_entries,
    is_unusable_path,
    path_error_message,
    read_json_or_none,
    write_json,
    write_text,
)


def test_a_write_that_fails_keeps_the_old_file_and_leaves_no_temporary(
    tmp_path: Path, monkeypatch
) -> None:
    path = tmp_path / "config.json"
    write_text(path, "old")

    def disk_full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space"):
        write_text(path, "new")
    # A leftover temporary made `learn --resume` take an empty run for a started one.
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == [path.name]


def test_a_path_too_long_or_looping_is_the_paths_fault_and_named_cut_short(tmp_path: Path) -> None:
    # ENAMETOOLONG and ELOOP are plain OSErrors: the commands printed them as tracebacks.
    too_long = tmp_path / ("a" * 300)
    with pytest.raises(OSError) as long_err:
        too_long.mkdir()
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    with pytest.raises(OSError) as loop_err:
        loop.read_text()
    assert is_unusable_path(long_err.value) and is_unusable_path(loop_err.value)
    message = path_error_message(long_err.value)
    assert message.startswith(f"cannot use {str(too_long)[:40]}")
    assert message.endswith(f"aaa ({len(str(too_long))} characters): File name too long")
    assert len(message) < 200
    assert path_error_message(loop_err.value) == (
        f"cannot use {loop}: Too many levels of symbolic links"
    )
    assert not is_unusable_path(OSError(errno.ENOSPC, "No space left on device"))


def test_a_recorded_path_is_found_wherever_the_run_now_is(tmp_path, monkeypatch) -> None:
    from itskill.files import run_path

    run = tmp_path / "run"
    (run / "reward").mkdir(parents=True)
    (run / "reward" / "best.py").write_text("")
    usual = "reward/best.py"
    # Relative to the run (records written now).
    assert run_path(run, "reward/best.py", usual) == run / "reward" / "best.py"
    # Relative to where an older release's command ran (`--out run`): at its usual place in the
    # run, which the resume of such a run needs.
    monkeypatch.chdir(tmp_path)
    assert run_path(run, "run/reward/best.py", usual) == run / "reward" / "best.py"
    # Absolute, of a run copied elsewhere while the original is still there: the copy's own.
    copy = tmp_path / "copy"
    (copy / "reward").mkdir(parents=True)
    (copy / "reward" / "best.py").write_text("")
    assert run_path(copy, str(run / "reward" / "best.py"), usual) == copy / "reward" / "best.py"
    # Absolute, of a run since moved: at its usual place in the run.
    assert run_path(run, "/gone/run/reward/best.py", usual) == run / "reward" / "best.py"


def test_a_directory_held_by_another_session_is_refused_and_one_session_may_nest(
    tmp_path: Path,
) -> None:
    from filelock import Timeout

    from itskill.files import directory_lock, held_alone

    busy = ValueError("in use")
    other = directory_lock(tmp_path, "run")  # another session's lock: a handle of its own
    with other, pytest.raises(ValueError, match="in use"), held_alone(tmp_path, "run", busy):
        pass
    # A command that holds the directory calls a function that takes it again: one session.
    nested = held_alone(tmp_path, "run", busy), held_alone(tmp_path, "run", busy)
    with nested[0], nested[1], pytest.raises(Timeout):
        other.acquire(timeout=0)
    other.acquire(timeout=0)  # let go once the outer block ended
    other.release()


def test_foreign_entries_leave_out_what_the_caller_and_file_browsers_own(tmp_path: Path) -> None:
    assert foreign_entries(tmp_path / "nowhere") == []
    # A write a kill cut short left its temporary file: a learn or reward search killed before
    # its first file was whole could not be started again until the user deleted it.
    for name in ("plan.json", ".DS_Store", "network", "notes.txt", ".config.json.4242.tmp",
                 ".v.mp4.4242.tmp.mp4"):  # fmt: skip
        (tmp_path / name).write_text("")
    (tmp_path / ".notes.tmp").write_text("")  # not a name an itskill write uses: the user's
    assert foreign_entries(tmp_path) == [".notes.tmp", "network", "notes.txt", "plan.json"]
    own = foreign_entries(tmp_path, lambda name: name in ("network", ".notes.tmp"))
    assert own == ["notes.txt", "plan.json"]


def test_read_json_or_none_gives_none_for_a_missing_or_damaged_record(tmp_path: Path) -> None:
    path = tmp_path / "record.json"
    assert read_json_or_none(path) is None
    path.write_text('{"steps": 3')
    assert read_json_or_none(path) is None
    path.write_bytes(b'{"name": "\xff"}')
    assert read_json_or_none(path) is None
    write_json(path, {"steps": 3})
    assert read_json_or_none(path) == {"steps": 3}


def test_lock_files_are_kept_in_a_folder_of_their_own(tmp_path, monkeypatch) -> None:
    # One stays per directory ever locked: thousands of them lay among /tmp's other files.
    from itskill.files import LOCK_DIR_ENV, directory_lock

    monkeypatch.delenv(LOCK_DIR_ENV, raising=False)
    lock = Path(directory_lock(tmp_path, "run").lock_file)
    assert lock.parent.parent == Path("/tmp")
    assert lock.parent.name.startswith("itskill-locks-") and lock.name.startswith("run-")


def test_sessions_with_different_temporary_directories_share_a_directorys_lock(
    tmp_path, monkeypatch
) -> None:
    # The lock folder followed TMPDIR: a second session with its own trained into the same run
    # as the first, interleaving their metrics.
    import tempfile

    from itskill.files import LOCK_DIR_ENV, directory_lock

    monkeypatch.delenv(LOCK_DIR_ENV, raising=False)
    files = set()
    for name in ("one", "two"):
        (tmp_path / name).mkdir()
        monkeypatch.setenv("TMPDIR", str(tmp_path / name))
        monkeypatch.setattr(tempfile, "tempdir", None)  # read TMPDIR again
        files.add(directory_lock(tmp_path / "run", "run").lock_file)
    assert len(files) == 1


def test_a_file_where_a_directory_is_needed_is_said_so(tmp_path) -> None:
    from itskill.files import path_error_message

    (tmp_path / "bad.zip").write_text("")
    with pytest.raises(FileExistsError) as err:
        (tmp_path / "bad.zip").mkdir(parents=True, exist_ok=True)
    assert path_error_message(err.value).endswith("it is a file, and a directory is needed there")


def _writable_by_others(locks: Path, monkeypatch) -> None:
    # Its name is predictable: another user's folder of that name could hold or delete the locks.
    locks.mkdir(mode=0o777)
    os.chmod(locks, 0o777)


def _of_another_user(locks: Path, monkeypatch) -> None:
    # Another user who made the folder first owns it: this session is another uid than its owner.
    locks.mkdir(mode=0o700)
    monkeypatch.setattr(os, "getuid", lambda: os.stat(locks).st_uid + 1)


def _a_link(locks: Path, monkeypatch) -> None:
    # A link named like the folder could lead the locks into a folder someone else controls.
    (locks.parent / "elsewhere").mkdir(mode=0o700)
    locks.symlink_to(locks.parent / "elsewhere")


@pytest.mark.parametrize("make", [_writable_by_others, _of_another_user, _a_link])
def test_a_lock_folder_not_this_users_alone_is_refused(tmp_path, monkeypatch, make) -> None:
    from itskill.files import LOCK_DIR_ENV, directory_lock, is_unusable_path

    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path / "locks"))
    make(tmp_path / "locks", monkeypatch)
    with pytest.raises(
        PermissionError, match="not a folder of this user's alone; set ITSKILL_LOCK_DIR"
    ) as err:
        directory_lock(tmp_path / "run", "run")
    assert is_unusable_path(err.value)
    elsewhere = tmp_path / "elsewhere"
    assert not elsewhere.exists() or not any(elsewhere.iterdir())


@pytest.mark.parametrize(
    ("named", "problem"),
    [
        # Read against each session's working directory: two sessions, two locks of one run.
        ("locks", "must name an absolute path"),
        ("./locks", "must name an absolute path"),
        ("~no_such_user_zz/locks", "cannot expand ~"),  # a RuntimeError traceback
    ],
)
def test_a_lock_folder_that_names_no_one_place_is_refused(
    tmp_path, monkeypatch, named: str, problem: str
) -> None:
    from itskill.files import LOCK_DIR_ENV, directory_lock, is_unusable_path

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(LOCK_DIR_ENV, named)
    with pytest.raises(PermissionError, match=problem) as err:
        directory_lock(tmp_path / "run", "run")
    assert is_unusable_path(err.value) and not (tmp_path / "locks").exists()


def test_a_lock_folder_named_with_a_tilde_is_the_home_folders(tmp_path, monkeypatch) -> None:
    from itskill.files import LOCK_DIR_ENV, lock_folder

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv(LOCK_DIR_ENV, "~/locks")
    assert lock_folder() == tmp_path / "locks"


def test_a_file_where_the_lock_folder_goes_is_said_so(tmp_path, monkeypatch) -> None:
    from itskill.files import LOCK_DIR_ENV, directory_lock, path_error_message

    (tmp_path / "locks").write_text("")
    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path / "locks"))
    with pytest.raises(PermissionError) as err:
        directory_lock(tmp_path / "run", "run")
    assert path_error_message(err.value).endswith(
        f"a file, where the folder of itskill's locks goes; set {LOCK_DIR_ENV} to a folder of "
        "your own, the same in every session on this machine"
    )


def test_a_folder_where_a_file_is_written_is_named_not_the_temporary_file(tmp_path) -> None:
    # "cannot use .../.report.md.23194.tmp: Is a directory" named a file the user never made.
    from itskill.files import path_error_message, write_json

    (tmp_path / "report.json").mkdir()
    with pytest.raises(IsADirectoryError) as err:
        write_json(tmp_path / "report.json", {"a": 1})
    assert path_error_message(err.value) == f"cannot use {tmp_path / 'report.json'}: Is a directory"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]  # no temporary left


def test_a_damaged_byte_after_a_byte_order_mark_is_named_where_it_is(tmp_path) -> None:
    from itskill.files import CorruptFileError, read_json

    path = tmp_path / "record.json"
    path.write_bytes(b'\xef\xbb\xbf{"a": "caf\xe9"}')
    with pytest.raises(CorruptFileError, match=r"not UTF-8 text \(byte 13\)"):
        read_json(path)
    path.write_bytes(b'\xef\xbb\xbf{"a": 1}')  # an editor's mark alone is not damage
    assert read_json(path) == {"a": 1}
