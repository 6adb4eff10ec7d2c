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

    @property
    def mean(self) -> float:
        return float(np.mean(self.values))

    @property
    def standard_error(self) -> float:
        return standard_error(self.values)


def final_returns(
    curves: Sequence[SeedCurves], settings: Settings, environment_set: str, body: str | None = None
) -> Final:
    """Each seed's mean over the points of the budget's last ``final_fraction`` (points past the budget left
    out): of the mean over bodies, or of ``body``'s curve."""
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
    """Two-sided p-value of Welch's t-test (unequal variances) that the two seed samples share a mean."""
    if len(a.values) < 2 or len(b.values) < 2:
        return math.nan
    return float(stats.ttest_ind(a.values, b.values, equal_var=False).pvalue)


def time_to_reach(curves: Sequence[SeedCurves], target: float) -> float | None:
    """Seconds (mean over seeds) until the mean-over-seeds curve first reaches ``target``; None if never."""
    means = [c.mean_over_bodies() for c in curves]
    for step in sorted({step for m in means for step in m}):
        values = [m[step] for m in means if step in m]
        if np.mean(values) >= target:
            return float(np.mean([c.seconds[step] for c in curves if step in c.seconds]))
    return None
