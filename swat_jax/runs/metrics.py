"""Training metrics of a run: ``metrics.csv`` (one row per seed per log interval) and TensorBoard event
files (``tensorboard/seed<k>/``, one TensorBoard run per seed).

Rows are keyed by ``env_steps`` (summed over bodies, per seed). On resume, rows written after the
checkpoint being resumed from are dropped first, so the CSV of a resumed run has no repeated steps.
:class:`MetricsWindow` sums what the iterations report between two rows.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tensorboardX import SummaryWriter

from swat_jax.td3.diagnostics import SUMS

CSV_FILE = "metrics.csv"
TENSORBOARD_DIR = "tensorboard"
LOSSES = ("critic_loss", "actor_loss")
RUN_TOTALS = ("counted_steps", "stored_steps")
"""What a window keeps from the run's start instead of summing per window: the steps counted, and the
transitions stored (with lock-step rounds fewer than the steps taken: a seed waiting for its round's updates
stores nothing)."""
DIAGNOSTICS = (*SUMS, "updates")
"""The diagnostics' per-body sums (:mod:`swat_jax.td3.diagnostics`), kept under ``diag_<name>``."""
DIAGNOSTIC_COLUMNS = ("estimate", "return", "overestimate", "twin_gap", "saturated", "noise", "update_share")
"""The ``diag/<name>/<body>`` columns of a row (:meth:`MetricsWindow.rows`)."""


class MetricsWriter:
    """Appends rows of scalars to the CSV and to each seed's TensorBoard run (NaN, e.g. no finished
    episode, is skipped there)."""

    def __init__(self, run_dir: Path, resumed_at: int | None = None):
        self.path = Path(run_dir) / CSV_FILE
        self.columns: list[str] | None = None
        if resumed_at is not None and self.path.exists():
            self._truncate(resumed_at)
        self.tensorboard_dir = Path(run_dir) / TENSORBOARD_DIR
        self.tensorboard: dict[int, SummaryWriter] = {}

    def write(self, row: dict[str, float]) -> None:
        """One row (``env_steps`` and ``seed`` among its columns); the first row fixes the CSV columns
        (env_steps first)."""
        if self.columns is None:
            self.columns = list(row)
            if not self.path.exists() or self.path.stat().st_size == 0:
                with self.path.open("w", newline="") as file:
                    csv.writer(file).writerow(self.columns)
        with self.path.open("a", newline="") as file:
            csv.writer(file).writerow([_format(row.get(column, math.nan)) for column in self.columns])
        step, seed = int(row["env_steps"]), int(row["seed"])
        if seed not in self.tensorboard:
            self.tensorboard[seed] = SummaryWriter(str(self.tensorboard_dir / f"seed{seed}"))
        for tag, value in row.items():
            if tag not in ("env_steps", "seed") and math.isfinite(value):
                self.tensorboard[seed].add_scalar(tag, value, step)
        self.tensorboard[seed].flush()

    def close(self) -> None:
        for writer in self.tensorboard.values():
            writer.close()

    def _truncate(self, last_step: int) -> None:
        with self.path.open(newline="") as file:
            rows = list(csv.reader(file))
        if not rows:
            return
        header, body = rows[0], rows[1:]
        self.columns = header
        kept = [row for row in body if row and float(row[0]) <= last_step]
        with self.path.open("w", newline="") as file:
            csv.writer(file).writerows([header, *kept])


def _format(value: float) -> str:
    if isinstance(value, int):
        return str(value)
    return "" if math.isnan(value) else f"{value:.6g}"


def read_metrics(run_dir: Path) -> list[dict[str, float]]:
    """The CSV rows as floats (empty cells as NaN)."""
    with (Path(run_dir) / CSV_FILE).open(newline="") as file:
        return [{k: float(v) if v else math.nan for k, v in row.items()} for row in csv.DictReader(file)]


def standard_error(values: np.ndarray) -> float:
    """Standard error of the mean of ``values`` [n] (sample standard deviation / sqrt(n)); NaN for n < 2."""
    if len(values) < 2:
        return math.nan
    return float(np.std(values, ddof=1) / math.sqrt(len(values)))


class MetricsWindow:
    """Per-seed sums since the last metrics row: each iteration's mean losses and the episodes each body
    finished (sums of returns and lengths, and their count), the latest iteration's ``counted_steps`` and the
    transitions stored since the run's start (:data:`RUN_TOTALS`).

    With ``diagnostics``, also the sums of the learning diagnostics per seed and body (:data:`DIAGNOSTICS`).

    Saved in checkpoints (:meth:`to_json`), so the row after a resume sums the same iterations, in the same
    order, as an uninterrupted run's.
    """

    def __init__(
        self, seeds: int, bodies: int, saved: dict[str, Any] | None = None, diagnostics: bool = False
    ):
        saved = saved or {}
        self.diagnostics = diagnostics
        self.iterations = int(saved.get("iterations", 0))
        self.sums = {
            name: np.array(saved.get(name, np.zeros(shape)), np.float64)
            for name, shape in self._shapes(seeds, bodies).items()
        }

    @staticmethod
    def _shapes(seeds: int, bodies: int) -> dict[str, tuple[int, ...]]:
        return {
            **{name: (seeds,) for name in (*LOSSES, "counted_steps", "stored_steps")},
            **{name: (seeds, bodies) for name in ("return_sum", "length_sum", "count")},
            **{f"diag_{name}": (seeds, bodies) for name in DIAGNOSTICS},
        }

    def add(self, metrics: dict[str, Any]) -> None:
        """One iteration's metrics: losses [S, U], one per update (U: bodies x updates with the original
        schedule, updates with all_tasks), ``episodes`` (EpisodeStats of [S, K] arrays) and
        ``counted_steps`` [S], the steps counted since the run's start (kept, not summed), ``stored_steps``
        [S], the transitions the iteration stored (added to the run's total); with diagnostics,
        ``diagnostics``, their sums [S, K] by name (:data:`DIAGNOSTICS`)."""
        for name in LOSSES:
            self.sums[name] += np.mean(np.asarray(metrics[name]), axis=-1)
        self.sums["counted_steps"][...] = np.asarray(metrics["counted_steps"])
        self.sums["stored_steps"] += np.asarray(metrics["stored_steps"])
        episodes = metrics["episodes"]
        for name in ("return_sum", "length_sum", "count"):
            self.sums[name] += np.asarray(getattr(episodes, name))
        if self.diagnostics:
            for name in DIAGNOSTICS:
                self.sums[f"diag_{name}"] += np.asarray(metrics["diagnostics"][name])
        self.iterations += 1

    def rows(self, seeds: Sequence[int], body_names: Sequence[str]) -> list[dict[str, float]]:
        """One row per seed: mean losses over the window's iterations, the mean return over bodies of the
        episodes they finished, per body the mean return, mean length and count of those episodes, and the
        steps counted and the transitions stored since the run's start (``counted_steps``, ``stored_steps``);
        with diagnostics the ``diag/*`` columns per
        body (:meth:`diagnostic_columns`)."""
        count = self.sums["count"]
        with np.errstate(invalid="ignore", divide="ignore"):
            returns = self.sums["return_sum"] / count
            lengths = self.sums["length_sum"] / count
        rows = []
        for index, seed in enumerate(seeds):
            finished = returns[index][count[index] > 0]
            row: dict[str, float] = {"seed": seed}
            row |= {name: float(self.sums[name][index] / max(self.iterations, 1)) for name in LOSSES}
            row["mean_return"] = float(np.mean(finished)) if finished.size else math.nan
            row["counted_steps"] = int(self.sums["counted_steps"][index])
            row["stored_steps"] = int(self.sums["stored_steps"][index])
            for body, episode_return, length, n in zip(
                body_names, returns[index], lengths[index], count[index], strict=True
            ):
                label = Path(body).stem
                row[f"return/{label}"] = float(episode_return)
                row[f"length/{label}"] = float(length)
                row[f"episodes/{label}"] = int(n)
            if self.diagnostics:
                row |= self.diagnostic_columns(index, body_names)
            rows.append(row)
        return rows

    def diagnostic_columns(self, seed_index: int, body_names: Sequence[str]) -> dict[str, float]:
        """One seed's ``diag/<name>/<body>`` columns (:data:`DIAGNOSTIC_COLUMNS`; :mod:`swat_jax.td3.diagnostics`):
        the mean estimate at the start of the episodes finished in the window, their mean discounted return
        and the difference, the mean twin disagreement and saturated share over the steps, the root mean
        square of the exploration noise applied over the policy phase's steps, and the body's share of the
        updates. NaN where the window has nothing to average (no episode finished, no policy step)."""
        sums = {name: self.sums[f"diag_{name}"][seed_index] for name in DIAGNOSTICS}
        total_updates = np.sum(sums["updates"])
        with np.errstate(invalid="ignore", divide="ignore"):
            columns = {
                "estimate": sums["estimate"] / sums["episodes"],
                "return": sums["return"] / sums["episodes"],
                "overestimate": (sums["estimate"] - sums["return"]) / sums["episodes"],
                "twin_gap": sums["twin_gap"] / sums["steps"],
                "saturated": sums["saturated"] / sums["steps"],
                "noise": np.sqrt(sums["noise_square"] / sums["policy_steps"]),
                "update_share": sums["updates"] / total_updates,
            }
        return {
            f"diag/{name}/{Path(body).stem}": float(values[k])
            for name, values in columns.items()
            for k, body in enumerate(body_names)
        }

    def to_json(self) -> dict[str, Any]:
        """The sums as JSON-ready lists (float64 values round-trip exactly)."""
        return {"iterations": self.iterations, **{k: v.tolist() for k, v in self.sums.items()}}

    def clear(self) -> None:
        """Start the next window: every sum back to 0 but the run's totals (counted and stored steps)."""
        self.iterations = 0
        for name, values in self.sums.items():
            if name not in RUN_TOTALS:
                values[...] = 0


def evaluation_columns(
    returns: np.ndarray, lengths: np.ndarray, body_names: Sequence[str]
) -> list[dict[str, float]]:
    """Per seed, the ``eval/*`` columns of a metrics row from deterministic episodes ``returns`` and
    ``lengths`` [S, K, E]: ``eval/mean_return`` (the mean over bodies of their mean returns), and per
    body ``eval/return/<body>`` and ``eval/length/<body>``. NaN inputs give NaN columns (a row without
    an evaluation)."""
    body_returns = np.mean(returns, axis=-1, dtype=np.float64)
    body_lengths = np.mean(lengths, axis=-1, dtype=np.float64)
    rows = []
    for seed_returns, seed_lengths in zip(body_returns, body_lengths, strict=True):
        row = {"eval/mean_return": float(np.mean(seed_returns))}
        for body, episode_return, length in zip(body_names, seed_returns, seed_lengths, strict=True):
            label = Path(body).stem
            row[f"eval/return/{label}"] = float(episode_return)
            row[f"eval/length/{label}"] = float(length)
        rows.append(row)
    return rows
