"""Statistics of experiments on hand-made curves with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import t as t_dist

from itskill.curves import Curve
from itskill.experiments.analysis import (
    best_evaluation,
    common_grid,
    efficiency_gain,
    interpolate,
    mean_band,
    success_at_fractions,
    threshold_gain,
    time_to_threshold,
)
from itskill.stats import mean_interval


def curve(steps, success, wall=None, budget=1000.0) -> Curve:
    steps = np.asarray(steps, float)
    wall = np.asarray(wall if wall is not None else steps / 10, float)
    return Curve(steps, np.asarray(success, float), wall, budget)


def test_interpolation_is_linear_inside_and_nan_outside_the_evaluated_range():
    c = curve([100, 200, 300], [0.0, 0.5, 1.0])
    got = interpolate(c, np.array([50, 100, 150, 300, 350]))
    assert np.isnan(got[0]) and np.isnan(got[-1])
    np.testing.assert_allclose(got[1:4], [0.0, 0.25, 1.0])


def test_common_grid_spans_first_evaluation_to_largest_budget():
    grid = common_grid(
        [curve([100, 200], [0, 1], budget=300), curve([50, 200], [0, 1], budget=400)], 8
    )
    assert grid[0] == 50 and grid[-1] == 400 and len(grid) == 8


def test_band_is_mean_with_student_t_interval_and_counts_seeds_per_point():
    curves = [curve([100, 200], [v, v]) for v in (0.5, 0.6, 0.7)]
    curves.append(curve([100], [0.9]))  # a run that stopped after its first evaluation
    band = mean_band(curves, np.array([100.0, 200.0]))
    assert list(band.n) == [4, 3]
    half = t_dist.ppf(0.975, 2) * 0.1 / math.sqrt(3)
    assert band.mean[1] == pytest.approx(0.6)
    assert band.low[1] == pytest.approx(0.6 - half)
    assert band.high[1] == pytest.approx(0.6 + half)
    assert band.mean[0] == pytest.approx((0.5 + 0.6 + 0.7 + 0.9) / 4)


def test_band_interval_is_clipped_to_valid_success_rates():
    band = mean_band([curve([100], [0.0]), curve([100], [1.0])], np.array([100.0]))
    assert band.low[0] == 0.0 and band.high[0] == 1.0


def test_success_at_budget_fractions_interpolates_each_seed():
    curves = [curve([200, 400, 600, 800, 1000], [0.2, 0.4, 0.6, 0.8, 1.0])] * 2
    got = success_at_fractions(curves, 1000, (0.1, 0.2, 0.5, 1.0))
    assert got[0].n == 0 and got[0].format() == "n/a"  # before the first evaluation
    assert [g.mean for g in got[1:]] == pytest.approx([0.2, 0.5, 1.0])
    assert got[2].format() == "50.0% (all 2 seeds)"  # no spread: no interval to show


def test_best_evaluation_is_each_seeds_peak_averaged_over_seeds():
    # A run that reached 90% and fell back to 10% still counts its peak.
    got = best_evaluation([curve([100, 200, 300], [0.5, 0.9, 0.1]), curve([100, 200], [0.3, 0.7])])
    assert got.mean == pytest.approx(0.8) and got.n == 2


def test_threshold_steps_and_wall_time_with_censoring():
    reached = curve([100, 200, 300], [0.1, 0.5, 0.85], wall=[5, 12, 30])
    never = curve([100, 200, 1000], [0.1, 0.5, 0.7], wall=[6, 13, 70])
    th = time_to_threshold([reached, never], 0.8)
    assert list(th.steps) == [300, 1000]  # the second is censored at its budget
    assert list(th.wall_s) == [30, 70]
    assert list(th.reached) == [True, False] and th.censored == 1
    assert th.format_steps().startswith("≥ 650")
    assert th.format_steps().endswith("(1/2 never reached)")
    none = time_to_threshold([never, never], 0.8)
    assert none.format_steps() == "≥ budget (2/2 never reached)"
    exact = time_to_threshold([reached, reached], 0.8)
    # Seeds that agree have no spread: the report says so rather than print "[300, 300]".
    assert exact.format_steps() == "300 (all 2 seeds)"
    assert exact.format_minutes() == "0.5 (all 2 seeds)"
    # Not where one of them is censored: "(all 2 seeds) (1/2 never reached)" said two things.
    at_budget = curve([100, 200, 1000], [0.1, 0.5, 0.85])
    assert "all" not in time_to_threshold([at_budget, never], 0.8).format_steps()


def test_threshold_interval_is_cut_to_zero_and_the_budget():
    early = curve([100, 200, 1000], [0.9, 0.9, 0.9])
    late = curve([100, 900, 1000], [0.1, 0.85, 0.9])
    th = time_to_threshold([early, late], 0.8)
    # Two seeds at 100 and 900: the t-interval 500 ± 5082 would say -4,582 to 5,582 env-steps.
    assert th.format_steps() == "500 [0, 1,000]"
    assert th.format_minutes().startswith("0.8 [0.0, ")


def test_a_crossing_after_the_budget_is_not_reached_within_it():
    # Training ends one rollout past its budget; the last evaluation there must not make a late
    # seed count as slower than one that never got there (a negative gain over a baseline that
    # never reached the threshold).
    late = curve([500, 1000, 1024], [0.5, 0.7, 0.8], budget=1000)
    never = curve([500, 1000, 1024], [0.5, 0.7, 0.7], budget=1000)
    th = time_to_threshold([late], 0.8)
    assert list(th.steps) == [1000] and not th.reached[0]
    gain = threshold_gain(th, time_to_threshold([never], 0.8))
    assert "-" not in gain.format()


def test_threshold_is_reached_at_equality():
    th = time_to_threshold([curve([100, 200], [0.8, 0.9])], 0.8)
    assert th.steps[0] == 100 and th.reached[0]


def test_gain_interval_is_each_sides_t_interval_carried_through_the_ratio():
    g = efficiency_gain([100, 100, 100], [400, 400, 400])
    assert (g.value, g.low, g.high, g.bound) == (pytest.approx(0.75), 0.75, 0.75, "exact")
    # A baseline without spread (every seed ran out the budget of 500): the gain's interval is
    # the method's t-interval over the budget, the figures the report prints beside it.
    mean, low, high = mean_interval([100, 200, 300])
    g = efficiency_gain([100, 200, 300], [500, 500, 500])
    assert g.value == pytest.approx(1 - mean / 500)
    # (cut at zero: the method's lower bound, -48, is not a time)
    assert low < 0 and (g.low, g.high) == (pytest.approx(1 - high / 500), 1.0)
    # Cut at 100%: a time to threshold is never negative.
    wide = efficiency_gain([0, 100, 500], [500, 500, 500])
    assert wide.high == 1.0 and wide.low < wide.value
    # A baseline whose own interval reaches zero leaves the ratio unbounded (Fieller).
    g = efficiency_gain([100, 200, 300], [20, 30, 900])
    assert math.isinf(g.low) and "unbounded" in g.format()
    # One seed on a side: nothing to estimate the spread from, and the report says so.
    g = efficiency_gain([100], [400, 400])
    assert math.isnan(g.low) and g.format() == "75.0% (one seed: no interval)"


def test_gain_interval_covers_the_true_gain_95_percent_of_the_time():
    # Three seeds a side, times to threshold normal around 200 and 300 env-steps (true gain 1/3).
    # A percentile bootstrap over so few seeds covered it 80% of the time.
    rng = np.random.default_rng(1)
    trials = 2000
    method = rng.normal(200, 40, (trials, 3))
    baseline = rng.normal(300, 60, (trials, 3))
    covered = sum(
        not efficiency_gain(m, b).excludes(1 / 3) for m, b in zip(method, baseline, strict=True)
    )
    assert 0.92 <= covered / trials <= 0.99


def test_gain_marks_the_direction_of_censoring():
    assert efficiency_gain([1], [2], 0, 1).bound == "lower"
    assert efficiency_gain([1], [2], 1, 0).bound == "upper"
    assert efficiency_gain([1], [2], 1, 1).bound == "unknown"
    assert efficiency_gain([1], [2], 0, 1).format().startswith("≥ 50.0%")
    assert math.isnan(efficiency_gain([], [2]).value)


def test_threshold_gain_in_steps_and_wall_time():
    fast = time_to_threshold([curve([100, 200], [0.9, 0.9], wall=[10, 20])], 0.8)
    slow = time_to_threshold([curve([100, 400], [0.1, 0.9], wall=[10, 80])], 0.8)
    assert threshold_gain(fast, slow, "steps").value == pytest.approx(0.75)
    assert threshold_gain(fast, slow, "wall_s").value == pytest.approx(1 - 10 / 80)
    never = time_to_threshold([curve([100, 400], [0.1, 0.2])], 0.8)
    assert threshold_gain(never, never).format() == "n/a"  # nothing to compare
    with pytest.raises(ValueError, match="use must be"):
        threshold_gain(fast, slow, "minutes")
