"""swat_jax's paper preset beside the original SWAT trainer: the same learning curves, and the wall clock of each.

    python -m experiments.against_original [--sets hopper walker] [--scale small|paper] [--seeds 4]
        [--original-python /tmp/orig-venv/bin/python] [--original-tools DIR] [--parallel 2] [--dry-run]
        [--report-only]
    python -m experiments.against_original --speed [--sets hopper walker animal_walkers] [--speed-seconds 120]

On one environment set, with the same network sizes, TD3 hyperparameters, random-start steps and step
budget, the script trains

- the original PyTorch code's unmodified ``main.py``, in its own virtual environment (MuJoCo 2.3.3, gym
  0.13.1, torch CPU, a small mujoco_py stand-in; ``--original-tools`` is the folder whose
  ``run_trainer.py BUDGET_S [main.py flags]`` runs it), one subprocess per seed with one torch thread,
  ``--parallel`` of them at a time; its own ``stat.json`` (a row per lock-step round: the environment steps
  so far, summed over bodies, and the return of each body's first episode of the round) and the trainer's
  log are copied to ``OUT/original/<set>-seed<k>/``;
- ``python -m swat_jax.train --preset paper``, one process per seed as well, ``--parallel`` at a time, each
  single-threaded and pinned to a core, in ``OUT/runs/<set>-swat_jax-seed<k>`` (its output beside it, in
  ``<set>-swat_jax-seed<k>.log``).

Both curves are binned on the same grid (a point every ``log_iterations`` collection chunks of 100 steps
per body): swat_jax's point is the mean return of the training episodes that ended in the interval, the
original's the mean of its rounds' returns in it. Written to OUT: ``<set>.png`` (a panel per body and one
for the mean over bodies; mean ± standard error over seeds), ``<set>.csv`` (every plotted number),
``timings.json`` and ``against_original.md`` (final returns, their difference and Welch's t-test over seeds,
the wall clock and throughput of each side; over two sets or more, the pooled test: Stouffer's combination
of the one-sided tests and the sign test). Each swat_jax seed stops at the original's counted budget
(``--counted-steps``). ``--report-only`` writes the report from the runs in OUT and trains nothing.

``--speed`` measures throughput at the paper's sizes instead (no learning curves): the original trainer for
``--speed-seconds`` with one torch thread and with all of them, and swat_jax's paper and fast presets
(compile, one warm-up iteration, ``--speed-iterations`` timed ones), and prints a Markdown table with each
figure's ratio to the original on one thread, measured in the same sitting.

A partial run resumes: a finished original seed (its ``stat.json`` copied) is kept, a swat_jax seed resumes
from its newest checkpoint. An original seed that stopped part-way is run again from its start: the
original's own checkpoint restores the networks and replay but starts its ``stat.json`` empty.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from experiments.machine import cpu_model, host_cores, software_versions
from experiments.original.curves import (
    SeedCurves,
    curve_points,
    original_curves,
    original_surplus,
    original_throughput,
    original_wall,
    ours_curves,
    ours_surplus,
)
from experiments.original.returns import (
    SIGNIFICANCE,
    Final,
    below,
    difference_interval,
    final_returns,
    final_value,
    sign_test,
    stouffer,
    time_to_reach,
    welch,
)
from experiments.original.runs import (
    ORIGINAL,
    OURS,
    SETTINGS,
    SINGLE_THREAD_XLA,
    Original,
    OriginalRun,
    ScaleName,
    Settings,
    original_runs,
    ours,
    train_original,
    train_ours,
)
from experiments.original.speed import speed_table
from experiments.paper import (
    GridError,
    exit_status,
    progress,
    read_timings,
    shown,
)
from swat_jax.compilation_cache import enable_caches
from swat_jax.morphology import get_set
from swat_jax.plot import curves_figure, save, write_points_csv
from swat_jax.runs.metrics import read_metrics

# The report


def compare(
    out: Path,
    settings: Settings,
    environment_set: str,
    timings: Mapping[str, float],
    seed_bodies: Sequence[str] = (),
) -> tuple[list[str], dict[str, Final]]:
    """Figure, CSV and the Markdown section of one set, and each side's final returns; ``seed_bodies`` of the
    set are tabulated seed by seed (none of them in the set: the body furthest from the original)."""
    originals, seed_rows = finished_runs(out, settings, environment_set, timings)
    sides = side_curves(originals, seed_rows, settings, environment_set)
    rows = [row for mine, _ in seed_rows for row in mine]
    if not sides:
        return [f"## {environment_set}\n\nNothing trained yet."], {}
    points = curve_points(environment_set, sides)
    save(curves_figure(points, "train"), out / f"{environment_set}.png")
    write_points_csv(points, out / f"{environment_set}.csv")
    finals = {side: final_returns(curves, settings, environment_set) for side, curves in sides.items()}
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
        first = float(np.mean([next(iter(c.mean_over_bodies().values())) for c in curves]))
        final = finals[side]
        if side == ORIGINAL:
            minutes, steps_rate, updates_rate = _original_speed(
                originals, timings.get(f"original-{environment_set}")
            )
        else:
            minutes, steps_rate, updates_rate = _ours_speed(curves, seed_rows)
        lines.append(
            f"| {side} | {len(curves)} | {first:.1f} | {final.cell()} "
            f"| {minutes} | {steps_rate} | {updates_rate} |"
        )
    lines += _short_lines(sides, settings, environment_set)
    lines += _surplus_lines(originals, rows)
    if len(sides) == 2 and all(len(final.finite().values) >= 2 for final in finals.values()):
        lines += _difference_lines(sides, finals, settings, environment_set, seed_bodies)
    elif len(sides) == 2:
        counts = ", ".join(f"{side} {len(final.finite().values)}" for side, final in finals.items())
        lines += ["", f"No test: Welch's needs two seeds a side with a final return ({counts})."]
    return lines, finals


SeedRows = list[tuple[list[dict[str, float]], float | None]]
"""swat_jax's seeds in a folder: each seed's metrics rows with its wall clock (None where none was recorded)."""


def finished_runs(
    out: Path, settings: Settings, environment_set: str, timings: Mapping[str, float]
) -> tuple[list[OriginalRun], SeedRows]:
    """The original's finished seeds in ``out`` and swat_jax's seeds that wrote metrics, with their wall clocks."""
    originals = [r for r in original_runs(out, settings, environment_set) if r.finished()]
    seed_rows = [
        (read_metrics(run.run_dir), timings.get(run.name))
        for run in ours(out, settings, environment_set)
        if (run.run_dir / "metrics.csv").is_file()
    ]
    return originals, seed_rows


def side_curves(
    originals: Sequence[OriginalRun], seed_rows: SeedRows, settings: Settings, environment_set: str
) -> dict[str, list[SeedCurves]]:
    """Each side's seed curves on the grid, by side (a side without runs left out)."""
    sides = {}
    if originals:
        sides[ORIGINAL] = [original_curves(r) for r in originals]
    if any(mine for mine, _ in seed_rows):
        sides[OURS] = [
            curve for mine, wall in seed_rows for curve in ours_curves(mine, settings, environment_set, wall)
        ]
    return sides


def _original_speed(originals: Sequence[OriginalRun], wall: float | None) -> tuple[str, str, str]:
    """The original's table cells: wall clock to the budget, env steps/s and updates/s per seed."""
    seed_walls = [seconds for seconds in map(original_wall, originals) if seconds]
    if wall is not None:
        minutes = f"{wall / 60:.1f}, all seeds (side by side as --parallel allows)"
    else:
        minutes = f"{np.mean(seed_walls) / 60:.1f} per seed (one core each)" if seed_walls else "-"
    rates = [rate for rate in map(original_throughput, originals) if rate]
    if not rates:
        return minutes, "-", "-"
    return minutes, f"{np.mean([r[0] for r in rates]):.1f}", f"{np.mean([r[1] for r in rates]):.1f}"


def _ours_speed(
    curves: Sequence[SeedCurves], seed_rows: Sequence[tuple[Sequence[Mapping[str, float]], float | None]]
) -> tuple[str, str, str]:
    """swat_jax's table cells: wall clock to the budget (mean over the seeds whose wall clock was recorded),
    env steps/s and updates/s per seed."""
    timed = [curve for curve, (_, wall) in zip(curves, seed_rows, strict=True) if wall is not None]
    to_budget = [curve.seconds[max(curve.seconds)] for curve in timed]
    minutes = f"{np.mean(to_budget) / 60:.1f} per seed (one core each)" if to_budget else "-"
    rows = [row for mine, _ in seed_rows for row in mine]
    stored_rate = float(np.mean([row["steps_per_second"] for row in rows]))
    surplus = np.mean([value for mine, _ in seed_rows for value in ours_surplus(mine)])
    return minutes, f"{stored_rate:.1f}", f"{stored_rate / surplus:.1f}"


def _surplus_lines(originals: Sequence[OriginalRun], rows: Sequence[Mapping[str, float]]) -> list[str]:
    """How many more steps each side stepped than it counted."""
    lines = []
    surplus = [value for value in map(original_surplus, originals) if value]
    if surplus:
        lines += [
            "",
            f"The original's trainers stepped {min(surplus):.2f}-{max(surplus):.2f}x the environment steps they "
            "counted: a body that has ended its first episode of a lock-step round keeps stepping, and those "
            "transitions are stored but neither counted nor updated on.",
        ]
    if rows:
        stored, slots = ours_surplus(rows), ours_surplus(rows, "env_steps")
        seeds = len({int(row["seed"]) for row in rows})
        told = (
            f"stored {min(stored):.2f}-{max(stored):.2f}x the transitions they counted"
            + ("" if len(stored) == seeds else f" ({len(stored)} of {seeds} seeds record what they stored)")
            if stored
            else "did not record the transitions they stored (runs written before stored_steps)"
        )
        lines += [
            "",
            f"swat_jax's seeds {told} (the same lock-step rounds; its curves are binned by counted steps), in "
            f"{min(slots):.2f}-{max(slots):.2f}x collection slots per counted step: the rest are slots a seed "
            "waited, storing nothing, from its round's end to its chunk's end.",
        ]
    return lines


def _short_lines(
    sides: Mapping[str, Sequence[SeedCurves]], settings: Settings, environment_set: str
) -> list[str]:
    """A line per seed whose curve ends short of the budget's last points (no final return: left out of the
    finals and the tests), saying where it ended."""
    budget = settings.budget(environment_set)
    lines = []
    for side, curves in sides.items():
        for seed, curve in enumerate(curves):
            if math.isnan(final_value(curve.mean_over_bodies(), settings, environment_set)):
                last = max(curve.seconds, default=0)
                lines.append(
                    f"{side} seed {seed} ended at the {last:,}-step point, short of the last points of the "
                    f"{budget:,}-step budget: left out of the final returns."
                )
    return ["", *lines] if lines else []


def _difference_lines(
    sides: Mapping[str, Sequence[SeedCurves]],
    finals: Mapping[str, Final],
    settings: Settings,
    environment_set: str,
    seed_bodies: Sequence[str],
) -> list[str]:
    """The two sides' difference, Welch's test, the per-body table, the seed tables of ``seed_bodies`` (none in
    the set: of the body furthest from the original) and the wall clock to the original's return."""
    bodies = get_set(environment_set).train
    tabulated = [body for body in seed_bodies if body in bodies] or [
        _furthest_body(sides, settings, environment_set)
    ]
    a, b = finals[ORIGINAL], finals[OURS]
    p = welch(a, b)
    verdict = "within the noise" if p >= SIGNIFICANCE else "beyond the noise: a fidelity bug to find"
    reached = {side: time_to_reach(curves, a.mean) for side, curves in sides.items()}
    return [
        "",
        f"Difference (swat_jax - original): {b.mean - a.mean:+.1f} ± "
        f"{math.hypot(a.standard_error, b.standard_error):.1f}; Welch's two-sided t-test over seeds: "
        f"p = {p:.3f}, {verdict} (at {SIGNIFICANCE}).",
        "",
        *body_table(sides, settings, environment_set),
        "",
        *(line for body in tabulated for line in [*seed_table(sides, settings, environment_set, body), ""]),
        f"Wall clock to first reach the original's final return ({a.mean:.1f}) on the mean-over-seeds curve: "
        + "; ".join(f"{side} {'never' if t is None else f'{t / 60:.1f} min'}" for side, t in reached.items())
        + " (mean over seeds; each seed one process on one core).",
    ]


def _furthest_body(
    sides: Mapping[str, Sequence[SeedCurves]], settings: Settings, environment_set: str
) -> str:
    """The body whose final returns differ most between the sides: the lowest Welch p."""

    def p_value(body: str) -> float:
        finals = (final_returns(sides[side], settings, environment_set, body) for side in (ORIGINAL, OURS))
        return float(np.nan_to_num(welch(*finals), nan=1.0))

    return min(get_set(environment_set).train, key=p_value)


def seed_table(
    sides: Mapping[str, Sequence[SeedCurves]], settings: Settings, environment_set: str, body: str
) -> list[str]:
    """``body`` seed by seed on both sides: its final return and episode length, its best curve point, and
    when (if ever) it first reached the original's final return on it, to tell seeds that stay on a plateau
    from those that break out of it."""
    target = final_returns(sides[ORIGINAL], settings, environment_set, body).mean
    lines = [
        f"{body} seed by seed (steps are counted steps; the original's final return on it: {target:.1f}):",
        "",
        "| implementation | seed | final return | final episode length | best point | first point at "
        f"{target:.0f} or more |",
        "|---|---|---|---|---|---|",
    ]
    for side in (ORIGINAL, OURS):
        for seed, curve in enumerate(sides[side]):
            line = curve.returns[body]
            best = max(line, key=line.__getitem__)
            reached = next((step for step in sorted(line) if line[step] >= target), None)
            length = final_value(curve.lengths.get(body, {}), settings, environment_set)
            lines.append(
                f"| {side} | {seed} | {final_value(line, settings, environment_set):.0f} | {length:.0f} "
                f"| {line[best]:.0f} at {best:,} | {'never' if reached is None else f'{reached:,}'} |"
            )
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
            f"| {body} | {a.cell()} | {', '.join(f'{v:.0f}' for v in a.finite().values)} "
            f"| {b.cell()} | {', '.join(f'{v:.0f}' for v in b.finite().values)} | {welch(a, b):.3f} |"
        )
    return lines


def report(
    out: Path,
    settings: Settings,
    sets: Sequence[str],
    argv: Sequence[str],
    original: Original,
    seed_bodies: Sequence[str] = (),
) -> Path:
    timings = read_timings(out)
    versions = ", ".join(f"{name} {version}" for name, version in software_versions().items())
    s = settings
    lines = [
        f"# swat_jax beside the original SWAT trainer, scale {s.name}",
        "",
        f"- Command: `python -m experiments.against_original {shlex.join(argv)}`",
        f"- Date: {datetime.date.today().isoformat()}",
        f"- Machine: {cpu_model()}, {host_cores()} cores; {versions}",
        f"- Both: SWAT actor and critic of width {s.width}, {s.heads} heads, {s.layers} layers, feed-forward "
        f"{s.feedforward}; TD3 at the paper's settings with learning rate {s.learning_rate} and batch "
        f"{s.batch_size}; {s.random_steps:,} random-action steps per body; replay {s.capacity:,} per body; "
        f"{s.seeds} seeds.",
        f"- The original: its unmodified main.py, one process per seed with one torch thread, "
        f"{original.parallel} at a time. swat_jax: `python -m swat_jax.train --preset paper`, one process per "
        f"seed as well, single-threaded and pinned to a core, {original.parallel} at a time.",
        "",
    ]
    pooled = {}
    for environment_set in sets:
        section, finals = compare(out, settings, environment_set, timings, seed_bodies)
        lines += [*section, ""]
        if all(len(finals.get(side, Final(np.array([]))).finite().values) >= 2 for side in (ORIGINAL, OURS)):
            pooled[environment_set] = (finals[ORIGINAL], finals[OURS])
    if len(pooled) >= 2:
        lines += pooled_lines(pooled)
    path = out / "against_original.md"
    path.write_text("\n".join(lines))
    return path


def pooled_lines(finals: Mapping[str, tuple[Final, Final]]) -> list[str]:
    """The sets compared, pooled: per set both sides' final returns (mean ± standard error over seeds), the
    difference with its 90% interval, Welch's two-sided p and the one-sided p that swat_jax is lower; then
    Stouffer's combination of the one-sided tests and the sign test over the sets."""
    lines = [
        "## Pooled over the sets",
        "",
        "Final returns: mean ± standard error over seeds. The difference is swat_jax's less the original's, "
        "with its 90% interval (Welch's); the one-sided p tests swat_jax lower.",
        "",
        "| set | seeds a side | original | swat_jax | difference (90% interval) | Welch p | one-sided p |",
        "|---|---|---|---|---|---|---|",
    ]
    for environment_set, (a, b) in finals.items():
        low, high = difference_interval(a, b)
        lines.append(
            f"| {get_set(environment_set).title} | {len(a.finite().values)}, {len(b.finite().values)} | {a.cell()} | {b.cell()} "
            f"| {b.mean - a.mean:+.1f} ({low:+.1f}, {high:+.1f}) | {welch(a, b):.3f} | {below(a, b):.3f} |"
        )
    combined, lower, sign = pooled_test(finals)
    lines += [
        "",
        f"Stouffer's combination of the one-sided tests over the {len(finals)} sets: p = "
        f"{combined:.3f}; swat_jax lower on {lower} of {len(finals)} (sign test p = {sign:.3f}).",
        "",
    ]
    return lines


def pooled_test(finals: Mapping[str, tuple[Final, Final]]) -> tuple[float, int, float]:
    """Over the sets' (original, swat_jax) final returns: Stouffer's combination of the one-sided tests that
    swat_jax is lower, the number of sets on which it is lower, and the sign test's p of that number."""
    lower = sum(b.mean < a.mean for a, b in finals.values())
    return stouffer([below(a, b) for a, b in finals.values()]), lower, sign_test(lower, len(finals))


# The command


Side = Literal["original", "swat_jax"]
"""One side of the comparison (``--only``)."""


@dataclasses.dataclass(frozen=True)
class AgainstOriginalCommand:
    """swat_jax's paper preset beside the original SWAT trainer: the same learning curves, and the wall clock
    of each. A partial run resumes: the same command goes on where it stopped."""

    sets: tuple[str, ...] = ()
    """Environment sets to compare (none: hopper walker; with --speed hopper walker animal_walkers); the original trains hopper, walker, cheetah, humanoid, their unions and animal_walkers."""
    scale: ScaleName = "small"
    """micro (a smoke test: 2 seeds, 600/800 steps), small (width-32 one-layer SWAT, 4 seeds, 24K/30K steps; about 80 min for Hopper++ and Walker++ on 2 CPU cores) or paper (the paper's sizes, 5 seeds, 10M steps)."""
    seeds: int | None = None
    """Seeds of each implementation; None: the scale's."""
    steps: int | None = None
    """Environment steps per seed on every set, summed over bodies; None: the scale's."""
    only: Side | None = None
    """Train one side only (the report shows what exists)."""
    original_python: Path = Path("/tmp/orig-venv/bin/python")
    """Python of the original code's venv: mujoco 2.3.3, gym 0.13.1, torch, xmltodict."""
    original_tools: Path = dataclasses.field(
        default_factory=lambda: Path(os.environ.get("ORIGINAL_TOOLS", ""))
    )
    """The folder with run_trainer.py that runs the original main.py unmodified (default $ORIGINAL_TOOLS)."""
    parallel: int = dataclasses.field(default_factory=host_cores)
    """Seeds of each side run at once, one core each (default: this machine's cores)."""
    original_timeout: float = 6 * 3600.0
    """Seconds after which an original seed is stopped."""
    out: Path = Path("experiments/results/against_original")
    """The folder of runs, figures and the report."""
    seed_bodies: tuple[str, ...] = ()
    """Bodies the report tabulates seed by seed, both sides (final return and episode length, best point, when a seed first reached the original's final return); a set with none of them: its body furthest from the original."""
    dry_run: bool = False
    """Write swat_jax's config files, print both sides' commands and stop."""
    report_only: bool = False
    """Train nothing: write the report (and its pooled test over --sets) from the runs already in --out."""
    speed: bool = False
    """Measure throughput at the paper's sizes (both sides, --sets) and print a Markdown table instead of training curves."""
    speed_seconds: float = 120.0
    """--speed: seconds of each original trainer run."""
    speed_iterations: int = 2
    """--speed: timed iterations of each swat_jax preset, after one warm-up."""


def run_sets(
    out: Path, settings: Settings, sets: Sequence[str], original: Original, only: str | None
) -> None:
    """Train both sides on every set: the original's seeds first, then swat_jax's."""
    for environment_set in sets:
        if only != "swat_jax":
            why = original.missing()
            if why:
                raise GridError(f"cannot run the original trainer: {why}; or give --only swat_jax")
            train_original(original_runs(out, settings, environment_set), original, out)
        if only != "original":
            train_ours(ours(out, settings, environment_set), original.parallel, out)


def print_plan(out: Path, settings: Settings, sets: Sequence[str], original: Original) -> None:
    """The commands a run would start, each original seed and swat_jax's run (new, or where it resumes)."""
    for environment_set in sets:
        for run in original_runs(out, settings, environment_set):
            print(
                f"OMP_NUM_THREADS=1 {shlex.join(run.command(original.python, original.tools, original.timeout))}"
            )
        for run in ours(out, settings, environment_set):
            steps = progress(run)
            state = "new" if steps is None else f"resumes at {steps:,} steps"
            run.write_config()
            print(f"XLA_FLAGS={shlex.quote(SINGLE_THREAD_XLA)} {shown(run.command())}  # {state}")


def main(argv: list[str] | None = None) -> int:
    enable_caches()
    argv = sys.argv[1:] if argv is None else argv
    args = tyro.cli(AgainstOriginalCommand, args=argv, prog="python -m experiments.against_original")
    out = args.out
    original = Original(args.original_python, args.original_tools, args.parallel, args.original_timeout)
    sets = args.sets or (("hopper", "walker", "animal_walkers") if args.speed else ("hopper", "walker"))

    def work() -> Path | None:
        if args.speed:
            why = original.missing()
            if why:
                raise GridError(f"cannot run the original trainer: {why}")
            print(speed_table(sets, original, args.speed_seconds, args.speed_iterations))
            return None
        settings = SETTINGS[args.scale].given(args.seeds, args.steps, sets)
        for environment_set in sets:
            get_set(environment_set)
        if args.dry_run:
            print_plan(out, settings, sets, original)
            return None
        if not args.report_only:
            run_sets(out, settings, sets, original, args.only)
        return report(out, settings, sets, argv, original, args.seed_bodies)

    return exit_status(work)


if __name__ == "__main__":
    sys.exit(main())
