import math

import pytest

from itskill.stats import (
    format_rate_interval,
    mean_interval,
    paired_gain_p,
    paired_wins,
    ratio_interval,
    steps_to_threshold,
    wilson_interval,
)


@pytest.mark.parametrize(
    ("successes", "n", "confidence", "expected"),
    [
        # 81/263 is a textbook worked example; the others were computed by hand.
        (81, 263, 0.95, (0.2553, 0.3662)),
        (50, 100, 0.95, (0.4038, 0.5962)),
        (0, 10, 0.95, (0.0, 0.2775)),
        (10, 10, 0.95, (0.7225, 1.0)),
        (95, 100, 0.99, (0.8609, 0.9832)),
    ],
)
def test_known_values(successes, n, confidence, expected):
    low, high = wilson_interval(successes, n, confidence)
    assert low == pytest.approx(expected[0], abs=1e-4)
    assert 0.0 <= low <= high <= 1.0
    assert high == pytest.approx(expected[1], abs=1e-4)


def test_interval_contains_rate_and_narrows_with_n():
    low1, high1 = wilson_interval(30, 60)
    low2, high2 = wilson_interval(300, 600)
    assert low1 < 0.5 < high1
    assert high2 - low2 < high1 - low1


@pytest.mark.parametrize(
    ("successes", "n", "confidence", "message"),
    [
        (1, 0, 0.95, "n must be positive, got 0"),
        # Without their own check these two would still raise ValueError, from math.sqrt.
        (-1, 5, 0.95, r"successes must be in \[0, 5\], got -1"),
        (6, 5, 0.95, r"successes must be in \[0, 5\], got 6"),
        # 0 would give an interval of zero width without an error; 1 and a percentage would fail
        # inside NormalDist, with a message about its own argument.
        (3, 5, 0.0, r"confidence must be in \(0, 1\), got 0.0"),
        (3, 5, 1.0, r"confidence must be in \(0, 1\), got 1.0"),
        (3, 5, 95, r"confidence must be in \(0, 1\), got 95"),
    ],
)
def test_rejects_bad_counts_and_confidence(successes, n, confidence, message):
    with pytest.raises(ValueError, match=message):
        wilson_interval(successes, n, confidence)


def test_mean_interval_uses_student_t() -> None:
    mean, low, high = mean_interval([1.0, 2.0, 3.0])
    assert mean == pytest.approx(2.0)
    # t(0.975, 2) = 4.303, sd = 1, n = 3: half width 4.303 / sqrt(3) = 2.484
    assert high - mean == pytest.approx(2.484, abs=1e-3)
    assert mean - low == pytest.approx(high - mean)
    assert mean_interval([0.5]) == (0.5, 0.5, 0.5)


def test_steps_to_threshold_is_the_first_crossing() -> None:
    steps = [10, 20, 30, 40]
    assert steps_to_threshold(steps, [0.1, 0.85, 0.7, 0.95], 0.8) == 20
    assert steps_to_threshold(steps, [0.1, 0.2, 0.3, 0.4], 0.8) is None


def test_a_rate_interval_is_cut_to_what_a_rate_can_be() -> None:
    assert format_rate_interval(0.75, 0.5712, 0.9288) == "75% [57%, 93%]"
    assert format_rate_interval(0.65, 0.0621, 1.2445) == "65% [6%, 100%]"
    assert format_rate_interval(0.35, -0.1123, 0.8056) == "35% [0%, 81%]"
    assert format_rate_interval(0.9475, 0.9211, 0.9651, decimals=1) == "94.8% [92.1%, 96.5%]"


def test_a_paired_comparison_counts_only_the_episodes_the_policies_differ_on() -> None:
    old = [True, True, False, False, True, False]
    new = [True, False, True, True, True, False]
    assert paired_wins(new, old) == (2, 1)
    # 2 of 3 under a fair coin: P(X >= 2) = 4/8.
    assert paired_gain_p(2, 1) == pytest.approx(0.5)
    assert paired_gain_p(0, 0) == 1.0
    # 15 won, 3 lost: what a refined skill gaining three points on 400 episodes can look like.
    assert paired_gain_p(15, 3) < 0.01 < paired_gain_p(6, 3)
    with pytest.raises(ValueError, match="cannot be paired"):
        paired_wins(new, old[:-1])


def test_ratio_interval_of_two_independent_means():
    # A denominator without spread: the numerator's t-interval over its mean.
    _, low, high = mean_interval([1.0, 2.0, 3.0])
    assert ratio_interval([1.0, 2.0, 3.0], [4.0, 4.0]) == pytest.approx((0.5, low / 4, high / 4))
    ratio, low, high = ratio_interval([1.0, 2.0, 3.0], [3.0, 4.0, 5.0])
    assert ratio == pytest.approx(0.5) and low < 0.5 < high
    assert ratio_interval([1.0], [2.0, 2.0])[0] == 0.5
    assert all(math.isnan(x) for x in ratio_interval([1.0], [2.0, 3.0])[1:])
    with pytest.raises(ValueError, match="zero"):
        ratio_interval([1.0], [0.0, 0.0])
