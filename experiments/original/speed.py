"""Throughput at the paper's sizes (``against_original --speed``): the original trainer on one thread and
on all of them, swat_jax's paper and fast presets, in one sitting."""

from __future__ import annotations

import dataclasses
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Sequence

from experiments.machine import host_cores
from experiments.original import runs
from experiments.original.runs import ORIGINAL_SET_FLAGS, SETTINGS, Original
from experiments.paper import (
    GridError,
)
from swat_jax.morphology import get_set


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
    shutil.rmtree(runs.ORIGINAL_WORK / "src" / "results" / experiment_id, ignore_errors=True)
    environment = {**os.environ, "ORIG_SWAT_DIR": str(runs.ORIGINAL_WORK)}
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
        label, updates, updates, updates * SETTINGS["paper"].batch_size, seconds - float(window.group(1))
    )


def ours_speed(preset: str, environment_set: str, iterations: int) -> Speed:
    """swat_jax's ``preset`` at the paper's network sizes on ``environment_set``, acting from its first step."""
    from experiments.benchmarks.presets import measure
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
