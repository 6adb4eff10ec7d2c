"""Training iterations over a device mesh against one device: environment steps per second after compilation.

Each arm runs in a fresh process (:mod:`experiments.workers`) with ``--xla_force_host_platform_device_count``
fake CPU devices (the flag must be set before JAX starts) and trains over the first N of them, as
``train --devices N`` lays a run out (:mod:`swat_jax.td3.sharding`), timed by the preset benchmark's
``measure``. On a CPU the fake devices share the same cores, so this measures what the partitioning
costs, not a speed-up; on a multi-GPU machine ``--real`` uses the real devices.

    python -m experiments.benchmarks.sharding [--env hopper] [--seeds 4] [--devices 1 2 4] [--iterations 5]
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any

import jax
import tyro

from experiments.benchmarks.presets import measure
from experiments.machine import cpu_model, host_cores, software_versions
from experiments.workers import Job, in_fresh_process
from swat_jax.compilation_cache import enable_caches
from swat_jax.runs.config import EnvConfig, NetworkSizes, TrainConfig
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


def arm_config(env: str, seeds: int) -> TrainConfig:
    """SWAT of width 32, 1 layer; 8 copies, chunk 25, 20 updates of batch 100 per body per iteration."""
    return TrainConfig(
        env=env,
        seeds=seeds,
        envs=EnvConfig(copies=8),
        network=NetworkSizes(width=32, layers=1, feedforward=64),
        iteration=IterationConfig(chunk=25, updates=20, rounds=False, random_steps=0, capacity=20_000),
        td3=TD3Config(batch_size=100),
    )


def arm(env: str, seeds: int, devices: int, iterations: int) -> dict[str, Any]:
    """One arm, measured in this process: its mesh, compile seconds and steps per second."""
    config = arm_config(env, seeds)
    chosen = jax.devices()[:devices]
    result = measure(f"{devices} devices", config, iterations, chosen)
    layout = placement(seeds, len(config.training_bodies()), config.envs.copies, chosen)
    return {
        "devices": devices,
        "mesh": layout.describe().split(";")[0],
        "compile_s": result.compile_seconds,
        "steps_per_second": result.env_steps_per_second * seeds,
    }


def run_arm(args: Options, devices: int) -> dict[str, Any]:
    """One arm in a fresh process, with fake CPU devices unless ``--real``."""
    environment = dict(os.environ)
    if not args.real:
        environment["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={max(args.devices)}"
    job = Job(arm, {"env": args.env, "seeds": args.seeds, "devices": devices, "iterations": args.iterations})
    return in_fresh_process(job, environment)


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.sharding")

    start = time.perf_counter()
    rows = [run_arm(args, devices) for devices in args.devices]
    print(f"CPU: {cpu_model()}, {host_cores()} cores; {software_versions()}")
    print(
        f"SWAT width 32, 1 layer on {args.env}, {args.seeds} seeds, 8 copies, chunk 25, 20 updates of batch "
        f"100 per body per iteration; {'real' if args.real else 'fake CPU'} devices; "
        f"{time.perf_counter() - start:.0f} s in all"
    )
    print("| devices | mesh | compile (s) | env steps/s (all seeds) | vs 1 device |")
    print("|---|---|---|---|---|")
    base = rows[0]["steps_per_second"]
    for row in rows:
        print(
            f"| {row['devices']} | {row['mesh']} | {row['compile_s']:.1f} | {row['steps_per_second']:,.0f} | "
            f"{row['steps_per_second'] / base:.2f} |"
        )


if __name__ == "__main__":
    main()
