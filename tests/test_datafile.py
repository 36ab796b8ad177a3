"""TOML data files: whatever is wrong with the file, the error names the file and the problem."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from itskill.datafile import (
    DataFileError,
    check_like,
    check_nonnegative,
    check_positive,
    check_table,
    check_type,
    is_number,
    read_toml,
)


def test_a_valid_file_reads(tmp_path: Path) -> None:
    path = tmp_path / "data.toml"
    path.write_text("[search]\nsamples = 3\n")
    assert read_toml(path) == {"search": {"samples": 3}}


def test_a_file_saved_with_a_byte_order_mark_reads_and_bad_bytes_are_counted_from_it(
    tmp_path: Path,
) -> None:
    # Windows Notepad saves UTF-8 with a byte-order mark: TOML syntax error at line 1, column 1.
    path = tmp_path / "data.toml"
    path.write_bytes(b"\xef\xbb\xbf[search]\nsamples = 3\n")
    assert read_toml(path) == {"search": {"samples": 3}}
    path.write_bytes(b"\xef\xbb\xbf[search]\nname = '\xe9'\n")
    with pytest.raises(DataFileError, match=r"not UTF-8 text \(byte 20\)"):
        read_toml(path)


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
    "written",
    # A file can hold all of these: 1e999 reads as inf, and an integer of any length is an int.
    ["nan", "inf", "-inf", "1e999", "1" + "0" * 400],
)
def test_a_float_field_refuses_what_is_no_finite_number(tmp_path: Path, written: str) -> None:
    # They passed, and reached training as "Invalid learning rate: nan" or NaN losses.
    path = tmp_path / "hp.toml"
    path.write_text(f"learning_rate = {written}\n")
    value = read_toml(path)["learning_rate"]
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


@pytest.mark.parametrize(
    ("value", "kind", "problem"),
    [
        (True, int, "expected an integer, got bool True"),  # TOML's booleans are Python ints
        (1, bool, "expected a boolean, got int 1"),
        ("3", (int, float), "expected an integer or a number, got str '3'"),
        pytest.param(10**400, float, "expected a finite number", id="past-float-range"),
        (math.nan, float, "expected a finite number, got nan"),
        ([1], dict, "expected a table, got list [1]"),
    ],
)
def test_a_value_of_another_type_names_the_type_expected(value, kind, problem) -> None:
    with pytest.raises(DataFileError) as err:
        check_type("f.toml", "a.b", value, kind, DataFileError)
    assert err.value.where == "a.b" and err.value.problem.startswith(problem)


def test_a_value_of_its_type_is_returned_a_float_fields_integer_as_a_float() -> None:
    assert check_type("f.toml", "x", 3, float, DataFileError) == 3.0
    assert isinstance(check_type("f.toml", "x", 3, float, DataFileError), float)
    assert check_type("f.toml", "x", 3, (int, float), DataFileError) == 3  # stays an integer
    assert check_type("f.toml", "x", False, bool, DataFileError) is False


def test_a_table_with_a_misspelt_key_names_it_and_the_known_ones() -> None:
    with pytest.raises(DataFileError) as err:
        check_table(
            "f.toml",
            "search",
            {"samples": 3, "iteratons": 2},
            DataFileError,
            {"samples", "iterations"},
        )
    assert err.value.where == "search.iteratons"
    assert err.value.problem == "unknown field; expected one of iterations, samples"
    top = {"serach": {}}
    with pytest.raises(DataFileError, match=r"^f.toml: serach: unknown table; expected one of"):
        check_table("f.toml", "", top, DataFileError, {"search"}, "table")


@pytest.mark.parametrize(
    ("value", "problem"),
    [
        (0, "must be positive, got 0"),
        (2000, "must be at most 1,000, got 2,000"),
        (1.0, "expected an integer"),
    ],
)
def test_a_count_out_of_its_bounds_says_which(value, problem) -> None:
    with pytest.raises(DataFileError, match=problem):
        check_positive("f.toml", "n", value, DataFileError, most=1000)
    assert check_positive("f.toml", "n", 1000, DataFileError, most=1000) == 1000


@pytest.mark.parametrize(
    ("value", "positive", "problem"),
    [
        (-0.5, False, r"expected a finite number >= 0 \(USD\), got -0.5"),
        (0, True, r"expected a finite number > 0 \(USD\), got 0"),
        (True, False, "got True"),  # TOML's true is no price
        (math.nan, False, "got nan"),
        (10**400, False, "got 1000"),  # past a float's range
        ("1", False, "got '1'"),
    ],
)
def test_an_amount_below_its_bound_or_no_number_is_refused(value, positive, problem) -> None:
    with pytest.raises(DataFileError, match=problem):
        check_nonnegative("f.toml", "price", value, DataFileError, positive, unit="USD")


def test_an_amount_within_its_bound_is_returned_as_a_float() -> None:
    assert check_nonnegative("f.toml", "w", 0, DataFileError) == 0.0
    assert isinstance(check_nonnegative("f.toml", "w", 3, DataFileError, positive=True), float)
