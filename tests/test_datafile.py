"""TOML data files: whatever is wrong with the file, the error names the file and the problem."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from itskill.datafile import DataFileError, check_like, is_number, read_toml


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


class _Bad(DataFileError):
    """The error a loader passes to :func:`check_like`."""


@pytest.mark.parametrize(
    "value",
    # TOML writes all of these; 1e999 reads as inf, and an integer of any length is an int.
    [math.nan, math.inf, -math.inf, float("1e999"), 10**400],
)
def test_a_float_field_refuses_what_is_no_finite_number(value: float | int) -> None:
    # They passed, and reached training as "Invalid learning rate: nan" or NaN losses.
    with pytest.raises(_Bad) as info:
        check_like("hp.toml", "nutbolt.ppo.learning_rate", value, 3e-4, _Bad)
    assert (info.value.path, info.value.where) == ("hp.toml", "nutbolt.ppo.learning_rate")
    assert "expected a finite number" in info.value.problem


def test_a_float_field_still_takes_finite_numbers_and_integers() -> None:
    assert check_like("f.toml", "t.k", 3, 0.5, _Bad) == 3.0
    assert check_like("f.toml", "t.k", -1e300, 0.5, _Bad) == -1e300


def test_an_integer_past_a_floats_range_is_no_number() -> None:
    # math.isfinite raised OverflowError on it: a traceback from every reader that asks.
    assert not is_number(10**400)
    assert is_number(10**300) and not is_number(True)


def test_an_integer_too_long_for_python_is_named_not_a_traceback(tmp_path: Path) -> None:
    path = tmp_path / "data.toml"
    path.write_text("[search]\nsamples = " + "9" * (sys.get_int_max_str_digits() + 1) + "\n")
    with pytest.raises(DataFileError) as info:
        read_toml(path)
    assert (info.value.path, info.value.where) == (str(path), "file")
    assert "digits" in info.value.problem and "sys." not in info.value.problem
