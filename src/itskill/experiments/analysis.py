"""Statistics of an experiment: learning curves over seeds, success at budget fractions, time to a
success threshold with censoring, and the time-efficiency gain of a method over a baseline.

Everything here works on plain arrays (one :class:`~itskill.curves.Curve` per seed), so it is
tested on hand-made curves with known answers; reading run directories is
:func:`itskill.curves.read_curve`'s only job.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from itskill.curves import Curve
from itskill.stats import mean_interval, ratio_interval, steps_to_threshold


def common_grid(curves: Sequence[Curve], points: int = 101) -> np.ndarray:
    """Evenly spaced env-steps from the earliest evaluation of any curve to the largest budget."""
    if not curves:
        raise ValueError("no curves")
    starts = [c.steps[0] for c in curves if len(c.steps)]
    if not starts:
        raise ValueError("every curve is empty")
    return np.linspace(min(starts), max(c.budget for c in curves), points)


def interpolate(curve: Curve, grid: np.ndarray) -> np.ndarray:
    """Success on ``grid`` by linear interpolation; NaN outside the evaluated range.

    No extrapolation: before the first evaluation nothing was measured, and after the last one a
    run that stopped early (not finished yet) has nothing to say either.
    """
    grid = np.asarray(grid, dtype=float)
    out = np.full(grid.shape, np.nan)
    if len(curve.steps) == 0:
        return out
    inside = (grid >= curve.steps[0]) & (grid <= curve.steps[-1])
    out[inside] = np.interp(grid[inside], curve.steps, curve.success)
    return out


@dataclass(frozen=True)
class Band:
    """Mean over seeds on a grid with its 95% t-interval; ``n`` seeds contribute at each point."""

    grid: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    n: np.ndarray


def mean_band(curves: Sequence[Curve], grid: np.ndarray, confidence: float = 0.95) -> Band:
    """Mean success over ``curves`` at each grid point with its Student-t interval.

    At a point only some seeds reach (a run still in progress) the statistics use those seeds;
    ``n`` says how many. The interval is clipped to [0, 1]: a success rate cannot leave it.
    """
    values = np.stack([interpolate(c, grid) for c in curves])
    mean = np.full(len(grid), np.nan)
    low, high = mean.copy(), mean.copy()
    n = np.sum(~np.isnan(values), axis=0)
    for j in np.flatnonzero(n):
        column = values[:, j]
        mean[j], low[j], high[j] = mean_interval(column[~np.isnan(column)], confidence)
    return Band(grid, mean, np.clip(low, 0, 1), np.clip(high, 0, 1), n)


@dataclass(frozen=True)
class Estimate:
    """A mean success rate over seeds with its 95% t-interval; NaN where nothing was measured."""

    mean: float
    low: float
    high: float
    n: int

    def format(self, digits: int = 1) -> str:
        """A success rate: ``mean [low, high]``, the interval cut to 0–100%. Seeds that all
        measured the same rate say so: their t-interval has no width, which is not certainty
        (0 successes in 200 episodes is still compatible with a rate of 1–2%)."""
        if self.n == 0 or math.isnan(self.mean):
            return "n/a"
        text = f"{self.mean:.{digits}%}"
        if self.n == 1:
            return text
        if self.high == self.low:
            return f"{text} (all {self.n} seeds)"
        low, high = max(self.low, 0.0), min(self.high, 1.0)
        return f"{text} [{low:.{digits}%}, {high:.{digits}%}]"


def estimate(values: Sequence[float], confidence: float = 0.95) -> Estimate:
    """Mean and t-interval of the finite ``values`` (NaNs are runs that measured nothing)."""
    data = np.asarray(values, dtype=float)
    data = data[~np.isnan(data)]
    if data.size == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    return Estimate(*mean_interval(data, confidence), int(data.size))


def success_at(curves: Sequence[Curve], steps: float, confidence: float = 0.95) -> Estimate:
    """Success at ``steps`` env-steps over seeds (interpolated between evaluations)."""
    return estimate([interpolate(c, np.array([steps]))[0] for c in curves], confidence)


def success_at_fractions(
    curves: Sequence[Curve], budget: float, fractions: Sequence[float]
) -> list[Estimate]:
    """Table II: success at each fraction of ``budget``, mean over seeds with its interval."""
    return [success_at(curves, f * budget) for f in fractions]


def best_evaluation(curves: Sequence[Curve], confidence: float = 0.95) -> Estimate:
    """Each seed's highest evaluation, mean over seeds: what a run keeping its best policy holds.

    Optimistic by construction (the maximum of noisy evaluations); set beside the curve's value at
    the budget, it shows how much of a level reached was later lost.
    """
    return estimate([float(np.max(c.success)) for c in curves], confidence)


@dataclass(frozen=True)
class Threshold:
    """Env-steps and wall time to reach a success threshold, one value per seed.

    A seed that never reaches it is censored at its budget (``reached`` False): its value is the
    budget, so the mean is a lower bound whenever any seed is censored.
    """

    steps: np.ndarray
    wall_s: np.ndarray
    reached: np.ndarray
    budget: float = math.inf
    """The largest budget of the seeds: no mean of ``steps`` can lie above it."""

    @property
    def censored(self) -> int:
        return int(np.sum(~self.reached))

    @property
    def n(self) -> int:
        return len(self.reached)

    def steps_estimate(self) -> Estimate:
        return estimate(self.steps)

    def wall_estimate(self) -> Estimate:
        return estimate(self.wall_s)

    def format_steps(self) -> str:
        return self._format(self.steps_estimate(), lambda v: f"{v:,.0f}", self.budget)

    def format_minutes(self) -> str:
        return self._format(self.wall_estimate(), lambda v: f"{v / 60:.1f}", math.inf)

    def _format(self, est: Estimate, fmt, upper: float) -> str:
        if self.n == 0:
            return "n/a"
        if self.censored == self.n:
            return f"≥ budget ({self.n}/{self.n} never reached)"
        text = fmt(est.mean)
        if est.n > 1 and est.high == est.low and not self.censored:
            # Seeds that all reached it at one evaluation have no spread: not certainty.
            text += f" (all {est.n} seeds)"
        elif est.n > 1:
            # With few seeds a t-interval can reach below zero or past the budget, where no
            # mean of these values can lie: it is cut to the possible range.
            text += f" [{fmt(max(est.low, 0.0))}, {fmt(min(est.high, upper))}]"
        if self.censored:
            return f"≥ {text} ({self.censored}/{self.n} never reached)"
        return text


def time_to_threshold(curves: Sequence[Curve], threshold: float) -> Threshold:
    """First evaluated env-step (and training wall time) at which success ≥ ``threshold``.

    Censored at the budget, and at the training wall time of the last evaluation, for a seed
    that does not reach it within the budget (training ends up to one rollout past it, and a
    crossing at that last evaluation would otherwise count as reached later than a seed censored
    at the budget).
    """
    steps, walls, reached = [], [], []
    for c in curves:
        hit = steps_to_threshold(c.steps, c.success, threshold)
        if hit is None or hit > c.budget:
            steps.append(c.budget)
            walls.append(float(c.wall_s[-1]) if len(c.wall_s) else math.nan)
            reached.append(False)
        else:
            steps.append(hit)
            walls.append(float(c.wall_s[np.searchsorted(c.steps, hit)]))
            reached.append(True)
    return Threshold(
        np.array(steps, float),
        np.array(walls, float),
        np.array(reached, bool),
        max((c.budget for c in curves), default=math.inf),
    )


@dataclass(frozen=True)
class Gain:
    """``1 - mean(method) / mean(baseline)`` with its interval over seeds (NaN bounds: one seed).

    ``bound`` says how censoring affects the point estimate: "exact" (no seed censored),
    "lower" (only the baseline has censored seeds: its true mean is larger, so the true gain is
    too), "upper" (only the method has), "unknown" (both have).
    """

    value: float
    low: float
    high: float
    bound: str

    def format(self) -> str:
        if math.isnan(self.value):
            return "n/a"
        prefix = {"exact": "", "lower": "≥ ", "upper": "≤ ", "unknown": "~"}[self.bound]
        text = f"{prefix}{self.value:.1%}"
        if math.isnan(self.low):
            text += " (one seed: no interval)"
        elif self.low == self.high:
            text += " (the seeds agree: no spread to estimate an interval from)"
        elif math.isinf(self.low):
            text += " [unbounded: the baseline's interval reaches zero]"
        else:
            text += f" [{self.low:.1%}, {self.high:.1%}]"
        return text + (" (censored on both sides)" if self.bound == "unknown" else "")

    @property
    def has_interval(self) -> bool:
        """Whether the seeds' spread gave an interval (not one seed, not seeds that agree)."""
        return not math.isnan(self.low) and self.low < self.high

    def excludes(self, value: float) -> bool:
        """Whether the interval lies wholly on one side of ``value`` (False without one)."""
        return self.has_interval and not self.low <= value <= self.high


def efficiency_gain(
    method: Sequence[float],
    baseline: Sequence[float],
    method_censored: int = 0,
    baseline_censored: int = 0,
    confidence: float = 0.95,
) -> Gain:
    """Time-efficiency gain of ``method`` over ``baseline`` from per-seed times to threshold.

    The interval is :func:`itskill.stats.ratio_interval`'s for the ratio of the two means (the
    methods' seeds are independent, not paired): the t-intervals the report prints for each
    side's mean, carried through, and cut at 100% (times are never negative). In env-steps a
    baseline whose seeds all ran out the budget adds no spread, and the gain's interval is then
    the method's t-interval (cut at zero) over the budget; in wall time such seeds keep each its
    own training time, which does spread. With one seed on either side, or seeds that all agree,
    it has none.
    """
    m = np.asarray(method, float)
    b = np.asarray(baseline, float)
    m, b = m[~np.isnan(m)], b[~np.isnan(b)]
    if m.size == 0 or b.size == 0 or b.mean() <= 0:
        return Gain(math.nan, math.nan, math.nan, "exact")
    ratio, low, high = ratio_interval(m, b, confidence)
    low = max(low, 0.0)  # times are never negative: a gain above 100% is impossible
    bound = {
        (False, False): "exact",
        (False, True): "lower",
        (True, False): "upper",
        (True, True): "unknown",
    }[(method_censored > 0, baseline_censored > 0)]
    return Gain(1.0 - ratio, 1.0 - high, 1.0 - low, bound)


def threshold_gain(method: Threshold, baseline: Threshold, use: str = "steps") -> Gain:
    """:func:`efficiency_gain` from two :class:`Threshold` results, in env-steps or wall time."""
    if use not in ("steps", "wall_s"):
        raise ValueError(f"use must be 'steps' or 'wall_s', got {use!r}")
    if method.censored == method.n and baseline.censored == baseline.n:
        return Gain(math.nan, math.nan, math.nan, "unknown")  # neither ever reached it
    return efficiency_gain(
        getattr(method, use), getattr(baseline, use), method.censored, baseline.censored
    )
