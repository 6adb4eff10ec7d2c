"""Training iterations over a device mesh against one device: environment steps per second after compilation.

Each arm runs in a fresh process (:mod:`experiments.workers`) with ``--xla_force_host_platform_device_count``
fake CPU devices (the flag must be set before JAX starts) and trains over the first N of them, as
``train --devices N`` lays a run out (:mod:`swat_jax.td3.sharding`), timed by the preset benchmark's
``measure``. On a CPU the fake devices share the same cores, so this measures what the partitioning
costs, not a speed-up; on a multi-GPU machine ``--real`` uses the real devices.

    python -m experiments.benchmarks.sharding [--env hopper] [--seeds 4] [--devices 1 2 4] [--iterations 5]
        [--preset fast] [--overlap-steps 20]

With more than one device on MuJoCo C physics it also records when each device's physics calls run
(``CSimulator.timeline``) over ``--overlap-steps`` environment steps of the run's bodies and prints their
concurrency: the calls' summed time over the time in which any call ran (1.0: the devices take turns; N: N
devices compute at once all along).
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import tyro

from experiments.benchmarks.presets import measure
from experiments.machine import cpu_model, host_cores, software_versions
from experiments.workers import Job, in_fresh_process
from swat_jax.compilation_cache import enable_caches
from swat_jax.runs.config import PRESETS, EnvConfig, NetworkSizes, Preset, TrainConfig
from swat_jax.runs.experiment import Experiment
from swat_jax.td3.iteration import IterationConfig
from swat_jax.td3.learner import TD3Config
from swat_jax.td3.sharding import placement


@dataclasses.dataclass(frozen=True)
class Options:
    """Training iterations over a device mesh against one device: environment steps per second after compilation."""

    env: str = "hopper"
    """Environment set."""
    seeds: int = 4
    """Seeds in the program."""
    devices: tuple[int, ...] = (1, 2, 4)
    """Device counts."""
    iterations: int = 5
    """Timed iterations per arm."""
    real: bool = False
    """The machine's real devices, not fake CPU ones."""
    overlap_steps: int = 20
    """Environment steps over which the physics calls' overlap is recorded on the largest device count (0: none)."""
    preset: Preset | None = None
    """Time this preset's iterations (its network and schedule, no random steps) instead of the small arm
    (SWAT width 32, 1 layer, 8 copies, chunk 25, 20 updates of batch 100 per body per iteration)."""


def arm_config(env: str, seeds: int, preset: Preset | None = None) -> TrainConfig:
    """``preset`` on ``env`` with ``seeds`` seeds, its random steps skipped so that every timed iteration
    updates; without a preset, SWAT of width 32, 1 layer; 8 copies, chunk 25, 20 updates of batch 100 per
    body per iteration."""
    if preset is not None:
        base = PRESETS[preset]
        iteration = dataclasses.replace(base.iteration, random_steps=0)
        return dataclasses.replace(base, env=env, seeds=seeds, iteration=iteration)
    return TrainConfig(
        env=env,
        seeds=seeds,
        envs=EnvConfig(copies=8),
        network=NetworkSizes(width=32, layers=1, feedforward=64),
        iteration=IterationConfig(chunk=25, updates=20, loop="per_body", random_steps=0, capacity=20_000),
        td3=TD3Config(batch_size=100),
    )


def arm(env: str, seeds: int, devices: int, iterations: int, preset: Preset | None = None) -> dict[str, Any]:
    """One arm, measured in this process: its mesh, compile seconds, steps per second and seconds per
    iteration."""
    config = arm_config(env, seeds, preset)
    chosen = jax.devices()[:devices]
    result = measure(f"{devices} devices", config, iterations, chosen)
    layout = placement(seeds, len(config.training_bodies()), config.envs.copies, chosen)
    return {
        "devices": devices,
        "mesh": layout.describe().split(";")[0],
        "compile_s": result.compile_seconds,
        "steps_per_second": result.env_steps_per_second * seeds,
        "iteration_s": result.seconds_per_iteration,
    }


def overlap(env: str, seeds: int, devices: int, steps: int, preset: Preset | None = None) -> dict[str, Any]:
    """The environment of ``arm_config``'s run over ``devices`` devices (C physics), stepped ``steps`` times
    after a warm-up with its physics calls recorded: their concurrency (module docstring) and count per
    device."""
    multi = Experiment.build(arm_config(env, seeds, preset), jax.devices()[:devices]).env
    step = jax.jit(multi.step)
    state = multi.reset(jax.random.split(jax.random.PRNGKey(0), seeds))
    action = jnp.zeros((seeds, multi.num_bodies, *multi.action_shape))
    state = jax.block_until_ready(step(state, action))[0]
    timeline: list[tuple[int, float, float]] = []
    for body in multi.envs:
        body.simulator.timeline = timeline
    for _ in range(steps):
        state = jax.block_until_ready(step(state, action))[0]
    busy = sum(end - start for _, start, end in timeline)
    union = union_length([(start, end) for _, start, end in timeline])
    return {
        "devices": devices,
        "calls": {
            str(shard): sum(s == shard for s, *_ in timeline) for shard in sorted({s for s, *_ in timeline})
        },
        "concurrency": busy / union if union else float("nan"),
    }


def union_length(intervals: list[tuple[float, float]]) -> float:
    """The length of the union of ``intervals`` (start, end)."""
    total, reached = 0.0, float("-inf")
    for start, end in sorted(intervals):
        total += max(0.0, end - max(start, reached))
        reached = max(reached, end)
    return total


def run_arm(args: Options, devices: int) -> dict[str, Any]:
    """One arm in a fresh process, with fake CPU devices unless ``--real``."""
    job = Job(
        arm,
        {
            "env": args.env,
            "seeds": args.seeds,
            "devices": devices,
            "iterations": args.iterations,
            "preset": args.preset,
        },
    )
    return in_fresh_process(job, fake_devices(args))


def fake_devices(args: Options) -> dict[str, str]:
    """The environment of a worker: this one's, with ``max(--devices)`` fake CPU devices unless ``--real``."""
    environment = dict(os.environ)
    if not args.real:
        environment["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={max(args.devices)}"
    return environment


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.sharding")

    start = time.perf_counter()
    rows = [run_arm(args, devices) for devices in args.devices]
    most = max(args.devices)
    recorded = (
        in_fresh_process(
            Job(
                overlap,
                {
                    "env": args.env,
                    "seeds": args.seeds,
                    "devices": most,
                    "steps": args.overlap_steps,
                    "preset": args.preset,
                },
            ),
            fake_devices(args),
        )
        if args.overlap_steps and most > 1
        else None
    )
    print(f"CPU: {cpu_model()}, {host_cores()} cores; {software_versions()}")
    arm_name = (
        f"the {args.preset} preset (no random steps)"
        if args.preset
        else "SWAT width 32, 1 layer, 8 copies, chunk 25, 20 updates of batch 100 per body per iteration"
    )
    print(
        f"{arm_name} on {args.env}, {args.seeds} seeds; {'real' if args.real else 'fake CPU'} devices; "
        f"{time.perf_counter() - start:.0f} s in all"
    )
    print("| devices | mesh | compile (s) | env steps/s (all seeds) | iteration (s) | vs 1 device |")
    print("|---|---|---|---|---|---|")
    base = rows[0]["steps_per_second"]
    for row in rows:
        print(
            f"| {row['devices']} | {row['mesh']} | {row['compile_s']:.1f} | {row['steps_per_second']:,.0f} | "
            f"{row['iteration_s']:.2f} | {row['steps_per_second'] / base:.2f} |"
        )
    if recorded:
        calls = ", ".join(f"{count} on device {shard}" for shard, count in recorded["calls"].items())
        print(
            f"physics calls on {recorded['devices']} devices over {args.overlap_steps} environment steps: "
            f"{calls}; concurrency {recorded['concurrency']:.2f} (1.00: taking turns; "
            f"{recorded['devices']}.00: all at once)"
        )


if __name__ == "__main__":
    main()
