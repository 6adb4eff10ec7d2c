"""What the learning diagnostics cost: a preset's training iteration with ``--iteration.diagnostics`` on and
off, timed alternately in one process (on, off, on, off, ...) so that a drift of the machine falls on both.

Each preset runs with its own network and hyperparameters on the set, the policy acting from the first step
(``random_steps=0``), so the timed iterations are the steady state; reported per preset: seconds per
iteration with and without, and the overhead of the diagnostics as a share of the iteration without them
(the budget is 3%).

    python -m experiments.benchmarks.diagnostics [--env walker] [--presets fast paper] [--seeds 4]
        [--iterations 20] [--repeats 3]
"""

from __future__ import annotations

import dataclasses
import statistics

import jax
import tyro

from experiments.benchmarks.presets import measure
from experiments.machine import cpu_model
from swat_jax.compilation_cache import enable_caches
from swat_jax.runs.config import PRESETS, Preset, TrainConfig


@dataclasses.dataclass(frozen=True)
class Options:
    """What the learning diagnostics cost: a preset's iteration with them and without, timed alternately."""

    env: str = "walker"
    """Environment set."""
    presets: tuple[Preset, ...] = ("fast",)
    """Presets to time, each with its own network."""
    seeds: int = 4
    """Seeds in each program."""
    iterations: int = 20
    """Timed iterations per measurement."""
    repeats: int = 3
    """Measurements of each side, alternating; the median is reported."""


def configured(preset: Preset, env: str, seeds: int, diagnostics: bool) -> TrainConfig:
    """``preset`` on ``env`` with ``seeds`` seeds, acting from the first step, diagnostics on or off."""
    base = PRESETS[preset]
    iteration = dataclasses.replace(base.iteration, random_steps=0, diagnostics=diagnostics)
    return dataclasses.replace(base, env=env, seeds=seeds, iteration=iteration)


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.diagnostics")
    print(
        f"{args.env}, {args.seeds} seeds, {len(jax.devices())} {jax.devices()[0].platform} devices: {cpu_model()}"
    )
    print("\n| preset | s per iteration, diagnostics on | off | overhead |")
    print("|---|---|---|---|")
    for preset in args.presets:
        seconds: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(args.repeats):
            for diagnostics in (True, False):
                config = configured(preset, args.env, args.seeds, diagnostics)
                seconds[diagnostics].append(measure(preset, config, args.iterations).seconds_per_iteration)
        on, off = statistics.median(seconds[True]), statistics.median(seconds[False])
        print(f"| {preset} | {on:.4f} | {off:.4f} | {100 * (on / off - 1):+.1f}% |", flush=True)


if __name__ == "__main__":
    main()
