"""Time from nothing to the first trained iteration, per MJX implementation (``--physics jax`` / ``warp``).

For each physics and each cache state, a fresh process builds a run of the set (``TrainConfig`` of the
preset), and times what a user waits for before training starts: building the experiment (bodies,
models), ``init_state`` (networks, replay buffers, environment resets: a compiled program), tracing and
compiling the training iteration, and its first call (where Warp loads its kernels). Then it times
``--iterations`` more iterations and reports the steady seconds per iteration, and the process's peak RSS.

Cache states, in this order, each in its own process:

- cold: empty JAX compilation cache and, for Warp, an empty Warp kernel cache (a new machine);
- warm JAX and program caches: a second run of the same command (the programs the cold run saved,
  :func:`swat_jax.compilation_cache.compile_cached`, load without tracing; Warp's are not saved);
- warm JAX cache, no program cache: the same without those programs: the iteration is traced and lowered
  again, and its compiled program loaded from JAX's cache (a start before the program cache);
- other set: for Warp, a new JAX cache and the Warp kernel cache the cold run filled, on ``--other-set``
  (a run of a different set on a machine that has run Warp once: Warp's kernels serve every body).

    python -m experiments.benchmarks.compile_time [--env animal_walkers] [--other-set hopper] [--preset paper]
        [--physics jax warp] [--iterations 2]
"""

from __future__ import annotations

import dataclasses
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import tyro

from experiments.machine import cpu_model, host_cores, software_versions
from experiments.workers import Job, in_fresh_process
from swat_jax.compilation_cache import PROGRAMS, enable_caches

PHASES = ("build", "init_state", "trace", "compile", "first_call")
"""Seconds to the first trained iteration, in order. ``trace`` is JAX's tracing and lowering of the
iteration (none when the program cache holds it), ``compile`` the rest of ``Experiment.compiled_iteration``:
XLA's compile, or loading the program from either cache."""
TRACE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")


def measure(env: str, preset: str, physics: str, iterations: int) -> dict[str, float]:
    """Phase seconds, steady seconds per iteration and peak RSS (GiB) of one run, in this process."""
    import jax

    from swat_jax.runs.config import PRESETS
    from swat_jax.runs.experiment import Experiment

    # Warp cannot read the stale kinematics of the paper preset: both physics run without them.
    base = PRESETS[preset]
    envs = dataclasses.replace(base.envs, physics=physics, stale_kinematics=False)
    config = dataclasses.replace(base, env=env, envs=envs)
    seconds = {}
    start = time.perf_counter()
    experiment = Experiment.build(config)
    seconds["build"] = time.perf_counter() - start
    start = time.perf_counter()
    state = jax.block_until_ready(experiment.init_state())
    seconds["init_state"] = time.perf_counter() - start
    tracing = []

    def listen(event: str, duration: float, **_: object) -> None:
        if event in TRACE_EVENTS:
            tracing.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listen)
    start = time.perf_counter()
    iteration = experiment.compiled_iteration(state)
    seconds["trace"] = sum(tracing)
    seconds["compile"] = time.perf_counter() - start - seconds["trace"]
    start = time.perf_counter()
    state, _ = jax.block_until_ready(iteration(state))
    seconds["first_call"] = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(iterations):
        state, _ = iteration(state)
    jax.block_until_ready(state)
    seconds["iteration"] = (time.perf_counter() - start) / iterations
    seconds["env_steps_per_second"] = (
        config.steps_per_iteration(experiment.env.num_bodies) / seconds["iteration"]
    )
    seconds["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return seconds


def run_child(
    env: str, preset: str, physics: str, iterations: int, jax_cache: Path, warp_cache: Path
) -> dict:
    """:func:`measure` in a fresh process with the given cache directories."""
    environment = dict(os.environ, SWAT_JAX_CACHE_DIR=str(jax_cache), WARP_CACHE_PATH=str(warp_cache))
    environment.pop("JAX_COMPILATION_CACHE_DIR", None)
    environment.pop("SWAT_JAX_COMPILATION_CACHE", None)
    arguments = {"env": env, "preset": preset, "physics": physics, "iterations": iterations}
    return in_fresh_process(Job(measure, arguments), environment)


@dataclasses.dataclass(frozen=True)
class Options:
    """Time from nothing to the first trained iteration, per MJX implementation (--physics jax / warp)."""

    env: str = "animal_walkers"
    """Environment set."""
    other_set: str = "hopper"
    """Set of the Warp 'other set' row."""
    preset: str = "paper"
    """Training preset."""
    physics: tuple[str, ...] = ("jax", "warp")
    """Implementations."""
    iterations: int = 2
    """Timed iterations after the first."""


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.compile_time")

    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for physics in args.physics:
            jax_cache, warp_cache = Path(scratch, physics, "jax"), Path(scratch, physics, "warp")
            cases = [
                ("cold", args.env, jax_cache),
                ("warm JAX and program caches", args.env, jax_cache),
                ("warm JAX cache, no program cache", args.env, jax_cache),
            ]
            if physics == "warp":
                cases.append(
                    ("other set, kernels cached", args.other_set, Path(scratch, physics, "jax-other"))
                )
            for label, env, cache in cases:
                if "no program cache" in label:
                    shutil.rmtree(cache / PROGRAMS, ignore_errors=True)
                result = run_child(env, args.preset, physics, args.iterations, cache, warp_cache)
                rows.append((physics, label, env, result))
                total = sum(result[phase] for phase in PHASES)
                print(f"{physics}, {label}, {env}: {total:.1f} s to the first iteration {result}", flush=True)

    print(f"\nMachine: {cpu_model()}, {host_cores()} cores; {software_versions()}; preset {args.preset}")
    print(
        "\n| physics | caches | set | build (s) | init_state (s) | trace (s) | compile (s) | first call (s) "
        "| to first iteration (s) | s / iteration after | env steps/s | peak RSS (GiB) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for physics, label, env, r in rows:
        phases = " | ".join(f"{r[phase]:.1f}" for phase in PHASES)
        total = sum(r[phase] for phase in PHASES)
        print(
            f"| {physics} | {label} | {env} | {phases} | {total:.1f} | {r['iteration']:.2f} "
            f"| {r['env_steps_per_second']:.0f} | {r['peak_rss_gib']:.2f} |"
        )


if __name__ == "__main__":
    main()
