"""Both sides' learning curves on one grid: the original's ``stat.json`` rounds and log, swat_jax's metrics
rows, binned by counted environment steps.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections.abc import Mapping, Sequence

import numpy as np

from experiments.original.runs import OriginalRun, Settings
from swat_jax.morphology import get_set
from swat_jax.plot import CurvePoint, summarise


@dataclasses.dataclass(frozen=True)
class SeedCurves:
    """One seed's binned training returns: by body, {grid step: mean return}, the wall clock (s from the start
    of the seed's run) at each grid step, and by body {grid step: mean episode length}."""

    returns: dict[str, dict[int, float]]
    seconds: dict[int, float]
    lengths: dict[str, dict[int, float]] = dataclasses.field(default_factory=dict)

    def mean_over_bodies(self) -> dict[int, float]:
        steps = sorted({step for curve in self.returns.values() for step in curve})
        means = {
            step: float(np.nanmean([curve.get(step, math.nan) for curve in self.returns.values()]))
            for step in steps
        }
        return {step: value for step, value in means.items() if math.isfinite(value)}


def grid_step(steps: float, interval: int, budget: int) -> int:
    """The curve point a step count falls into: the end of its interval (capped at the budget)."""
    return min(max(1, math.ceil(steps / interval)) * interval, budget)


def binned(bins: Sequence[int], values: Sequence[float]) -> dict[int, float]:
    """{grid step: mean of the finite ``values`` whose ``bins`` entry is that step}."""
    grouped: dict[int, list[float]] = {}
    for step, value in zip(bins, values, strict=True):
        if math.isfinite(value):
            grouped.setdefault(step, []).append(value)
    return {step: float(np.mean(group)) for step, group in grouped.items()}


def original_curves(run: OriginalRun) -> SeedCurves:
    """The original seed's stat.json rows binned on the grid, with the trainer log's wall clock of each
    round (its log line k is written by the same training round as stat.json's row k)."""
    stat = json.loads((run.folder / "stat.json").read_text())
    interval, budget = (
        run.settings.log_interval(run.environment_set),
        run.settings.budget(run.environment_set),
    )
    bins = [grid_step(step, interval, budget) for step in stat["timestep"]]
    bodies = get_set(run.environment_set).train
    returns = {body: binned(bins, stat[f"{body}_episode_reward"]) for body in bodies}
    lengths = {body: binned(bins, stat[f"{body}_episode_len"]) for body in bodies}
    rounds = [float(t) for t in re.findall(r"\[harness\] t=\s*([\d.]+)s round=", run.log())]
    seconds = dict(zip(bins, rounds, strict=False))
    return SeedCurves(returns, seconds, lengths)


def original_surplus(run: OriginalRun) -> float | None:
    """Environment steps the seed's trainer took (every body, every step of each lock-step round) per step
    it counted toward its budget (one update each): above 1 by the transitions it stores uncounted."""
    match = re.search(r"totals: env_steps=(\d+) .*?updates=(\d+)", run.log())
    return int(match.group(1)) / int(match.group(2)) if match and int(match.group(2)) else None


def original_wall(run: OriginalRun) -> float | None:
    """Seconds the seed's trainer ran, as its log reports them."""
    match = re.search(r"stopped after ([\d.]+)s wall", run.log())
    return float(match.group(1)) if match else None


def original_throughput(run: OriginalRun) -> tuple[float, float] | None:
    """Environment steps/s and updates/s of the seed's training window, as its trainer log reports them."""
    match = re.search(r"([\d.]+) env steps/s, ([\d.]+) updates/s overall", run.log())
    return (float(match.group(1)), float(match.group(2))) if match else None


def ours_curves(
    rows: Sequence[Mapping[str, float]], settings: Settings, environment_set: str, wall: float | None
) -> list[SeedCurves]:
    """Each seed's metrics rows binned on the grid by the steps counted so far (as the original's rounds
    are), up to the first row that counts the budget (the original's last round also ends past it; the rows
    after it left out); wall clock from the rows' steps/s, the compile and start-up time (the run's wall
    clock less its training windows) added, at each bin's last row."""
    interval, budget = settings.log_interval(environment_set), settings.budget(environment_set)
    curves = []
    for seed in dict.fromkeys(int(row["seed"]) for row in rows):
        mine = [row for row in rows if int(row["seed"]) == seed]
        stored = np.diff([0.0] + [row["env_steps"] for row in mine])
        windows = np.cumsum(
            [steps / row["steps_per_second"] for steps, row in zip(stored, mine, strict=True)]
        )
        startup = (wall - windows[-1]) if wall is not None else 0.0
        reaching = next((k for k, row in enumerate(mine) if row["counted_steps"] >= budget), len(mine) - 1)
        kept = list(zip(mine[: reaching + 1], windows[: reaching + 1], strict=True))
        bins = [grid_step(row["counted_steps"], interval, budget) for row, _ in kept]
        bodies = get_set(environment_set).train
        returns = {body: binned(bins, [row[f"return/{body}"] for row, _ in kept]) for body in bodies}
        lengths = {body: binned(bins, [row[f"length/{body}"] for row, _ in kept]) for body in bodies}
        seconds = {step: startup + float(t) for step, (_, t) in zip(bins, kept, strict=True)}
        curves.append(SeedCurves(returns, seconds, lengths))
    return curves


def ours_surplus(rows: Sequence[Mapping[str, float]], column: str = "stored_steps") -> list[float]:
    """Per seed, the transitions swat_jax stored per step it counted, at its last row (``column``
    ``env_steps``: the collection slots it took, those a seed waited for its round's updates included); the
    seeds whose rows lack ``column`` (runs written before ``stored_steps`` existed) are left out."""
    last = {int(row["seed"]): row for row in rows}
    return [
        row[column] / max(row["counted_steps"], 1)
        for row in last.values()
        if math.isfinite(row.get(column, math.nan))
    ]


def curve_points(environment_set: str, sides: Mapping[str, Sequence[SeedCurves]]) -> list[CurvePoint]:
    """The plotted points: a panel for the mean over bodies and one per body, a line per implementation."""
    label = get_set(environment_set).title
    points = []
    for implementation, curves in sides.items():
        points += summarise(
            f"{label}: mean over bodies", implementation, [c.mean_over_bodies() for c in curves]
        )
    for body in get_set(environment_set).train:
        for implementation, curves in sides.items():
            points += summarise(f"{label}: {body}", implementation, [c.returns[body] for c in curves])
    return points
