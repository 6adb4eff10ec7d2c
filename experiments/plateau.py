"""What tells a seed stranded on a plateau from one that breaks out: each run's learning diagnostics
(``diag/*`` columns of ``metrics.csv``, docs/training.md "Diagnostics") by seed and body, early in the run
and at its end, beside the seed's final return and whether it is stranded (below every seed of the
original trainer on that body).

    python -m experiments.plateau RUN_DIR [RUN_DIR ...] --original-from DIR [--scale small] [--early 0.3]

For each run (several seeds in one program, as ``experiments.time_to_return`` trains them) and each body:
a row per seed with its final return (the mean over the metrics rows of the run's last 20%), the episode
length, the share of saturated actions, the critics' overestimate of an episode's start, the twin
critics' disagreement and the exploration noise applied, each averaged over the rows of the first
``--early`` of the run after the random phase (``early``) and over the last 20% (``late``). Prints
Markdown.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import tyro

from experiments.original.curves import original_curves
from experiments.original.returns import final_returns
from experiments.original.runs import SETTINGS, ScaleName, original_runs
from swat_jax.cli import run_command
from swat_jax.morphology import get_set
from swat_jax.runs.config import CONFIG_FILE, load_config
from swat_jax.runs.metrics import read_metrics

FINAL_FRACTION = 0.2
"""The last share of a run whose rows give its final return and its ``late`` diagnostics."""
COLUMNS = ("length", "diag/saturated", "diag/overestimate", "diag/twin_gap", "diag/noise")
"""The columns summarised early and late, per body."""


@dataclasses.dataclass(frozen=True)
class Options:
    """What tells a seed stranded on a plateau from one that breaks out, from runs' learning diagnostics."""

    run_dirs: tyro.conf.Positional[tuple[Path, ...]]
    """Run directories (trained with the diagnostics) of one environment set."""
    original_from: Path
    """A folder with the original trainer's runs of that set (``original/<set>-seed<k>/``)."""
    scale: ScaleName = "small"
    """The scale those runs ran at (its budget and seeds)."""
    early: float = 0.3
    """The share of the run, after its random phase, whose rows give the ``early`` diagnostics."""


def window_mean(rows: Sequence[Mapping[str, float]], column: str, start: float, end: float) -> float:
    """The mean of ``column`` over the finite values of the rows with env_steps in (start, end]; NaN if none."""
    values = [row[column] for row in rows if start < row["env_steps"] <= end and math.isfinite(row[column])]
    return float(np.mean(values)) if values else math.nan


def original_lowest(original_from: Path, scale: ScaleName, environment_set: str) -> dict[str, float]:
    """Per body, the lowest final return of the original's seeds in ``original_from``."""
    settings = SETTINGS[scale]
    runs = [run for run in original_runs(original_from, settings, environment_set) if run.finished()]
    if not runs:
        raise ValueError(f"{original_from} holds no finished run of the original on {environment_set}")
    curves = [original_curves(run) for run in runs]
    return {
        body: float(np.nanmin(final_returns(curves, settings, environment_set, body).values))
        for body in get_set(environment_set).train
    }


def body_table(run_dir: Path, body: str, lowest: float, early: float) -> list[str]:
    """``body``'s rows of one run: per seed its final return, whether it is stranded, and each of
    :data:`COLUMNS` early and late."""
    config = load_config(run_dir / CONFIG_FILE)
    rows = read_metrics(run_dir)
    end = max(row["env_steps"] for row in rows)
    random_end = config.iteration.random_steps * len(get_set(config.env).train)
    late_start = end * (1 - FINAL_FRACTION)
    early_end = random_end + (end - random_end) * early
    header = " | ".join(f"{column.removeprefix('diag/')} early, late" for column in COLUMNS)
    lines = [
        f"{run_dir.name}, {body} (stranded: below the original's lowest seed, {lowest:.1f}):",
        "",
        f"| seed | final return | stranded | {header} |",
        f"|---|---|---|{'---|' * len(COLUMNS)}",
    ]
    for seed in dict.fromkeys(int(row["seed"]) for row in rows):
        mine = [row for row in rows if int(row["seed"]) == seed]
        final = window_mean(mine, f"return/{body}", late_start, end)
        cells = [
            f"{window_mean(mine, f'{column}/{body}', random_end, early_end):.3g}, "
            f"{window_mean(mine, f'{column}/{body}', late_start, end):.3g}"
            for column in COLUMNS
        ]
        stranded = "yes" if final < lowest else "no"
        lines.append(f"| {seed} | {final:.1f} | {stranded} | {' | '.join(cells)} |")
    return lines


def report(options: Options) -> str:
    """The Markdown tables of every run and body."""
    lines = []
    for run_dir in options.run_dirs:
        if not (run_dir / CONFIG_FILE).is_file():
            raise ValueError(f"{run_dir}: not a run directory (no {CONFIG_FILE})")
        environment_set = load_config(run_dir / CONFIG_FILE).env
        lowest = original_lowest(options.original_from, options.scale, environment_set)
        for body in get_set(environment_set).train:
            lines += [*body_table(run_dir, body, lowest[body], options.early), ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2, with one error line, for a run that cannot be read)."""
    return run_command(Options, report, argv, (ValueError, OSError), prog="python -m experiments.plateau")


if __name__ == "__main__":
    sys.exit(main())
