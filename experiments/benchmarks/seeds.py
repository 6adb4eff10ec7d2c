"""Many seeds in one program against the same runs one after another: wall clock, compile included.

Arm ``one program``: ``python -m swat_jax.train --seeds N`` (the whole training state has a leading
seed axis; one compilation serves every seed). Arm ``one after another``: N processes of
``python -m swat_jax.train --seeds 1 --seed k``, as a user without the seed axis would run them. Each
arm starts from its own empty compilation cache, so it pays its compiles as a user would the first
time (the sequential runs after the first hit the cache that the first one wrote). Every command is
a real training run (start-up, compile, training, checkpoints) and is timed from outside.

    python -m experiments.benchmarks.seeds [--env hopper] [--seeds 5] [--steps 30000]
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import tyro

from experiments.machine import cpu_model, host_cores, software_versions

SMALL_NETWORK = ["--network.width", "32", "--network.layers", "1", "--network.feedforward", "64"]
ITERATION = [
    "--envs.copies", "4",
    "--iteration.chunk", "50",
    "--iteration.updates", "50",
    "--iteration.random-steps", "1000",
    "--iteration.capacity", "20000",
    "--td3.batch-size", "64",
]  # fmt: skip


def timed_run(flags: list[str], cache: Path) -> float:
    """Seconds of wall clock of one ``python -m swat_jax.train`` with ``flags`` and compilation cache ``cache``."""
    environment = {**os.environ, "SWAT_JAX_CACHE_DIR": str(cache)}
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "swat_jax.train", *flags, "--no-progress"],
        env=environment,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - start


@dataclasses.dataclass(frozen=True)
class Options:
    """Many seeds in one program against the same runs one after another: wall clock, compile included."""

    env: str = "hopper"
    """Environment set."""
    algo: str = "swat"
    """Network."""
    seeds: int = 5
    """Seeds."""
    steps: int = 30_000
    """Environment steps per seed."""


def main() -> None:
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.seeds")

    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        common = ["--env", args.env, "--algo", args.algo, "--steps", str(args.steps)]
        common += SMALL_NETWORK + ITERATION + ["--log-interval", str(args.steps)]
        together = timed_run(
            [*common, "--seeds", str(args.seeds), "--run-dir", str(scratch / "together")],
            scratch / "cache-together",
        )
        one_by_one = [
            timed_run(
                [*common, "--seed", str(seed), "--run-dir", str(scratch / f"seed{seed}")],
                scratch / "cache-one-by-one",
            )
            for seed in range(args.seeds)
        ]

    print(f"CPU: {cpu_model()}, {host_cores()} cores; {software_versions()}")
    print(
        f"{args.algo} on {args.env}, {args.steps:,} steps per seed, width 32, 1 layer, 4 copies, chunk 50, "
        "50 updates of batch 64"
    )
    print("| runs | wall clock (s) | ratio to one program |")
    print("|---|---|---|")
    print(f"| {args.seeds} seeds in one program | {together:.1f} | 1.00 |")
    sequential = sum(one_by_one)
    print(
        f"| {args.seeds} runs one after another | {sequential:.1f} "
        f"({', '.join(f'{s:.0f}' for s in one_by_one)}) | {sequential / together:.2f} |"
    )
    print(f"| one run (the first of those) | {one_by_one[0]:.1f} | {one_by_one[0] / together:.2f} |")


if __name__ == "__main__":
    main()
