"""Final returns over seeds, Welch's test between two sides, and the time a curve takes to reach a return."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats

from experiments.original.curves import SeedCurves
from experiments.original.runs import Settings
from swat_jax.runs.metrics import standard_error

SIGNIFICANCE = 0.05
"""Welch's p below this: the two sides' final returns differ beyond the noise."""


@dataclasses.dataclass(frozen=True)
class Final:
    """Each seed's final return (mean over bodies, averaged over the last points of the budget)."""

    values: np.ndarray
    """[seeds]; NaN for a seed without one (its run ended short of the budget's last points)."""

    def finite(self) -> Final:
        """The seeds that have a final return."""
        return Final(self.values[np.isfinite(self.values)])

    @property
    def mean(self) -> float:
        """The mean over the seeds that have a final return."""
        return float(np.mean(self.finite().values))

    @property
    def standard_error(self) -> float:
        return standard_error(self.finite().values)

    def cell(self) -> str:
        """``mean ± standard error`` for a table, with how many seeds have a final return when some do not
        (never NaN)."""
        count = len(self.finite().values)
        if not count:
            return "no seed reached the budget"
        seeds = f"{count} of {len(self.values)} seeds"
        if count == 1:
            return f"{self.mean:.1f} ({seeds if len(self.values) > 1 else '1 seed'})"
        return f"{self.mean:.1f} ± {self.standard_error:.1f}" + (
            "" if count == len(self.values) else f", {seeds}"
        )


def final_returns(
    curves: Sequence[SeedCurves], settings: Settings, environment_set: str, body: str | None = None
) -> Final:
    """Each seed's mean over the points of the budget's last ``final_fraction`` (points past the budget left
    out): of the mean over bodies, or of ``body``'s curve; NaN for a seed without such points (a run that
    ended short)."""
    lines = [curve.mean_over_bodies() if body is None else curve.returns[body] for curve in curves]
    return Final(np.array([final_value(line, settings, environment_set) for line in lines]))


def final_value(line: Mapping[int, float], settings: Settings, environment_set: str) -> float:
    """The mean of ``line`` ({grid step: value}) over the points of the budget's last ``final_fraction``;
    NaN if it has none."""
    budget = settings.budget(environment_set)
    start = budget * (1 - settings.final_fraction)
    tail = [value for step, value in line.items() if start < step <= budget]
    return float(np.mean(tail)) if tail else math.nan


def welch(a: Final, b: Final) -> float:
    """Two-sided p-value of Welch's t-test (unequal variances) that the two seed samples share a mean (the
    seeds with a final return); NaN with fewer than two a side; where neither sample varies (t undefined),
    1 if their values are equal and 0 if not."""
    a, b = a.finite(), b.finite()
    if len(a.values) < 2 or len(b.values) < 2:
        return math.nan
    if np.ptp(a.values) == 0 and np.ptp(b.values) == 0:
        return 1.0 if a.values[0] == b.values[0] else 0.0
    return float(stats.ttest_ind(a.values, b.values, equal_var=False).pvalue)


def welch_statistic(a: Final, b: Final) -> tuple[float, float, float]:
    """Welch's t of ``b``'s mean less ``a``'s, its degrees of freedom (Welch-Satterthwaite) and the standard
    error of the difference (the seeds with a final return)."""
    a, b = a.finite(), b.finite()
    va, vb = (np.var(final.values, ddof=1) / len(final.values) for final in (a, b))
    error = math.sqrt(va + vb)
    freedom = (va + vb) ** 2 / (va**2 / (len(a.values) - 1) + vb**2 / (len(b.values) - 1))
    return (b.mean - a.mean) / error, freedom, error


def below(a: Final, b: Final) -> float:
    """One-sided p-value of Welch's test that ``b``'s mean is below ``a``'s (small when it is lower)."""
    t, freedom, _ = welch_statistic(a, b)
    return float(stats.t.cdf(t, freedom))


def difference_interval(a: Final, b: Final, level: float = 0.90) -> tuple[float, float]:
    """The ``level`` confidence interval of ``b``'s mean less ``a``'s (Welch's)."""
    _, freedom, error = welch_statistic(a, b)
    half = float(stats.t.ppf(0.5 + level / 2, freedom)) * error
    return b.mean - a.mean - half, b.mean - a.mean + half


def stouffer(one_sided: Sequence[float]) -> float:
    """Stouffer's combination of independent one-sided p-values: 1 - Phi(sum of Phi^-1(1 - p) / sqrt(k))."""
    z = np.sum(stats.norm.isf(np.asarray(one_sided))) / math.sqrt(len(one_sided))
    return float(stats.norm.sf(z))


def sign_test(lower: int, sets: int) -> float:
    """One-sided sign test: the chance of ``lower`` or more of ``sets`` lower when each is a coin flip."""
    return float(stats.binom.sf(lower - 1, sets, 0.5))


def time_to_reach(curves: Sequence[SeedCurves], target: float) -> float | None:
    """Seconds (mean over seeds) until the mean-over-seeds curve first reaches ``target``; None if never."""
    means = [c.mean_over_bodies() for c in curves]
    for step in sorted({step for m in means for step in m}):
        values = [m[step] for m in means if step in m]
        if np.mean(values) >= target:
            return float(np.mean([c.seconds[step] for c in curves if step in c.seconds]))
    return None


def ratio_interval(a: Final, b: Final, level: float = 0.90) -> tuple[float, float]:
    """The ``level`` confidence interval of ``b``'s mean over ``a``'s, by the delta method (the ratio's
    standard error from both means' relative standard errors, Welch's degrees of freedom)."""
    _, freedom, _ = welch_statistic(a, b)
    ratio = b.mean / a.mean
    error = abs(ratio) * math.hypot(a.standard_error / a.mean, b.standard_error / b.mean)
    half = float(stats.t.ppf(0.5 + level / 2, freedom)) * error
    return ratio - half, ratio + half
