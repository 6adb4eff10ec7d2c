"""Variants of a body against copies of the body: environment steps per second in one program.

For each count N, one jitted, vmapped step of one body runs N copies, either all of the nominal body
(baseline) or each a different variant (``BodyEnv(body, variants=...)``: the variants' numbers are inputs
of the step). Both arms are timed in the same run, over ``--steps`` steps in a ``lax.scan`` after a
warm-up call; compile time is reported apart, and so is the time to build the N variants (draw, write and
load their MJCF files, then ``BodyEnv``'s compile and stacking). The ratio is variants' steps/s over the
nominal copies'.

    python -m experiments.benchmarks.variants [--body hopper_3] [--counts 1 64 1024] [--steps 50]
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import jax
import numpy as np
import tyro

import swat_jax
from experiments.machine import cpu_model, host_cores, software_versions
from swat_jax.envs import BodyEnv
from swat_jax.morphology.variants import Variation, write_variants


@dataclasses.dataclass(frozen=True)
class Options:
    """Environment steps per second of N variants of one body against N copies of it."""

    body: str = "hopper_3"
    """The body (a benchmark name or an MJCF path)."""
    counts: tuple[int, ...] = (1, 64, 1024)
    """Numbers of copies (and of variants) to time."""
    steps: int = 50
    """Environment steps per timed call."""
    variation: float = 0.2
    """Spread of the variants' factors."""


def timed(env: BodyEnv, count: int, steps: int, table) -> tuple[float, float]:
    """(compile seconds, environment steps per second summed over copies) of ``steps`` steps of ``count``
    copies; ``table``: the copies' variant rows, or None for the nominal body."""

    def rollout(keys, table, actions):
        start = jax.vmap(env.reset)(keys, table)
        return jax.lax.scan(lambda state, action: (jax.vmap(env.step)(state, action), None), start, actions)[
            0
        ]

    keys = jax.random.split(jax.random.PRNGKey(0), count)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, count, env.num_limbs)).astype(np.float32)
    begin = time.perf_counter()
    compiled = jax.jit(rollout).lower(keys, table, actions).compile()
    compile_seconds = time.perf_counter() - begin
    jax.block_until_ready(compiled(keys, table, actions))
    begin = time.perf_counter()
    jax.block_until_ready(compiled(keys, table, actions))
    return compile_seconds, steps * count / (time.perf_counter() - begin)


def main(options: Options) -> None:
    swat_jax.enable_caches()
    nominal = BodyEnv(options.body)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for count in options.counts:
            begin = time.perf_counter()
            variants = write_variants(
                options.body, count, Variation(options.variation), Path(folder) / str(count)
            )
            written = time.perf_counter() - begin
            env = BodyEnv(options.body, variants=variants)
            built = (written, time.perf_counter() - begin - written)
            baseline = timed(nominal, count, options.steps, None)
            drawn = timed(env, count, options.steps, env.variant_table())
            rows.append((count, built, baseline, drawn))
            print(
                f"{count}: nominal {baseline[1]:,.0f} steps/s, variants {drawn[1]:,.0f} steps/s", flush=True
            )
    print(f"\nCPU: {cpu_model()}, {host_cores()} cores; {jax.devices()[0].platform}; {software_versions()}")
    print(f"{options.body}, {options.steps} steps per call, variation {options.variation}")
    print(
        "| copies | nominal copies: steps/s (compile s) | variants: steps/s (compile s) | ratio "
        "| variants written + env built (s) |"
    )
    print("|---|---|---|---|---|")
    for count, (written, env_built), (base_compile, base), (variant_compile, variant) in rows:
        print(
            f"| {count:,} | {base:,.0f} ({base_compile:.1f}) | {variant:,.0f} ({variant_compile:.1f}) | "
            f"{variant / base:.2f} | {written:.1f} + {env_built:.1f} |"
        )


if __name__ == "__main__":
    main(tyro.cli(Options))
