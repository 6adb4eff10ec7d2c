"""swat_jax's paper preset beside the original SWAT trainer: the same learning curves, and the wall clock of each.

    python experiments/against_original.py [--sets hopper walker] [--scale small|paper] [--seeds 4]
        [--original-python /tmp/orig-venv/bin/python] [--original-tools DIR] [--parallel 2] [--dry-run]
    python experiments/against_original.py --speed [--sets hopper walker animal_walkers] [--speed-seconds 120]

On one environment set, with the same network sizes, TD3 hyperparameters, random-start steps and step
budget, the script trains

- the original PyTorch code's unmodified ``main.py``, in its own virtual environment (MuJoCo 2.3.3, gym
  0.13.1, torch CPU, a small mujoco_py stand-in; ``--original-tools`` is the folder whose
  ``run_trainer.py BUDGET_S [main.py flags]`` runs it), one subprocess per seed with one torch thread,
  ``--parallel`` of them at a time; its own ``stat.json`` (a row per lock-step round: the environment steps
  so far, summed over bodies, and the return of each body's first episode of the round) and the trainer's
  log are copied to ``OUT/original/<set>-seed<k>/``;
- ``python -m swat_jax.train --preset paper`` with every seed in one program, in ``OUT/runs/<set>-swat_jax``.

Both curves are binned on the same grid (a point every ``log_iterations`` collection chunks of 100 steps
per body): swat_jax's point is the mean return of the training episodes that ended in the interval, the
original's the mean of its rounds' returns in it. Written to OUT: ``<set>.png`` (a panel per body and one
for the mean over bodies; mean ± standard error over seeds), ``<set>.csv`` (every plotted number),
``timings.json`` and ``against_original.md`` (final returns, their difference and Welch's t-test over seeds,
the wall clock and throughput of each side).

``--speed`` measures throughput at the paper's sizes instead (no learning curves): the original trainer for
``--speed-seconds`` with one torch thread and with all of them, and swat_jax's paper and fast presets
(compile, one warm-up iteration, ``--speed-iterations`` timed ones), and prints a Markdown table with each
figure's ratio to the original on one thread, measured in the same sitting.

A partial run resumes: a finished original seed (its ``stat.json`` copied) is kept, swat_jax's run resumes
from its newest checkpoint. An original seed that stopped part-way is run again from its start: the
original's own checkpoint restores the networks and replay but starts its ``stat.json`` empty.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from machine import cpu_model, host_cores, software_versions
from paper import (
    GridError,
    GridInterrupted,
    RunSpec,
    add_timing,
    exit_status,
    progress,
    read_timings,
    train_all,
)
from scipy import stats

from swat_jax.compilation_cache import enable_caches
from swat_jax.convert import SET_FOLDERS
from swat_jax.morphology import get_set
from swat_jax.plot import CurvePoint, curves_figure, save, summarise, write_points_csv
from swat_jax.runs.metrics import read_metrics, standard_error

ORIGINAL = "original (PyTorch)"
OURS = "swat_jax (paper preset)"
ORIGINAL_SET_FLAGS: dict[str, tuple[str, ...]] = {
    **{name: ("--custom_xml", f"environments/{folder}") for folder, name in SET_FOLDERS.items()},
    "animal_walkers": ("--morphologies", "nervenet"),
}
"""How the original's main.py is told each set's train bodies: its folder of XMLs, or (Animal-Walkers,
which has no folder) the name its XML files share."""
CHUNK = 100
"""Steps per body of the paper preset's collection chunk (the original trains after each lock-step round)."""
SURPLUS_ALLOWANCE: dict[str, float] = {"hopper": 1.75, "walker": 1.95}
"""Environment steps swat_jax stores per step it counts, with room to spare, by set (else 2): its budget in
stored steps is the counted budget times this, so that every seed counts the whole budget. In lock-step
rounds both implementations store more steps than they count; the original's trainers stored 1.37-1.56x
(Hopper++) and 1.59-1.76x (Walker++) at the small scale."""
ORIGINAL_WORK = Path(os.environ.get("ORIG_SWAT_DIR", "/tmp/swat-original"))
"""Where the original's tools copy its tree and where its main.py writes ``results/<expID>/``."""
SIGNIFICANCE = 0.05


@dataclasses.dataclass(frozen=True)
class Settings:
    """What both implementations train with: the same sizes, hyperparameters and budget."""

    name: str
    seeds: int
    steps: Mapping[str, int]
    """Environment steps per seed, summed over the set's bodies, by set."""
    width: int = 128
    heads: int = 2
    layers: int = 3
    feedforward: int = 256
    random_steps: int = 10_000
    """Steps per body with uniform random actions (the original's start_timesteps)."""
    learning_rate: float = 1e-4
    batch_size: int = 100
    capacity: int = 500_000
    """Replay rows per body (the original's rb_per_env)."""
    log_iterations: int = 5
    """Chunks of 100 steps per body between two points of the curves."""
    final_fraction: float = 0.2
    """The final return of a seed is its mean over the points in this last fraction of the budget."""

    def log_interval(self, environment_set: str) -> int:
        """Environment steps (all bodies) between two points of ``environment_set``'s curves."""
        return len(get_set(environment_set).train) * CHUNK * self.log_iterations

    def stored_budget(self, environment_set: str) -> int:
        """swat_jax's ``--steps`` on ``environment_set``: the counted budget times its surplus allowance,
        rounded up to whole collection chunks of every body."""
        chunk = len(get_set(environment_set).train) * CHUNK
        allowance = SURPLUS_ALLOWANCE.get(environment_set, 2.0)
        return math.ceil(self.budget(environment_set) * allowance / chunk) * chunk

    def budget(self, environment_set: str) -> int:
        """The step budget on ``environment_set`` in the steps the original counts (the curves' x axis);
        GridError if it has none or it is off the curves' grid."""
        if environment_set not in self.steps:
            raise GridError(f"scale {self.name} has no budget for {environment_set}; give --steps")
        steps, interval = self.steps[environment_set], self.log_interval(environment_set)
        if steps % interval:
            raise GridError(
                f"--steps {steps} on {environment_set}: must be a multiple of {interval} (its "
                f"{len(get_set(environment_set).train)} bodies x {CHUNK} steps x {self.log_iterations} chunks "
                "between curve points)"
            )
        return steps


SCALES = {
    "micro": Settings(
        name="micro",
        seeds=2,
        steps={"hopper": 600, "walker": 800},
        width=8,
        layers=1,
        feedforward=16,
        random_steps=100,
        capacity=1_000,
        log_iterations=1,
    ),
    "small": Settings(
        name="small",
        seeds=4,
        steps={"hopper": 24_000, "walker": 30_000},
        width=32,
        layers=1,
        feedforward=64,
        random_steps=1_000,
        learning_rate=1e-3,
        capacity=50_000,
    ),
    "paper": Settings(
        name="paper",
        seeds=5,
        steps={name: 10_000_000 for name in ORIGINAL_SET_FLAGS},
        log_iterations=100,
    ),
}
"""``micro`` is a smoke test of the whole pipeline (a few minutes); ``small`` fits Hopper++ and Walker++, both implementations, into about 80 minutes of 2 CPU cores;
``paper`` is the paper's sizes and budget (days of the original on a CPU)."""


# The two sides' runs


def ours(out: Path, settings: Settings, environment_set: str) -> RunSpec:
    """swat_jax's paper-preset run of every seed in one program: lock-step rounds, so it stores more steps
    than it counts; it runs for :meth:`Settings.stored_budget` steps and logs a row (with the steps
    counted so far) after every chunk, for the curves to be binned by counted steps."""
    chunk = len(get_set(environment_set).train) * CHUNK
    flags = (
        f"--env {environment_set} --algo swat --preset paper --seeds {settings.seeds} "
        f"--steps {settings.stored_budget(environment_set)} --width {settings.width} --heads {settings.heads} "
        f"--layers {settings.layers} --feedforward {settings.feedforward} "
        f"--iteration.random-steps {settings.random_steps} --iteration.capacity {settings.capacity} "
        f"--td3.learning-rate {settings.learning_rate} --td3.batch-size {settings.batch_size} "
        f"--log-interval {chunk} --checkpoint-interval {settings.log_interval(environment_set) * 4}"
    )
    return RunSpec(out / "runs" / f"{environment_set}-swat_jax", tuple(flags.split()))


@dataclasses.dataclass(frozen=True)
class OriginalRun:
    """One seed of the original trainer on one set."""

    out: Path
    settings: Settings
    environment_set: str
    seed: int

    @property
    def name(self) -> str:
        return f"{self.environment_set}-seed{self.seed}"

    @property
    def folder(self) -> Path:
        """Where its stat.json, args.txt and log are kept in OUT."""
        return self.out / "original" / self.name

    @property
    def experiment_id(self) -> str:
        """The original's --expID: unique per OUT folder, so two comparisons never share a results folder."""
        digest = hashlib.sha1(str(self.out.resolve()).encode()).hexdigest()[:8]
        return f"swat_jax_against_{digest}_{self.name}"

    def flags(self) -> list[str]:
        """The original main.py's flags for these settings."""
        s = self.settings
        if self.environment_set not in ORIGINAL_SET_FLAGS:
            raise GridError(
                f"the original code has no folder for {self.environment_set}; sets it can train: "
                f"{', '.join(ORIGINAL_SET_FLAGS)}"
            )
        return [
            *ORIGINAL_SET_FLAGS[self.environment_set],
            "--actor_type", "swat", "--critic_type", "swat", "--seed", str(self.seed),
            "--expID", self.experiment_id, "--max_timesteps", str(s.budget(self.environment_set)),
            "--start_timesteps", str(s.random_steps), "--lr", str(s.learning_rate),
            "--batch_size", str(s.batch_size), "--rb_per_env", str(s.capacity),
            "--attention_embedding_size", str(s.width), "--attention_heads", str(s.heads),
            "--attention_layers", str(s.layers), "--attention_hidden_size", str(s.feedforward),
        ]  # fmt: skip

    def command(self, python: Path, tools: Path, timeout: float) -> list[str]:
        return [str(python), str(tools / "run_trainer.py"), str(timeout), *self.flags()]

    def finished(self) -> bool:
        return (self.folder / "stat.json").is_file()


def original_runs(out: Path, settings: Settings, environment_set: str) -> list[OriginalRun]:
    return [OriginalRun(out, settings, environment_set, seed) for seed in range(settings.seeds)]


@dataclasses.dataclass(frozen=True)
class Original:
    """Where the original trainer runs: its venv's python and the folder of its tools."""

    python: Path
    tools: Path
    parallel: int
    timeout: float

    def missing(self) -> str | None:
        """Why it cannot run here, or None."""
        if not self.python.is_file():
            return f"no original-code venv at {self.python} (give --original-python)"
        if self.tools == Path():
            return "no folder of the original's tools: give --original-tools DIR or set $ORIGINAL_TOOLS"
        if not (self.tools / "run_trainer.py").is_file():
            return f"no run_trainer.py in {self.tools} (give --original-tools)"
        return None


def train_original(runs: Sequence[OriginalRun], original: Original, out: Path) -> None:
    """Run every unfinished seed, ``original.parallel`` at a time, each with one torch thread; copy its
    stat.json, args.txt and log into OUT; add the wall clock to ``timings.json``."""
    pending = [run for run in runs if not run.finished()]
    for run in runs:
        if run.finished():
            print(f"original {run.name}: done, kept", file=sys.stderr)
    if not pending:
        return
    prepare_tree(original)
    start, running = time.perf_counter(), []
    try:
        while pending or running:
            while pending and len(running) < original.parallel:
                run = pending.pop(0)
                running.append((run, _start_original(run, original), time.perf_counter()))
            time.sleep(1.0)
            for entry in list(running):
                run, process, began = entry
                if process.poll() is None:
                    continue
                running.remove(entry)
                _collect_original(run, process.returncode, time.perf_counter() - began)
    except KeyboardInterrupt:
        for _, process, _ in running:
            process.terminate()
        raise GridInterrupted(
            "stopped; the finished seeds are kept, run the same command again to go on"
        ) from None
    finally:
        add_timing(out, f"original-{runs[0].environment_set}", time.perf_counter() - start)


def prepare_tree(original: Original) -> None:
    """Have the original's tools copy its tree into ORIGINAL_WORK once, before seeds start side by side (each
    would copy it otherwise, and a seed started during another's copy finds it half-written)."""
    setup = f"import sys; sys.path.insert(0, {str(original.tools)!r}); import common; common.extract()"
    environment = {**os.environ, "ORIG_SWAT_DIR": str(ORIGINAL_WORK)}
    subprocess.run([str(original.python), "-c", setup], env=environment, cwd="/tmp", check=True)


def _start_original(run: OriginalRun, original: Original) -> subprocess.Popen:
    for stale in (ORIGINAL_WORK / "src" / "results", ORIGINAL_WORK / "src" / "buffers"):
        shutil.rmtree(stale / run.experiment_id, ignore_errors=True)
    run.folder.mkdir(parents=True, exist_ok=True)
    command = run.command(original.python, original.tools, original.timeout)
    print(f"original {run.name}: {shlex.join(command)}", file=sys.stderr)
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "ORIG_SWAT_DIR": str(ORIGINAL_WORK)}
    log = (run.folder / "trainer.log").open("w")
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=environment, cwd="/tmp")


def _collect_original(run: OriginalRun, status: int, seconds: float) -> None:
    results = ORIGINAL_WORK / "src" / "results" / run.experiment_id
    if status != 0 or not (results / "stat.json").is_file():
        raise GridError(
            f"original {run.name} exited with status {status}; its log: {run.folder / 'trainer.log'}"
        )
    if "training finished" not in _log(run):
        raise GridError(
            f"original {run.name} stopped before its budget (after {seconds:.0f} s); raise --original-timeout "
            f"(its log: {run.folder / 'trainer.log'})"
        )
    shutil.copy(results / "args.txt", run.folder / "args.txt")
    shutil.copy(results / "stat.json", run.folder / "stat.json")
    print(f"original {run.name}: finished in {seconds / 60:.1f} min", file=sys.stderr)


# Curves on one grid


@dataclasses.dataclass(frozen=True)
class SeedCurves:
    """One seed's binned training returns: by body, {grid step: mean return}, and the wall clock (s from
    the start of the seed's run) at each grid step."""

    returns: dict[str, dict[int, float]]
    seconds: dict[int, float]

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


def original_curves(run: OriginalRun) -> SeedCurves:
    """The original seed's stat.json rows binned on the grid, with the trainer log's wall clock of each
    round (its log line k is written by the same training round as stat.json's row k)."""
    stat = json.loads((run.folder / "stat.json").read_text())
    interval, budget = (
        run.settings.log_interval(run.environment_set),
        run.settings.budget(run.environment_set),
    )
    bins = [grid_step(step, interval, budget) for step in stat["timestep"]]
    returns = {}
    for body in get_set(run.environment_set).train:
        values: dict[int, list[float]] = {}
        for step, value in zip(bins, stat[f"{body}_episode_reward"], strict=True):
            values.setdefault(step, []).append(value)
        returns[body] = {step: float(np.mean(v)) for step, v in values.items()}
    rounds = [float(t) for t in re.findall(r"\[harness\] t=\s*([\d.]+)s round=", _log(run))]
    seconds = dict(zip(bins, rounds, strict=False))
    return SeedCurves(returns, seconds)


def _log(run: OriginalRun) -> str:
    return (run.folder / "trainer.log").read_text()


def original_surplus(run: OriginalRun) -> float | None:
    """Environment steps the seed's trainer took (every body, every step of each lock-step round) per step
    it counted toward its budget (one update each): above 1 by the transitions it stores uncounted."""
    match = re.search(r"totals: env_steps=(\d+) .*?updates=(\d+)", _log(run))
    return int(match.group(1)) / int(match.group(2)) if match and int(match.group(2)) else None


def original_wall(run: OriginalRun) -> float | None:
    """Seconds the seed's trainer ran, as its log reports them."""
    match = re.search(r"stopped after ([\d.]+)s wall", _log(run))
    return float(match.group(1)) if match else None


def original_throughput(run: OriginalRun) -> tuple[float, float] | None:
    """Environment steps/s and updates/s of the seed's training window, as its trainer log reports them."""
    match = re.search(r"([\d.]+) env steps/s, ([\d.]+) updates/s overall", _log(run))
    return (float(match.group(1)), float(match.group(2))) if match else None


def ours_curves(
    rows: Sequence[Mapping[str, float]], settings: Settings, environment_set: str, wall: float | None
) -> list[SeedCurves]:
    """Each seed's metrics rows binned on the grid by the steps counted so far (as the original's rounds
    are), rows past the counted budget left out; wall clock from the rows' steps/s, the compile and
    start-up time (the run's wall clock less its training windows) added, at each bin's last row."""
    interval, budget = settings.log_interval(environment_set), settings.budget(environment_set)
    curves = []
    for seed in dict.fromkeys(int(row["seed"]) for row in rows):
        mine = [row for row in rows if int(row["seed"]) == seed]
        stored = np.diff([0.0] + [row["env_steps"] for row in mine])
        windows = np.cumsum(
            [steps / row["steps_per_second"] for steps, row in zip(stored, mine, strict=True)]
        )
        startup = (wall - windows[-1]) if wall is not None else 0.0
        kept = [(row, t) for row, t in zip(mine, windows, strict=True) if row["counted_steps"] <= budget]
        bins = [grid_step(row["counted_steps"], interval, budget) for row, _ in kept]
        returns = {}
        for body in get_set(environment_set).train:
            values: dict[int, list[float]] = {}
            for step, (row, _) in zip(bins, kept, strict=True):
                if math.isfinite(row[f"return/{body}"]):
                    values.setdefault(step, []).append(row[f"return/{body}"])
            returns[body] = {step: float(np.mean(v)) for step, v in values.items()}
        seconds = {step: startup + float(t) for step, (_, t) in zip(bins, kept, strict=True)}
        curves.append(SeedCurves(returns, seconds))
    return curves


def ours_surplus(rows: Sequence[Mapping[str, float]]) -> list[float]:
    """Per seed, the environment steps swat_jax stored per step it counted, at its last row."""
    last = {int(row["seed"]): row for row in rows}
    return [row["env_steps"] / max(row["counted_steps"], 1) for row in last.values()]


def curve_points(environment_set: str, sides: Mapping[str, Sequence[SeedCurves]]) -> list[CurvePoint]:
    """The plotted points: a panel for the mean over bodies and one per body, a line per implementation."""
    label = get_set(environment_set).description or environment_set
    points = []
    for implementation, curves in sides.items():
        points += summarise(
            f"{label}: mean over bodies", implementation, [c.mean_over_bodies() for c in curves]
        )
    for body in get_set(environment_set).train:
        for implementation, curves in sides.items():
            points += summarise(f"{label}: {body}", implementation, [c.returns[body] for c in curves])
    return points


# Statistics


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
    budget = settings.budget(environment_set)
    start = budget * (1 - settings.final_fraction)
    values = []
    for curve in curves:
        line = curve.mean_over_bodies() if body is None else curve.returns[body]
        tail = [value for step, value in line.items() if start < step <= budget]
        values.append(float(np.mean(tail)) if tail else math.nan)
    return Final(np.array(values))


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


# The report


def compare(out: Path, settings: Settings, environment_set: str, timings: Mapping[str, float]) -> list[str]:
    """Figure, CSV and the Markdown section of one set."""
    run = ours(out, settings, environment_set)
    originals = [r for r in original_runs(out, settings, environment_set) if r.finished()]
    sides = {}
    if originals:
        sides[ORIGINAL] = [original_curves(r) for r in originals]
    rows = read_metrics(run.run_dir) if (run.run_dir / "metrics.csv").is_file() else []
    if rows:
        sides[OURS] = ours_curves(rows, settings, environment_set, timings.get(run.name))
    if not sides:
        return [f"## {environment_set}\n\nNothing trained yet."]
    points = curve_points(environment_set, sides)
    figure = curves_figure(points, "train")
    save(figure, out / f"{environment_set}.png")
    write_points_csv(points, out / f"{environment_set}.csv")
    finals = {side: final_returns(curves, settings, environment_set) for side, curves in sides.items()}
    first = {
        side: float(np.mean([next(iter(c.mean_over_bodies().values())) for c in curves]))
        for side, curves in sides.items()
    }
    lines = [
        f"## {get_set(environment_set).description or environment_set}, {settings.budget(environment_set):,} steps",
        "",
        f"![{environment_set}]({environment_set}.png)",
        "",
        f"Every plotted number: [{environment_set}.csv]({environment_set}.csv). Final return: each seed's mean "
        f"over bodies, averaged over the points of the last {settings.final_fraction:.0%} of the budget.",
        "",
        "| implementation | seeds | return at the first point (random actions) | final return (mean ± s.e.) "
        "| wall clock to the budget (min) | env steps/s per seed (all it stepped) | updates/s per seed (= counted steps/s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for side, curves in sides.items():
        final = finals[side]
        if side == ORIGINAL:
            wall = timings.get(f"original-{environment_set}")
            seed_walls = [seconds for seconds in map(original_wall, originals) if seconds]
            minutes = (
                f"{wall / 60:.1f}, all seeds (side by side as --parallel allows)"
                if wall is not None
                else f"{np.mean(seed_walls) / 60:.1f} per seed (one core each)"
                if seed_walls
                else "-"
            )
            rates = [rate for rate in map(original_throughput, originals) if rate]
            steps_rate = f"{np.mean([r[0] for r in rates]):.1f}" if rates else "-"
            updates_rate = f"{np.mean([r[1] for r in rates]):.1f}" if rates else "-"
        else:
            to_budget = max(c.seconds[max(c.seconds)] for c in curves) if timings.get(run.name) else None
            minutes = "-" if to_budget is None else f"{to_budget / 60:.1f}, every seed in one program"
            stored_rate = float(np.mean([row["steps_per_second"] for row in rows]))
            steps_rate = f"{stored_rate:.1f}"
            updates_rate = f"{stored_rate / np.mean(ours_surplus(rows)):.1f}"
        lines.append(
            f"| {side} | {len(curves)} | {first[side]:.1f} | {final.mean:.1f} ± {final.standard_error:.1f} "
            f"| {minutes} | {steps_rate} | {updates_rate} |"
        )
    surplus = [value for value in map(original_surplus, originals) if value]
    if surplus:
        lines += [
            "",
            f"The original's trainers stepped {min(surplus):.2f}-{max(surplus):.2f}x the environment steps they "
            "counted: a body that has ended its first episode of a lock-step round keeps stepping, and those "
            "transitions are stored but neither counted nor updated on.",
        ]
    if rows:
        ours_stored = ours_surplus(rows)
        lines += [
            "",
            f"swat_jax's seeds stepped {min(ours_stored):.2f}-{max(ours_stored):.2f}x the steps they counted "
            "(the same lock-step rounds; its curves are binned by counted steps).",
        ]
    if len(sides) == 2:
        a, b = finals[ORIGINAL], finals[OURS]
        p = welch(a, b)
        verdict = "within the noise" if p >= SIGNIFICANCE else "beyond the noise: a fidelity bug to find"
        lines += [
            "",
            f"Difference (swat_jax - original): {b.mean - a.mean:+.1f} ± "
            f"{math.hypot(a.standard_error, b.standard_error):.1f}; Welch's two-sided t-test over seeds: "
            f"p = {p:.3f}, {verdict} (at {SIGNIFICANCE}).",
        ]
        lines += ["", *body_table(sides, settings, environment_set)]
        reached = {side: time_to_reach(curves, a.mean) for side, curves in sides.items()}
        lines += [
            "",
            f"Wall clock to first reach the original's final return ({a.mean:.1f}) on the mean-over-seeds curve: "
            + "; ".join(
                f"{side} {'never' if t is None else f'{t / 60:.1f} min'}" for side, t in reached.items()
            )
            + " (the original: one seed's run on one core; swat_jax: every seed at once on all cores).",
        ]
    return lines


def body_table(
    sides: Mapping[str, Sequence[SeedCurves]], settings: Settings, environment_set: str
) -> list[str]:
    """Per body: both sides' final returns, each seed's, and Welch's p-value, so a disagreement shows where it is."""
    lines = [
        "| body | original: final return | seeds | swat_jax: final return | seeds | Welch p |",
        "|---|---|---|---|---|---|",
    ]
    for body in get_set(environment_set).train:
        a, b = (final_returns(sides[side], settings, environment_set, body) for side in (ORIGINAL, OURS))
        lines.append(
            f"| {body} | {a.mean:.1f} ± {a.standard_error:.1f} | {', '.join(f'{v:.0f}' for v in a.values)} "
            f"| {b.mean:.1f} ± {b.standard_error:.1f} | {', '.join(f'{v:.0f}' for v in b.values)} | {welch(a, b):.3f} |"
        )
    return lines


def report(
    out: Path, settings: Settings, sets: Sequence[str], argv: Sequence[str], original: Original
) -> Path:
    timings = read_timings(out)
    versions = ", ".join(f"{name} {version}" for name, version in software_versions().items())
    s = settings
    lines = [
        f"# swat_jax beside the original SWAT trainer, scale {s.name}",
        "",
        f"- Command: `python experiments/against_original.py {shlex.join(argv)}`",
        f"- Date: {datetime.date.today().isoformat()}",
        f"- Machine: {cpu_model()}, {host_cores()} cores; {versions}",
        f"- Both: SWAT actor and critic of width {s.width}, {s.heads} heads, {s.layers} layers, feed-forward "
        f"{s.feedforward}; TD3 at the paper's settings with learning rate {s.learning_rate} and batch "
        f"{s.batch_size}; {s.random_steps:,} random-action steps per body; replay {s.capacity:,} per body; "
        f"{s.seeds} seeds.",
        f"- The original: its unmodified main.py, one process per seed with one torch thread, "
        f"{original.parallel} at a time. swat_jax: `python -m swat_jax.train --preset paper`, every seed in "
        "one program.",
        "",
    ]
    for environment_set in sets:
        lines += [*compare(out, settings, environment_set, timings), ""]
    path = out / "against_original.md"
    path.write_text("\n".join(lines))
    return path


# Throughput at the paper's sizes (--speed)


@dataclasses.dataclass(frozen=True)
class Speed:
    """One throughput measurement: environment steps counted toward the budget, Adam steps of the critic, and
    the transitions those sampled, per second of steady state."""

    label: str
    env_steps: float
    updates: float
    transitions: float
    startup: float
    """Seconds before the timed window: process start and the first round (original) or the compile."""


def original_speed(original: Original, environment_set: str, threads: int | None, seconds: float) -> Speed:
    """The original trainer at its default (the paper's) sizes for ``seconds``, acting from its first step.

    Its training window (rounds 2 to the last, as run_trainer.py reports it) gives the rates. Each counted
    environment step (its total_timesteps, the budget's steps) is one update of the paper's schedule, so the
    counted steps/s are its updates/s; the steps its vectorised env takes for bodies already done in a round
    are not counted.
    """
    experiment_id = f"swat_jax_speed_{environment_set}"
    label = f"original, {threads or host_cores()} torch thread{'s' if (threads or host_cores()) > 1 else ''}"
    flags = [*ORIGINAL_SET_FLAGS[environment_set], "--actor_type", "swat", "--critic_type", "swat"]
    flags += ["--seed", "0", "--start_timesteps", "100", "--expID", experiment_id]
    shutil.rmtree(ORIGINAL_WORK / "src" / "results" / experiment_id, ignore_errors=True)
    environment = {**os.environ, "ORIG_SWAT_DIR": str(ORIGINAL_WORK)}
    environment.pop("OMP_NUM_THREADS", None)
    if threads:
        environment["OMP_NUM_THREADS"] = str(threads)
    command = [str(original.python), str(original.tools / "run_trainer.py"), str(seconds), *flags]
    print(f"{label}: {shlex.join(command)}", file=sys.stderr)
    log = subprocess.run(
        command, env=environment, cwd="/tmp", stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    ).stdout
    window = re.search(r"training window ([\d.]+)s .*?([\d.]+) updates/s overall", log)
    if not window:
        raise GridError(
            f"{label}: no training window in its log (fewer than two rounds in {seconds} s?):\n{log[-2000:]}"
        )
    updates = float(window.group(2))
    return Speed(
        label, updates, updates, updates * SCALES["paper"].batch_size, seconds - float(window.group(1))
    )


def ours_speed(preset: str, environment_set: str, iterations: int) -> Speed:
    """swat_jax's ``preset`` at the paper's network sizes on ``environment_set``, acting from its first step."""
    from preset_benchmark import measure

    from swat_jax.runs.config import PRESETS

    base = PRESETS[preset]
    config = dataclasses.replace(
        base,
        env=environment_set,
        iteration=dataclasses.replace(base.iteration, random_steps=0, capacity=100_000),
    )
    measured = measure(f"swat_jax {preset} preset", config, iterations)
    return Speed(
        measured.label,
        measured.env_steps_per_second,
        measured.updates_per_second,
        measured.transitions_per_second,
        measured.compile_seconds,
    )


def speed_table(sets: Sequence[str], original: Original, seconds: float, iterations: int) -> str:
    """Every set's measurements as Markdown, with ratios to the original on one torch thread."""
    lines = [
        "| set | implementation | env steps/s | updates/s | update transitions/s | start-up (s) "
        "| env steps/s vs original (1 thread) |",
        "|---|---|---|---|---|---|---|",
    ]
    for environment_set in sets:
        measured = [original_speed(original, environment_set, 1, seconds)]
        if host_cores() > 1:
            measured.append(original_speed(original, environment_set, None, seconds))
        measured += [ours_speed(preset, environment_set, iterations) for preset in ("paper", "fast")]
        baseline = measured[0].env_steps
        for m in measured:
            lines.append(
                f"| {get_set(environment_set).description} | {m.label} | {m.env_steps:,.1f} | {m.updates:,.1f} "
                f"| {m.transitions:,.0f} | {m.startup:.0f} | {m.env_steps / baseline:.2f} |"
            )
            print(lines[-1], file=sys.stderr, flush=True)
    return "\n".join(lines)


# The command


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python experiments/against_original.py",
        description=__doc__.split("\n\n")[0],
        epilog="A partial run resumes: the same command goes on where it stopped.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--sets", nargs="+", metavar="SET",
        help="environment sets to compare (default hopper walker; with --speed hopper walker animal_walkers); "
        f"the original can train {', '.join(ORIGINAL_SET_FLAGS)}",
    )  # fmt: skip
    parser.add_argument(
        "--scale", choices=tuple(SCALES), default="small",
        help="micro (a smoke test: 2 seeds, 600/800 steps), small (default: width-32 one-layer SWAT, 4 seeds, 24K/30K steps; about 80 min for Hopper++ "
        "and Walker++ on 2 CPU cores) or paper (the paper's sizes, 5 seeds, 10M steps)",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, help="seeds of each implementation (default: the scale's)")
    parser.add_argument(
        "--steps",
        type=int,
        help="environment steps per seed on every set, summed over bodies (default: the scale's)",
    )
    parser.add_argument(
        "--only", choices=("original", "swat_jax"), help="train one side only (the report shows what exists)"
    )
    parser.add_argument(
        "--original-python", type=Path, default=Path("/tmp/orig-venv/bin/python"),
        help="python of the original code's venv: mujoco 2.3.3, gym 0.13.1, torch, xmltodict (default /tmp/orig-venv)",
    )  # fmt: skip
    parser.add_argument(
        "--original-tools", type=Path, default=Path(os.environ.get("ORIGINAL_TOOLS", "")),
        help="the folder with run_trainer.py that runs the original main.py unmodified (default $ORIGINAL_TOOLS)",
    )  # fmt: skip
    parser.add_argument(
        "--parallel", type=int, default=host_cores(),
        help="original seeds run at once, one torch thread each (default: this machine's cores)",
    )  # fmt: skip
    parser.add_argument(
        "--original-timeout", type=float, default=6 * 3600.0,
        help="seconds after which an original seed is stopped (default 6 hours)",
    )  # fmt: skip
    parser.add_argument(
        "--out",
        type=Path,
        help="the folder of runs, figures and the report; default experiments/results/against_original",
    )
    parser.add_argument("--dry-run", action="store_true", help="print both sides' commands and stop")
    parser.add_argument(
        "--speed", action="store_true",
        help="measure throughput at the paper's sizes (both sides, --sets, default hopper walker animal_walkers) "
        "and print a Markdown table instead of training curves",
    )  # fmt: skip
    parser.add_argument(
        "--speed-seconds", type=float, default=120.0,
        help="--speed: seconds of each original trainer run (default 120)",
    )  # fmt: skip
    parser.add_argument(
        "--speed-iterations", type=int, default=2,
        help="--speed: timed iterations of each swat_jax preset, after one warm-up (default 2)",
    )  # fmt: skip
    return parser


def settings_from(args: argparse.Namespace) -> Settings:
    settings = SCALES[args.scale]
    if args.seeds is not None:
        settings = dataclasses.replace(settings, seeds=args.seeds)
    if args.steps is not None:
        settings = dataclasses.replace(settings, steps={name: args.steps for name in args.sets})
    if settings.seeds < 1:
        raise GridError(f"--seeds must be 1 or more, got {settings.seeds}")
    return settings


def run_sets(
    out: Path, settings: Settings, sets: Sequence[str], original: Original, only: str | None
) -> None:
    """Train both sides on every set: the original's seeds first, then swat_jax's program."""
    for environment_set in sets:
        if only != "swat_jax":
            why = original.missing()
            if why:
                raise GridError(f"cannot run the original trainer: {why}; or give --only swat_jax")
            train_original(original_runs(out, settings, environment_set), original, out)
        if only != "original":
            train_all([ours(out, settings, environment_set)], out)


def print_plan(out: Path, settings: Settings, sets: Sequence[str], original: Original) -> None:
    """The commands a run would start, each original seed and swat_jax's run (new, or where it resumes)."""
    for environment_set in sets:
        for run in original_runs(out, settings, environment_set):
            print(
                f"OMP_NUM_THREADS=1 {shlex.join(run.command(original.python, original.tools, original.timeout))}"
            )
        run = ours(out, settings, environment_set)
        steps = progress(run)
        state = "new" if steps is None else f"resumes at {steps:,} steps"
        print(f"python {shlex.join(run.command()[1:])}  # {state}")


def main(argv: list[str] | None = None) -> int:
    enable_caches()
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser().parse_args(argv)
    out = args.out or Path("experiments/results/against_original")
    original = Original(args.original_python, args.original_tools, args.parallel, args.original_timeout)
    args.sets = args.sets or (["hopper", "walker", "animal_walkers"] if args.speed else ["hopper", "walker"])

    def work() -> Path | None:
        if args.speed:
            why = original.missing()
            if why:
                raise GridError(f"cannot run the original trainer: {why}")
            print(speed_table(args.sets, original, args.speed_seconds, args.speed_iterations))
            return None
        settings = settings_from(args)
        for environment_set in args.sets:
            get_set(environment_set)
        if args.dry_run:
            print_plan(out, settings, args.sets, original)
            return None
        run_sets(out, settings, args.sets, original, args.only)
        return report(out, settings, args.sets, argv, original)

    return exit_status(work)


if __name__ == "__main__":
    sys.exit(main())
