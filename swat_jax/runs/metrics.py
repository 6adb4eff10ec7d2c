"""Training metrics of a run: ``metrics.csv`` (one row per log interval) and TensorBoard event files.

Rows are keyed by ``env_steps`` (summed over bodies). On resume, rows written after the checkpoint
being resumed from are dropped first, so the CSV of a resumed run has no repeated steps.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from tensorboardX import SummaryWriter

CSV_FILE = "metrics.csv"
TENSORBOARD_DIR = "tensorboard"


class MetricsWriter:
    """Appends rows of scalars to the CSV and to TensorBoard (NaN, e.g. no finished episode, is skipped there)."""

    def __init__(self, run_dir: Path, resumed_at: int | None = None):
        self.path = Path(run_dir) / CSV_FILE
        self.columns: list[str] | None = None
        if resumed_at is not None and self.path.exists():
            self._truncate(resumed_at)
        self.tensorboard = SummaryWriter(str(Path(run_dir) / TENSORBOARD_DIR))

    def write(self, row: dict[str, float]) -> None:
        """One row; the first row fixes the CSV columns (env_steps first)."""
        if self.columns is None:
            self.columns = list(row)
            if not self.path.exists() or self.path.stat().st_size == 0:
                with self.path.open("w", newline="") as file:
                    csv.writer(file).writerow(self.columns)
        with self.path.open("a", newline="") as file:
            csv.writer(file).writerow([_format(row.get(column, math.nan)) for column in self.columns])
        step = int(row["env_steps"])
        for tag, value in row.items():
            if tag != "env_steps" and math.isfinite(value):
                self.tensorboard.add_scalar(tag, value, step)
        self.tensorboard.flush()

    def close(self) -> None:
        self.tensorboard.close()

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
