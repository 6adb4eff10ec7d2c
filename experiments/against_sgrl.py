"""swat_jax's paper preset with SGRL's settings beside SGRL's own 3D trainer: learning curves, final returns and
the machine time of each.

    python -m experiments.against_sgrl [--algo swat|set] [--sets 3d_hopper 3d_walker] [--scale small] [--seeds 4] [--epochs 150]
        [--sgrl-python /tmp/sgrl-venv/bin/python] [--original-tools DIR] [--sgrl-tools DIR] [--parallel 2]
        [--only sgrl|swat_jax] [--dry-run] [--report-only] [--out experiments/results/against_sgrl]

On each 3D set, with one network (``--algo``: SWAT, SGRL's baseline, or SET, its own) at the same sizes and
learning rate, the script trains

- SGRL's unmodified ``main.py`` (``--actor_type ALGO --critic_type ALGO``, its ``configs/3d.py`` with
  ``max_epoch`` set to the budget), in its own virtual environment over the original's mujoco_py stand-in, one
  process per seed with one torch thread, ``--parallel`` at a time. Its logger sends its numbers to wandb only;
  a stand-in for wandb (``experiments/sgrl/recorder``) records them. Kept in ``OUT/sgrl/<set>-<algo>-seed<k>/``: that
  record, SGRL's ``logs.txt`` and ``parameters.txt``, and the wall clock;
- ``python -m swat_jax.train --preset paper`` with SGRL's batch (256) and target rate (0.005), one process
  per seed, single-threaded, ``--parallel`` at a time, in ``OUT/runs/<set>-<algo>-swat_jax-seed<k>``, stopping where
  SGRL's counter reaches the budget (``experiments/sgrl/runs.py`` converts it to counted steps).

SGRL records only the mean over bodies of each round's first-episode returns (docs/fidelity.md, row S11), so
the comparison is of that mean: both sides binned on SGRL's counter, a seed's final return its mean over the
budget's last 20%, Welch's test over seeds and the ratio of the means with its 90% interval; swat_jax's own
per-body finals beside it. Written to OUT: ``<set>-<algo>.png``, ``<set>-<algo>.csv``, ``timings.json`` and
``against_sgrl-<algo>.md``. A finished seed is kept; an SGRL seed that stopped part-way is run again from its start,
a swat_jax seed resumes from its newest checkpoint.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from experiments.machine import cpu_model, host_cores, software_versions
from experiments.original.curves import SeedCurves
from experiments.original.returns import (
    SIGNIFICANCE,
    final_returns,
    ratio_interval,
    time_to_reach,
    welch,
)
from experiments.original.runs import SINGLE_THREAD_XLA, train_ours
from experiments.paper import GridError, exit_status, progress, read_timings, shown
from experiments.sgrl.curves import ours_on_counter, sgrl_curves
from experiments.sgrl.runs import OURS, SCALES, SGRL, Sgrl, SgrlScale, ours, sgrl_runs, train_sgrl
from swat_jax.compilation_cache import enable_caches
from swat_jax.morphology import get_set
from swat_jax.plot import curves_figure, save, summarise, write_points_csv
from swat_jax.runs.metrics import read_metrics

Side = Literal["sgrl", "swat_jax"]
COUNTER_LABEL = "SGRL's counter (5,000 after its warm-up, + stored transitions + updates)"


def side_curves(out: Path, scale: SgrlScale, environment_set: str) -> dict[str, list[SeedCurves]]:
    """Each side's finished seeds' curves (a side without any left out)."""
    timings = read_timings(out)
    sides = {}
    finished = [run for run in sgrl_runs(out, scale, environment_set) if run.finished()]
    if finished:
        sides[SGRL] = [sgrl_curves(run) for run in finished]
    mine = [
        curve
        for run in ours(out, scale, environment_set)
        if (run.run_dir / "metrics.csv").is_file()
        for curve in ours_on_counter(read_metrics(run.run_dir), scale, environment_set, timings.get(run.name))
    ]
    if mine:
        sides[OURS] = mine
    return sides


def compare(out: Path, scale: SgrlScale, environment_set: str) -> list[str]:
    """The figure, CSV and Markdown section of one set."""
    sides = side_curves(out, scale, environment_set)
    budget = scale.budget(environment_set)
    title = get_set(environment_set).title
    if not sides:
        return [f"## {title}, {scale.algorithm.upper()}\n\nNothing trained yet."]
    points = [
        point
        for side, curves in sides.items()
        for point in summarise(f"{title}: mean over bodies", side, [c.mean_over_bodies() for c in curves])
    ]
    figure = curves_figure(points, "train")
    for axes in figure.axes:
        axes.set_xlabel(COUNTER_LABEL)
    name = f"{environment_set}-{scale.algorithm}"
    save(figure, out / f"{name}.png")
    write_points_csv(points, out / f"{name}.csv")
    finals = {side: final_returns(curves, scale, environment_set) for side, curves in sides.items()}
    lines = [
        f"## {title}, {scale.algorithm.upper()}, SGRL's counter {budget:,}",
        "",
        f"![{name}]({name}.png)",
        "",
        f"Every plotted number: [{name}.csv]({name}.csv). A seed's final return: its mean "
        f"over bodies, averaged over the points of the budget's last {scale.final_fraction:.0%}; mean ± "
        "standard error over seeds.",
        "",
        "| implementation | seeds | first point | final return | machine min per seed to the budget |",
        "|---|---|---|---|---|",
    ]
    for side, curves in sides.items():
        first = float(np.mean([next(iter(c.mean_over_bodies().values())) for c in curves]))
        minutes = np.mean([c.seconds[max(c.seconds)] for c in curves]) / 60
        lines.append(f"| {side} | {len(curves)} | {first:.1f} | {finals[side].cell()} | {minutes:.1f} |")
    if len(sides) == 2 and all(len(final.finite().values) >= 2 for final in finals.values()):
        lines += difference_lines(sides, finals)
    if OURS in sides:
        lines += body_lines(sides[OURS], scale, environment_set)
    return lines


def difference_lines(sides: Mapping[str, Sequence[SeedCurves]], finals: Mapping) -> list[str]:
    """Welch's test, the ratio of the means with its 90% interval, and each side's time to SGRL's final return."""
    a, b = finals[SGRL], finals[OURS]
    p = welch(a, b)
    low, high = ratio_interval(a, b)
    verdict = "within the noise" if p >= SIGNIFICANCE else "beyond the noise"
    reached = {side: time_to_reach(curves, a.mean) for side, curves in sides.items()}
    return [
        "",
        f"swat_jax / SGRL: {b.mean / a.mean:.2f} (90% interval {low:.2f} to {high:.2f}); Welch's two-sided "
        f"p = {p:.3f}, {verdict} (at {SIGNIFICANCE}). Machine time to SGRL's final return ({a.mean:.1f}) on the "
        "mean-over-seeds curve: "
        + "; ".join(f"{side} {'never' if t is None else f'{t / 60:.1f} min'}" for side, t in reached.items())
        + ".",
    ]


def body_lines(curves: Sequence[SeedCurves], scale: SgrlScale, environment_set: str) -> list[str]:
    """swat_jax's final return per body (SGRL records none per body)."""
    lines = ["", "swat_jax per body (SGRL's logger records the mean over bodies only):", ""]
    lines += ["| body | final return | seeds |", "|---|---|---|"]
    for body in get_set(environment_set).train:
        final = final_returns(curves, scale, environment_set, body)
        lines.append(f"| {body} | {final.cell()} | {', '.join(f'{v:.0f}' for v in final.finite().values)} |")
    return lines


def report(out: Path, scale: SgrlScale, sets: Sequence[str], argv: Sequence[str], sgrl: Sgrl) -> Path:
    versions = ", ".join(f"{name} {version}" for name, version in software_versions().items())
    lines = [
        f"# swat_jax beside SGRL's 3D trainer, scale {scale.name}",
        "",
        f"- Command: `python -m experiments.against_sgrl {shlex.join(argv)}`",
        f"- Date: {datetime.date.today().isoformat()}",
        f"- Machine: {cpu_model()}, {host_cores()} cores; {versions}",
        f"- Both: {scale.algorithm.upper()} actor and critic of width {scale.width}, {scale.heads} heads, {scale.layers} layers, "
        f"feed-forward {scale.feedforward}; learning rate {scale.learning_rate}; {scale.seeds} seeds, each one "
        f"process on one core, {sgrl.parallel} at a time. SGRL: its configs/3d.py with max_epoch "
        f"{', '.join(f'{s} {scale.epochs[s]}' for s in sets)}. swat_jax: the paper preset, batch 256, target "
        f"rate 0.005, {scale.random_steps:,} random steps per body.",
        "",
    ]
    for environment_set in sets:
        lines += [*compare(out, scale, environment_set), ""]
    path = out / f"against_sgrl-{scale.algorithm}.md"
    path.write_text("\n".join(lines))
    return path


@dataclasses.dataclass(frozen=True)
class AgainstSgrlCommand:
    """swat_jax's paper preset with SGRL's settings beside SGRL's own 3D trainer. A partial run resumes: the
    same command goes on where it stopped."""

    sets: tuple[str, ...] = ("3d_hopper", "3d_walker")
    """3D sets to compare (SGRL trains 3d_hopper, 3d_walker, 3d_humanoid, 3d_cheetah, 3d_whh, 3d_cwhh)."""
    algo: Literal["swat", "set"] = "swat"
    """The network of both sides' actor and critic: SWAT (SGRL's baseline) or SET (SGRL's own)."""
    scale: Literal["micro", "small"] = "small"
    """micro (a smoke test: 2 seeds, SGRL's warm-up and an epoch or two) or small (width-32 one-layer SWAT, 4 seeds, SGRL's counter 150,000)."""
    seeds: int | None = None
    """Seeds of each side; None: the scale's."""
    epochs: int | None = None
    """SGRL's max_epoch on every set (the budget is 1,000 x this in its counter); None: the scale's."""
    only: Side | None = None
    """Train one side only (the report shows what exists)."""
    sgrl_python: Path = Path("/tmp/sgrl-venv/bin/python")
    """Python of SGRL's venv: mujoco 2.3.3, gym 0.13.1, numpy 1.x, torch, tqdm, opencv, imageio."""
    original_tools: Path = dataclasses.field(
        default_factory=lambda: Path(os.environ.get("ORIGINAL_TOOLS", ""))
    )
    """The original code's tools, for their mujoco_py stand-in in shim/ (default $ORIGINAL_TOOLS)."""
    sgrl_tools: Path = dataclasses.field(default_factory=lambda: Path(os.environ.get("SGRL_TOOLS", "")))
    """SGRL's tools, whose record_sgrl.py makes its working copy in $SGRL_DIR (default $SGRL_TOOLS)."""
    parallel: int = dataclasses.field(default_factory=host_cores)
    """Seeds of each side run at once, one core each (default: this machine's cores)."""
    sgrl_timeout: float = 6 * 3600.0
    """Seconds after which an SGRL seed is stopped."""
    out: Path = Path("experiments/results/against_sgrl")
    """The folder of runs, figures and the report."""
    dry_run: bool = False
    """Write swat_jax's config files, print both sides' commands and stop."""
    report_only: bool = False
    """Train nothing: write the report from the runs already in --out."""


def print_plan(out: Path, scale: SgrlScale, sets: Sequence[str], sgrl: Sgrl) -> None:
    """The commands a run would start: each SGRL seed (in SGRL's src/) and each swat_jax seed."""
    for environment_set in sets:
        for run in sgrl_runs(out, scale, environment_set):
            state = "done" if run.finished() else "new"
            print(f"(cd SGRL_DIR/src) {shlex.join(run.command(sgrl.python))}  # {state}")
        for run in ours(out, scale, environment_set):
            steps = progress(run)
            run.write_config()
            state = "new" if steps is None else f"resumes at {steps:,} steps"
            print(f"XLA_FLAGS={shlex.quote(SINGLE_THREAD_XLA)} {shown(run.command())}  # {state}")


def main(argv: list[str] | None = None) -> int:
    enable_caches()
    argv = sys.argv[1:] if argv is None else argv
    args = tyro.cli(AgainstSgrlCommand, args=argv, prog="python -m experiments.against_sgrl")
    sgrl = Sgrl(args.sgrl_python, args.original_tools, args.sgrl_tools, args.parallel, args.sgrl_timeout)

    def work() -> Path | None:
        scale = SCALES[args.scale].given(args.seeds, args.epochs, args.sets, args.algo)
        for environment_set in args.sets:
            scale.budget(environment_set)
        if args.dry_run:
            print_plan(args.out, scale, args.sets, sgrl)
            return None
        if not args.report_only:
            for environment_set in args.sets:
                if args.only != "swat_jax":
                    why = sgrl.missing()
                    if why:
                        raise GridError(f"cannot run SGRL's trainer: {why}; or give --only swat_jax")
                    train_sgrl(sgrl_runs(args.out, scale, environment_set), sgrl, args.out)
                if args.only != "sgrl":
                    train_ours(ours(args.out, scale, environment_set), args.parallel, args.out)
        return report(args.out, scale, args.sets, argv, sgrl)

    return exit_status(work)


if __name__ == "__main__":
    sys.exit(main())
