"""Reading the trainer's evaluation file as a learning curve."""

from __future__ import annotations

import pytest

from itskill.curves import CurveError, NoEvaluationsError, read_curve


def test_read_curve_drops_rows_superseded_by_a_resumed_session(tmp_path):
    # Session 1 evaluated at 100..300 and was killed; its last checkpoint was at 200.
    # Session 2 resumed from 200: its wall time restarts (as in older releases) and it
    # re-evaluates 300.
    (tmp_path / "eval.csv").write_text(
        "env_steps,wall_s,success,ci_low,ci_high,mean_length\n"
        "100,10,0.1,0,1,50\n200,20,0.3,0,1,50\n300,30,0.5,0,1,50\n"
        "300,9,0.4,0,1,50\n400,19,0.6,0,1,50\n"
    )
    c = read_curve(tmp_path, 400)
    assert list(c.steps) == [100, 200, 300, 400]
    assert list(c.success) == [0.1, 0.3, 0.4, 0.6]
    assert list(c.wall_s) == [10, 20, 29, 39]


def test_read_curve_keeps_a_clock_that_goes_on_across_sessions(tmp_path):
    # Today's trainer resumes its clock from the checkpoint (at 200, 21 s of training): the
    # resumed session's rows need no offset, only the superseded 300 goes.
    (tmp_path / "eval.csv").write_text(
        "env_steps,wall_s,success\n100,10,0.1\n200,20,0.3\n300,30,0.5\n300,31,0.4\n400,41,0.6\n"
    )
    c = read_curve(tmp_path, 400)
    assert list(c.steps) == [100, 200, 300, 400]
    assert list(c.wall_s) == [10, 20, 31, 41]


def test_read_curve_errors_name_the_file_and_problem(tmp_path):
    # Not evaluated yet (the reward search then measures the final policy) is told apart from
    # a damaged file (the candidate fails, naming it).
    with pytest.raises(NoEvaluationsError, match=r"eval\.csv: missing"):
        read_curve(tmp_path, 100)
    (tmp_path / "eval.csv").write_text("env_steps,success\n100,0.5\n")
    with pytest.raises(CurveError, match="missing column") as damaged:
        read_curve(tmp_path, 100)
    assert not isinstance(damaged.value, NoEvaluationsError)
    (tmp_path / "eval.csv").write_text("env_steps,wall_s,success\n100,x,0.5\n")
    with pytest.raises(CurveError, match="not a number"):
        read_curve(tmp_path, 100)
    # A run stopped before its first evaluation: read as an empty curve, the report failed.
    (tmp_path / "eval.csv").write_text("env_steps,wall_s,success\n")
    with pytest.raises(NoEvaluationsError, match=r"eval\.csv: no evaluations"):
        read_curve(tmp_path, 100)
    # A damaged byte: the report notes the cell's file instead of stopping with a traceback.
    (tmp_path / "eval.csv").write_bytes(b"env_steps,wall_s,success\n100,1,0.5\n\xff\xfe,2,0.6\n")
    with pytest.raises(CurveError, match=r"eval\.csv: not UTF-8 text \(byte 35\)"):
        read_curve(tmp_path, 100)


@pytest.mark.parametrize(
    ("rows", "problem"),
    [
        # A success of 7.5 reached the report as 148% over five seeds.
        ("100,1,0.5\n200,2,7.5\n", r"line 3: success 7.5 is not a fraction in \[0, 1\]"),
        ("100,1,-0.1\n", r"line 2: success -0.1 is not"),
        ("100,1,nan\n", r"line 2: success nan is not"),
        ("-100,1,0.5\n", "line 2: env_steps and wall_s must be numbers >= 0"),
        ("100,inf,0.5\n", "line 2: env_steps and wall_s must be numbers >= 0"),
    ],
)
def test_read_curve_refuses_values_no_evaluation_writes(tmp_path, rows, problem):
    (tmp_path / "eval.csv").write_text("env_steps,wall_s,success\n" + rows)
    with pytest.raises(CurveError, match=problem):
        read_curve(tmp_path, 1000)


def test_read_curve_names_the_line_past_blank_ones(tmp_path):
    (tmp_path / "eval.csv").write_text("env_steps,wall_s,success\n100,1,0.5\n\n200,2,7.5\n")
    with pytest.raises(CurveError, match=r"line 4: success 7\.5"):
        read_curve(tmp_path, 1000)
