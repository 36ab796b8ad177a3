"""Statistics for reported results: success-rate intervals, means with intervals, thresholds.

A leaf module (NumPy and SciPy only), so every layer can report the same way.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from statistics import NormalDist

import numpy as np
from scipy.stats import binomtest
from scipy.stats import t as t_dist


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a success rate of ``successes`` out of ``n`` trials.

    Preferred over the normal approximation because it stays inside [0, 1] and is sensible at
    rates of 0 or 1, which short scripted or early-training evaluations often produce.
    """
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, {n}], got {successes}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # At p = 0 or 1 the bound is exactly 0 or 1; floating point leaves a residue of ~1e-17.
    low = 0.0 if successes == 0 else centre - half
    high = 1.0 if successes == n else centre + half
    return low, high


def mean_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float, float]:
    """Mean of ``values`` with its Student-t confidence interval (seeds are few, so not normal).

    One value, or equal values, give an interval of zero width: there is no spread to estimate.
    """
    data = np.asarray(values, dtype=float)
    if data.size == 0:
        raise ValueError("no values")
    mean = float(data.mean())
    if np.all(data == data[0]):  # one value, or equal values whose std rounds to 1e-17, not 0
        return mean, mean, mean
    half = float(t_dist.ppf(0.5 + confidence / 2, data.size - 1) * data.std(ddof=1))
    half /= math.sqrt(data.size)
    return mean, mean - half, mean + half


def ratio_interval(
    numerator: Sequence[float], denominator: Sequence[float], confidence: float = 0.95
) -> tuple[float, float, float]:
    """``mean(numerator) / mean(denominator)`` of two independent samples with its interval.

    The delta method with Welch-Satterthwaite degrees of freedom: each mean's Student-t
    uncertainty (as :func:`mean_interval` has it) carried through the ratio, so a denominator
    without spread gives exactly the numerator's t-interval divided by its mean. With fewer than
    two values on either side there is no spread to estimate: the bounds are NaN. Where the
    denominator's own t-interval reaches zero the ratio is unbounded (Fieller's interval is), and
    so are the bounds: -inf and inf.
    """
    num, den = np.asarray(numerator, dtype=float), np.asarray(denominator, dtype=float)
    if num.size == 0 or den.size == 0:
        raise ValueError("no values")
    if den.mean() == 0:
        raise ValueError("the denominator's mean is zero")
    ratio = float(num.mean() / den.mean())
    if num.size < 2 or den.size < 2:
        return ratio, math.nan, math.nan
    u = num.var(ddof=1) / num.size / den.mean() ** 2
    v = ratio**2 * den.var(ddof=1) / den.size / den.mean() ** 2
    if u + v == 0:
        return ratio, ratio, ratio
    _, den_low, den_high = mean_interval(den, confidence)
    if den_low <= 0 <= den_high:
        return ratio, -math.inf, math.inf
    df = (u + v) ** 2 / (u**2 / (num.size - 1) + v**2 / (den.size - 1))
    half = float(t_dist.ppf(0.5 + confidence / 2, df) * math.sqrt(u + v))
    return ratio, ratio - half, ratio + half


def format_rate(value: float | None) -> str:
    """A success rate as a whole percentage, ``"-"`` where there is none (yet)."""
    return "-" if value is None else f"{value:.0%}"


def paired_wins(new: Sequence[bool], old: Sequence[bool]) -> tuple[int, int]:
    """Of the episodes both policies ran, those only ``new`` succeeded in and those only ``old``
    did: the discordant pairs a paired comparison rests on."""
    if len(new) != len(old):
        raise ValueError(f"outcomes of {len(new)} and {len(old)} episodes cannot be paired")
    won = sum(bool(a) and not b for a, b in zip(new, old, strict=True))
    lost = sum(bool(b) and not a for a, b in zip(new, old, strict=True))
    return won, lost


def paired_gain_p(won: int, lost: int) -> float:
    """One-sided exact McNemar test that a policy succeeds more often than another on the same
    episodes (:func:`paired_wins`): the chance under a fair coin of winning at least ``won`` of
    the ``won + lost`` episodes where they differ. Pairing removes each episode's own difficulty,
    which two separate intervals would count against both."""
    if won + lost == 0:
        return 1.0
    return float(binomtest(won, won + lost, 0.5, alternative="greater").pvalue)


def format_rate_interval(mean: float, low: float, high: float, decimals: int = 0) -> str:
    """A success rate with its interval as ``"75% [57%, 93%]"``; a t-interval over few seeds can
    reach past 0 or 1, where no rate can lie, so it is cut to that range. ``decimals=1`` suits
    rates over hundreds of episodes, where whole percents would round 94.75% up to a 95% target."""
    f = f".{decimals}%"
    return f"{mean:{f}} [{max(low, 0.0):{f}}, {min(high, 1.0):{f}}]"


def steps_to_threshold(
    steps: Sequence[float], values: Sequence[float], threshold: float
) -> float | None:
    """The first of ``steps`` at which ``values`` reaches ``threshold``; None if it never does."""
    for step, value in zip(steps, values, strict=True):
        if value >= threshold:
            return float(step)
    return None
