"""TOML data files: whatever is wrong with the file, the error names the file and the problem."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from itskill.datafile import DataFileError, read_toml


def test_a_valid_file_reads(tmp_path: Path) -> None:
    path = tmp_path / "data.toml"
    path.write_text("[search]\nsamples = 3\n")
    assert read_toml(path) == {"search": {"samples": 3}}


@pytest.mark.parametrize(
    ("make", "where", "problem"),
    [
        (lambda p: None, "file", "no such file"),
        # A directory or a binary file given for a TOML option was an IsADirectoryError or
        # UnicodeDecodeError traceback.
        (lambda p: p.mkdir(), "file", "is a directory"),
        (lambda p: p.write_bytes(b"\xff\xfe\x00bad"), "file", "not UTF-8 text"),
        (lambda p: p.write_text("[table\n"), "TOML syntax", "line 1"),
    ],
)
def test_an_unreadable_file_names_the_file_and_the_problem(
    tmp_path: Path, make: Callable[[Path], object], where: str, problem: str
) -> None:
    path = tmp_path / "data.toml"
    make(path)
    with pytest.raises(DataFileError) as info:
        read_toml(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert problem in info.value.problem
