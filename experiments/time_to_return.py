"""Time to a trained policy: machine seconds per seed for swat_jax's configurations to reach the original
SWAT trainer's final return, beside the original's own.

    python -m experiments.time_to_return [--sets hopper walker] [--scale small] [--candidates paper fast]
        [--seeds 4] [--steps 120000] [--window 3] [--horizon 1.5] [--original-from experiments/results/against_original]
        [--out DIR] [--dry-run]

On one environment set, at a scale of experiments/against_original.py (the same network sizes, learning
rate, random-start steps, replay size and step budget as the original trainer's runs), the script trains
each candidate configuration of swat_jax with every seed in one program, and reads the original's
curves from its committed runs (``--original-from``: ``original/<set>-seed<k>/`` with its ``stat.json``
and trainer log, as against_original.py writes them; run that script with ``--only original`` for new
ones).

Two x axes:

- counted environment steps, summed over bodies (the original's budget and curves count these);
- machine seconds per seed: wall clock x cores used / seeds run at once, start-up and compilation
  included. The original runs one seed per process on one core (torch with one thread), so its machine
  seconds per seed are its own wall clock; swat_jax runs every seed in one program on all
  ``host_cores()`` cores.

``--horizon H`` trains swat_jax's candidates for H times the original's budget (rounded up to a curve
point): the time to R counts wherever the curve reaches it, the final return is still the budget's. A run
that stopped at a shorter horizon continues from its last checkpoint.

R is the original's final return (the mean over seeds of each seed's mean over the points of the
budget's last 20%, as against_original.py). A curve reaches R at its first point where the mean over
seeds, smoothed by a trailing mean over ``--window`` points, is at least R; a curve that never does is
reported as "not reached" with its last point's time as a lower bound. The original's own time to R is
measured the same way on its own curve, or, where its smoothed curve stays just below its final return
(which averages the budget's last 20%), is its time at the budget. Per candidate: the machine seconds per seed to R, its ratio to
the original's, the final return at the original's budget with Welch's two-sided t-test against the
original's seeds.

Written to OUT (default experiments/results/time_to_return): ``<set>.png`` (the mean return over bodies
against both x axes, mean ± standard error over seeds, R dashed), ``<set>.csv`` (every plotted number),
``time_to_return.md`` (the table), ``timings.json`` (each run's wall clock). A partial run resumes: a
run that reached its budget is kept, one that stopped part-way resumes from its newest checkpoint.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import math
import os
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import tyro

from experiments.machine import cpu_model, host_cores, software_versions
from experiments.original.curves import SeedCurves, original_curves, ours_curves
from experiments.original.returns import Final, final_returns, welch
from experiments.original.runs import SETTINGS, ScaleName, Settings, original_runs, paper_config
from experiments.paper import GridError, RunSpec, exit_status, progress, read_timings, shown, train_all
from swat_jax.compilation_cache import enable_caches
from swat_jax.morphology import get_set
from swat_jax.plot import new_figure, save
from swat_jax.runs.config import PRESETS, TrainConfig
from swat_jax.runs.metrics import read_metrics, standard_error

ORIGINAL = "original (PyTorch)"


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A swat_jax configuration of the search: a preset at the scale's sizes and hyperparameters, with these
    changes (None: the preset's)."""

    preset: str = "fast"
    copies: int | None = None
    """Environment copies per body."""
    chunk: int | None = None
    """Steps per copy per iteration."""
    updates: int | None = None
    """Updates per iteration."""
    batch: int | None = None
    """Batch per body."""
    learning_rate: float | None = None
    noise: tuple[float, float] | None = None
    """Each copy's exploration noise std, spread evenly from the first to the second."""
    c51: bool = False
    """A distributional critic of 51 atoms on [-100, 400] (FastTD3's C51 critic)."""
    initialisation: str | None = None
    """Initial weights: flax or original (the original PyTorch code's)."""
    normalise: bool | None = None
    """Observations standardised by running statistics (FastTD3's normaliser)."""
    n_step: int | None = None
    """Rewards summed into each TD target (``--td3.n-step``)."""
    pessimism: float | None = None
    """How far below the twin target critics' mean TD targets bootstrap (``--td3.target-pessimism``; 0: their
    mean)."""
    reward_scaling: bool | None = None
    """Each body's rewards divided by the spread of its discounted returns (``--td3.reward-scaling``)."""
    action_penalty: float | None = None
    """Weight of the actor's penalty on its pre-tanh outputs squared (``--td3.action-penalty``)."""
    action_penalty_from: float | None = None
    """|pre-tanh output| from which the penalty counts (``--td3.action-penalty-from``)."""

    def config(self, scaled: TrainConfig) -> TrainConfig:
        """``scaled`` (the preset at the scale's settings) with this candidate's changes."""
        iteration = dataclasses.replace(scaled.iteration, **_given(chunk=self.chunk, updates=self.updates))
        if self.noise is not None:
            iteration = dataclasses.replace(
                iteration, exploration_noise=self.noise[0], exploration_noise_max=self.noise[1]
            )
        td3 = dataclasses.replace(
            scaled.td3,
            **_given(
                batch_size=self.batch,
                learning_rate=self.learning_rate,
                n_step=self.n_step,
                target_pessimism=self.pessimism,
                reward_scaling=self.reward_scaling,
                action_penalty=self.action_penalty,
                action_penalty_from=self.action_penalty_from,
            ),
        )
        if self.c51:
            td3 = dataclasses.replace(td3, atoms=51, value_min=-100.0, value_max=400.0)
        envs = dataclasses.replace(scaled.envs, **_given(copies=self.copies))
        network = dataclasses.replace(
            scaled.network,
            **_given(initialisation=self.initialisation, observation_normalisation=self.normalise),
        )
        return dataclasses.replace(scaled, envs=envs, iteration=iteration, td3=td3, network=network)


def _given(**values: Any) -> dict[str, Any]:
    """The ``values`` that are not None."""
    return {name: value for name, value in values.items() if value is not None}


CANDIDATES: dict[str, Candidate] = {
    "paper": Candidate("paper"),
    "paper-2dev": Candidate("paper"),
    "paper-flax-2dev": Candidate("paper", initialisation="flax"),
    "fast": Candidate(),
    "fast-2dev": Candidate(),
    "fast-rscale-p0.5-2dev": Candidate(reward_scaling=True, pessimism=0.5, action_penalty=0.0),
    "fast-ap0.01-2dev": Candidate(action_penalty=0.01),
    "fast-ap0.1-2dev": Candidate(action_penalty=0.1),
    "fast-ap0.003-2dev": Candidate(action_penalty=0.003, pessimism=0.5),
    "fast-ap0.1-from2-2dev": Candidate(action_penalty=0.1, action_penalty_from=2.0),
    "fast-ap0.003-p0-2dev": Candidate(action_penalty=0.003, pessimism=0.0),
    "fast-ap0.003-p0.25-2dev": Candidate(action_penalty=0.003, pessimism=0.25),
}
"""swat_jax configurations by name: ``paper`` is against_original's run (the paper preset in lock-step rounds,
stopping at the original's counted budget); every other is its preset at the scale's sizes and
hyperparameters with the candidate's changes, trained for the original's budget. ``paper-flax``: the paper
preset with Flax's initial weights; ``-rscale`` with per-body reward scaling, ``-pX`` at target pessimism
X, ``-apW`` with the actor's action penalty W, ``-fromU`` counting it from |u| = U; ``-Ndev``: the same
with the CPU's cores as N JAX devices (:data:`CPU_DEVICES`). ``fast`` and ``fast-2dev`` are the preset of
the day (``fast-ap0.003-p0.25-2dev`` spelled out; ``fast-ap0.003-2dev`` is the preset before it, at
pessimism 0.5). The candidates of the searches before are retired: each one's config is in the results folder that
reports it, ``runs/<set>-<candidate>/config.json`` (experiments/LAB.md, "Retired candidates")."""
CPU_DEVICES: dict[str, int] = {name: 2 for name in CANDIDATES if name.endswith("-2dev")}
"""Candidates run as N CPU devices (``--xla_force_host_platform_device_count``, the seeds split over
them: XLA runs each device's share on its own thread; 1.11x on the fast preset's iteration with 2,
BENCHMARKS.md)."""


@dataclasses.dataclass(frozen=True)
class DeviceRun(RunSpec):
    """A run whose process sees ``devices`` CPU devices."""

    devices: int = 1

    def command(self) -> list[str]:
        return self._on_devices(super().command())

    def resume_command(self) -> list[str]:
        return self._on_devices(super().resume_command())

    def _on_devices(self, command: list[str]) -> list[str]:
        """``command`` run with XLA_FLAGS that give its process :attr:`devices` CPU devices."""
        if self.devices == 1:
            return command
        flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={self.devices}"
        return ["env", f"XLA_FLAGS={flags.strip()}", *command]


@dataclasses.dataclass(frozen=True)
class Curve:
    """One configuration's seeds on the grid: {counted steps: return} per seed (mean over bodies) and
    {counted steps: machine seconds per seed}."""

    name: str
    returns: tuple[dict[int, float], ...]
    seconds: tuple[dict[int, float], ...]
    finals: Final
    body_finals: dict[str, Final]
    """Each body's final returns, by body."""

    def points(self) -> list[tuple[int, float, float, float]]:
        """(steps, machine seconds per seed, mean return, standard error) at every step where a seed has a
        value: the means over the seeds that have one."""
        rows = []
        for step in sorted({step for curve in self.returns for step in curve}):
            values = np.array([curve[step] for curve in self.returns if step in curve])
            seconds = [s[step] for s in self.seconds if step in s]
            rows.append((step, float(np.mean(seconds)), float(np.mean(values)), standard_error(values)))
        return rows


def smoothed_crossing(points: Sequence[tuple[int, float, float, float]], target: float, window: int):
    """The first point (steps, seconds) at which the trailing mean of the mean return over ``window``
    points (fewer at the start) reaches ``target``; None if none does."""
    means = [mean for _, _, mean, _ in points]
    for index, (step, seconds, _, _) in enumerate(points):
        recent = means[max(0, index - window + 1) : index + 1]
        if np.mean(recent) >= target:
            return step, seconds
    return None


def original_time(original: Curve, window: int) -> tuple[int, float]:
    """(steps, machine seconds per seed) at which the original reaches R, its own final return: its smoothed
    curve's first point at R, or its last point where the smoothed curve stays just below (the final return
    averages the budget's last points)."""
    return smoothed_crossing(original.points(), original.finals.mean, window) or original.points()[-1][:2]


def machine_seconds(curves: Sequence[SeedCurves], cores: float, seeds_at_once: int) -> tuple[dict, ...]:
    """Each seed's wall clock at its grid points as machine seconds per seed."""
    return tuple({step: t * cores / seeds_at_once for step, t in c.seconds.items()} for c in curves)


def with_horizon(settings: Settings, environment_set: str, horizon: float) -> Settings:
    """``settings`` with ``environment_set``'s budget ``horizon`` times as long, rounded up to a curve point."""
    interval = settings.log_interval(environment_set)
    steps = math.ceil(settings.budget(environment_set) * horizon / interval) * interval
    return dataclasses.replace(settings, steps={**settings.steps, environment_set: steps})


def candidate_run(out: Path, settings: Settings, environment_set: str, name: str) -> RunSpec:
    """The swat_jax run of candidate ``name``: the scale's sizes and hyperparameters, every seed in one
    program, a metrics row at least every curve interval, for ``settings``' budget (the horizon's)."""
    if name not in CANDIDATES:
        raise GridError(f"unknown candidate {name!r}; candidates: {', '.join(CANDIDATES)}")
    devices, run_dir = CPU_DEVICES.get(name, 1), out / "runs" / f"{environment_set}-{name}"
    candidate = CANDIDATES[name]
    if candidate.preset == "paper":
        scaled = paper_config(settings, environment_set, run_dir)
    else:
        interval = settings.log_interval(environment_set)
        steps = settings.budget(environment_set)
        scaled = settings.config(
            PRESETS[candidate.preset], environment_set, run_dir, steps=steps, log_interval=interval
        )
    return DeviceRun(candidate.config(scaled), devices)


def candidate_curve(
    out: Path,
    settings: Settings,
    environment_set: str,
    name: str,
    timings: Mapping[str, float],
    horizon: float,
    cores: int | None = None,
) -> Curve | None:
    """Candidate ``name``'s curve up to the horizon, with its final returns at ``settings``' budget; its
    machine seconds for a run on ``cores`` (None: this machine's)."""
    longer = with_horizon(settings, environment_set, horizon)
    run = candidate_run(out, longer, environment_set, name)
    if not (run.run_dir / "metrics.csv").is_file():
        return None
    curves = ours_curves(read_metrics(run.run_dir), longer, environment_set, timings.get(run.name))
    return _curve(name, curves, settings, environment_set, cores or host_cores(), len(curves))


def original_curve(original_out: Path, settings: Settings, environment_set: str) -> Curve | None:
    """The original's finished runs of ``environment_set`` in ``original_out`` (seeds 0 to ``settings.seeds``
    - 1), as one curve; None if none finished."""
    runs = [run for run in original_runs(original_out, settings, environment_set) if run.finished()]
    if not runs:
        return None
    return _curve(ORIGINAL, [original_curves(run) for run in runs], settings, environment_set, 1, 1)


def _curve(
    name: str,
    curves: Sequence[SeedCurves],
    settings: Settings,
    environment_set: str,
    cores: float,
    seeds_at_once: int,
) -> Curve:
    """The :class:`Curve` of one configuration's seeds, run ``seeds_at_once`` at a time on ``cores``."""
    return Curve(
        name,
        tuple(c.mean_over_bodies() for c in curves),
        machine_seconds(curves, cores, seeds_at_once),
        final_returns(curves, settings, environment_set),
        {
            body: final_returns(curves, settings, environment_set, body)
            for body in get_set(environment_set).train
        },
    )


def figure(curves: Sequence[Curve], target: float, budget: int, title: str, path: Path) -> None:
    """Mean return over bodies against counted steps (the original's budget dotted) and against machine
    seconds per seed, side by side under one title."""
    fig = new_figure()
    axes = fig.subplots(1, 2)
    for index, curve in enumerate(curves):
        points = curve.points()
        steps, seconds, means, errors = (np.array(column) for column in zip(*points, strict=True))
        errors = np.nan_to_num(errors)
        for ax, x in zip(axes, (steps, seconds), strict=True):
            ax.plot(x, means, color=f"C{index}", label=curve.name)
            ax.fill_between(x, means - errors, means + errors, color=f"C{index}", alpha=0.2)
    for ax, label in zip(
        axes, ("counted environment steps (all bodies)", "machine seconds per seed"), strict=True
    ):
        ax.axhline(target, color="k", linestyle="--", linewidth=1, label=f"R = {target:.1f}")
        if label.startswith("counted"):
            ax.axvline(budget, color="grey", linestyle=":", linewidth=1, label="the original's budget")
        ax.set_xlabel(label)
        ax.set_ylabel("return (training episodes, mean over bodies)")
        ax.legend(loc="lower right", fontsize="small")
    fig.suptitle(title)
    fig.set_size_inches(12, 4.5)
    save(fig, path)


def write_csv(curves: Sequence[Curve], path: Path) -> None:
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(
            ["configuration", "counted_steps", "machine_seconds_per_seed", "mean_return", "standard_error"]
        )
        for curve in curves:
            for row in curve.points():
                writer.writerow([curve.name, *row])


def set_section(
    out: Path,
    original_out: Path,
    settings: Settings,
    environment_set: str,
    names: Sequence[str],
    window: int,
    horizon: float,
    original_seeds: int,
) -> list[str]:
    """Figure, CSV and the Markdown section of one set, against the original's first ``original_seeds`` seeds."""
    timings = read_timings(out)
    original = original_curve(
        original_out, dataclasses.replace(settings, seeds=original_seeds), environment_set
    )
    if original is None:
        raise GridError(
            f"no finished original runs of {environment_set} at scale {settings.name} in {original_out}/original; "
            "run python -m experiments.against_original --only original, or give --original-from"
        )
    candidates = [
        c for name in names if (c := candidate_curve(out, settings, environment_set, name, timings, horizon))
    ]
    target = original.finals.mean
    label = get_set(environment_set).description or environment_set
    curves = [original, *candidates]
    budget = settings.budget(environment_set)
    seeds = f"{settings.seeds} seeds" + (
        "" if original_seeds == settings.seeds else f", the original's {len(original.returns)}"
    )
    figure(curves, target, budget, f"{label}, {seeds}", out / f"{environment_set}.png")
    write_csv(curves, out / f"{environment_set}.csv")
    reference = original_time(original, window)
    lines = [
        f"## {label}, {settings.budget(environment_set):,} steps",
        "",
        f"![{environment_set}]({environment_set}.png)",
        "",
        f"R = {target:.1f}, the original's final return. Every plotted number: [{environment_set}.csv]"
        f"({environment_set}.csv).",
        "",
        "| configuration | seeds | machine s per seed to R | ratio to the original | steps to R | final return at the budget | Welch p against the original |",
        "|---|---|---|---|---|---|---|",
    ]
    for curve in curves:
        crossing = reference if curve is original else smoothed_crossing(curve.points(), target, window)
        last_seconds = curve.points()[-1][1]
        if crossing is None:
            seconds, ratio, steps = f"not reached (> {last_seconds:.0f})", "-", "-"
        else:
            seconds, steps = f"{crossing[1]:.0f}", f"{crossing[0]:,}"
            ratio = f"{crossing[1] / reference[1]:.2f}"
        p = "-" if curve is original else f"{welch(curve.finals, original.finals):.3f}"
        lines.append(
            f"| {curve.name} | {len(curve.returns)} | {seconds} | {ratio} | {steps} | "
            f"{curve.finals.mean:.1f} ± {curve.finals.standard_error:.1f} | {p} |"
        )
    return [*lines, "", *body_finals_table(original, candidates), "", *stranded_table(original, candidates)]


def body_finals_table(original: Curve, candidates: Sequence[Curve]) -> list[str]:
    """Each body's final return at the budget by configuration, with Welch's p against the original's:
    where the mean over bodies gains or loses. A seed that finished no episode of the body in the budget's
    last points (episodes longer than that window) is left out, and the cell says how many seeds are in."""
    bodies = list(original.body_finals)
    lines = [
        "Final return at the budget by body (mean ± standard error over seeds; Welch's p against the original):",
        "",
        f"| configuration | {' | '.join(bodies)} |",
        f"|---|{'---|' * len(bodies)}",
    ]
    for curve in [original, *candidates]:
        cells = []
        for body in bodies:
            runs, final = len(curve.body_finals[body].values), curve.body_finals[body].finite()
            if not len(final.values):
                cells.append("no episode ended")
                continue
            reference = original.body_finals[body].finite()
            p = "" if curve is original else f" ({welch(final, reference):.2f})"
            seeds = "" if len(final.values) == runs else f", {len(final.values)} of {runs} seeds"
            cells.append(f"{final.mean:.1f} ± {final.standard_error:.1f}{p}{seeds}")
        lines.append(f"| {curve.name} | {' | '.join(cells)} |")
    return lines


def stranded_table(original: Curve, candidates: Sequence[Curve]) -> list[str]:
    """Per body and configuration, the seeds whose final return there is below every seed of the
    original's: where a recipe strands seeds on a plateau (a seed that never walks) rather than learning
    a little less on every seed. A seed drawn like the original's N falls below all of them by chance one
    time in N + 1 (1 in 5 against 4 seeds)."""
    bodies = list(original.body_finals)
    chance = len(original.finals.values) + 1
    lines = [
        f"Seeds below the original's lowest seed on each body (stranded seeds; by chance alone about 1 in {chance}):",
        "",
        f"| configuration | {' | '.join(bodies)} | all bodies |",
        f"|---|{'---|' * (len(bodies) + 1)}",
    ]
    for curve in candidates:
        cells = []
        for body in bodies:
            lowest = np.nanmin(original.body_finals[body].values)
            final = curve.body_finals[body].finite()
            cells.append(f"{int(np.sum(final.values < lowest))} of {len(final.values)}")
        below = int(np.sum(curve.finals.values < np.min(original.finals.values)))
        lines.append(f"| {curve.name} | {' | '.join(cells)} | {below} of {len(curve.finals.values)} |")
    return lines


def report(
    out: Path,
    original_out: Path,
    settings: Settings,
    sets: Sequence[str],
    names: Sequence[str],
    window: int,
    horizon: float,
    argv,
    original_seeds: int | None = None,
) -> Path:
    """``time_to_return.md`` in ``out``: every set's section, against the original's first
    ``original_seeds`` seeds (None: as many as ``settings.seeds``)."""
    original_seeds = original_seeds or settings.seeds
    versions = ", ".join(f"{name} {version}" for name, version in software_versions().items())
    s = settings
    lines = [
        f"# Time to the original's final return, scale {s.name}",
        "",
        f"- Command: `python -m experiments.time_to_return {shlex.join(argv)}`",
        f"- Date: {datetime.date.today().isoformat()}",
        f"- Machine: {cpu_model()}, {host_cores()} cores; {versions}",
        f"- Every run: SWAT of width {s.width}, {s.heads} heads, {s.layers} layers, feed-forward {s.feedforward}; "
        f"learning rate {s.learning_rate}; {s.random_steps:,} random-action steps per body; replay "
        f"{s.capacity:,} per body; {s.seeds} seeds. The original: its committed runs in {original_out} (seeds 0 to "
        f"{original_seeds - 1}), one "
        "process per seed on one core. swat_jax: every seed in one program on all cores.",
        f"- Machine seconds per seed: wall clock x cores used / seeds at once, start-up and compilation "
        f"included. A curve reaches R at its first point where the mean over seeds, smoothed by a trailing "
        f"mean over {window} points, is at least R (the original: that point, or its budget's end if its "
        "smoothed curve stays below its own final return)."
        + (
            f" swat_jax trains for {horizon:g} times the original's budget; the final return is the budget's."
            if horizon != 1
            else ""
        ),
        "",
    ]
    for environment_set in sets:
        section = set_section(
            out, original_out, settings, environment_set, names, window, horizon, original_seeds
        )
        lines += [*section, ""]
    path = out / "time_to_return.md"
    path.write_text("\n".join(lines))
    return path


@dataclasses.dataclass(frozen=True)
class TimeToReturnCommand:
    """Machine seconds per seed for swat_jax's configurations to reach the original trainer's final return.
    A partial run resumes: the same command goes on where it stopped."""

    sets: tuple[str, ...] = ("hopper", "walker")
    """Environment sets."""
    scale: ScaleName = "small"
    """against_original's scale: the sizes, hyperparameters and budget of the original's runs."""
    candidates: tuple[str, ...] = tuple(CANDIDATES)
    """swat_jax configurations to train (names of CANDIDATES: paper, fast, fast-2dev, ...; default all)."""
    seeds: int | None = None
    """Seeds of every configuration; None: the scale's."""
    original_seeds: int | None = None
    """The original's seeds in --original-from that R, the Welch tests and the stranded-seed count use (its
    seeds 0 to N - 1); None: --seeds."""
    steps: int | None = None
    """Counted environment steps per seed on every set, summed over bodies: the original's budget, which its runs in --original-from must have run (against_original.py --steps); None: the scale's."""
    window: int = 3
    """Curve points of the trailing mean that must reach R."""
    original_from: Path = Path("experiments/results/against_original")
    """The folder whose original/<set>-seed<k>/ hold the original's runs."""
    out: Path = Path("experiments/results/time_to_return")
    """Runs, figures and the report."""
    horizon: float = 1.0
    """Train swat_jax's candidates for this many times the original's budget; the time to R counts past the budget, the final return stays the budget's."""
    dry_run: bool = False
    """Write the runs' config files, print their commands and stop."""
    report_only: bool = False
    """Train nothing: write the report from the runs that exist (a candidate without one is left out)."""


def main(argv: list[str] | None = None) -> int:
    enable_caches()
    argv = sys.argv[1:] if argv is None else argv
    args = tyro.cli(TimeToReturnCommand, args=argv, prog="python -m experiments.time_to_return")

    def work() -> Path | None:
        settings = SETTINGS[args.scale].given(args.seeds, args.steps, args.sets)
        if args.window < 1:
            raise GridError(f"--window must be 1 or more, got {args.window}")
        if not args.horizon >= 1:
            raise GridError(
                f"--horizon must be 1 or more (a multiple of the original's budget), got {args.horizon}"
            )
        runs = [
            candidate_run(args.out, with_horizon(settings, s, args.horizon), s, name)
            for s in args.sets
            for name in args.candidates
        ]
        if args.dry_run:
            for run in runs:
                steps = progress(run)
                state = "new" if steps is None else f"resumes at {steps:,} steps"
                run.write_config()
                print(f"{shown(run.command())}  # {state}")
            return None
        if not args.report_only:
            train_all(runs, args.out)
        return report(
            args.out,
            args.original_from,
            settings,
            args.sets,
            args.candidates,
            args.window,
            args.horizon,
            argv,
            args.original_seeds,
        )

    return exit_status(work)


if __name__ == "__main__":
    sys.exit(main())
