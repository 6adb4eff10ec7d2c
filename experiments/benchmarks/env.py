"""Time the multi-task environment step (on MJX, or on MuJoCo C through its host callback) against MuJoCo C
alone, and measure its compile time and memory.

Measured on the machine it runs on, each printed as a markdown table for BENCHMARKS.md:

1. Throughput: environment steps per second (K bodies x n copies x steps / seconds) of the jitted
   ``MultiTaskEnv.step`` on every training body of a set, with random actions. ``--steps`` env steps
   run as one ``lax.scan`` inside one jitted call, so dispatch overhead does not dominate; the median
   of ``--repeats`` calls after a warm-up call.
2. The same bodies on MuJoCo C, single-threaded: one MjData per body, ``mj_step`` frame_skip times per
   env step plus ``mj_kinematics``, ``mj_comPos`` and ``mj_comVel`` (the observation's kinematics),
   random controls; steps per second summed over bodies, and MJX / C per row. C bodies are not reset
   when they fall (MJX copies are), so C keeps simulating contacts on the ground.
3. Compile time of the plain multi-task step (``jax.jit(env.step)``), cold (empty persistent cache)
   and warm (the cache the cold run filled), each in a fresh process; tracing (``lower``) and XLA
   compilation (``compile``) separately.
4. Memory: peak RSS of each throughput process (compilation included) and, on a GPU, the device's
   peak bytes in use.

Every MJX configuration runs in a fresh subprocess, so that its compilation, memory peak and cache
state are its own. The throughput runs use the persistent compilation cache as configured (their
compile column then shows a cache load); ``SWAT_JAX_COMPILATION_CACHE=0`` gives cold compile times.

    python -m experiments.benchmarks.env [--sets hopper walker animal_walkers cwhh] [--copies 1 16]
        [--steps 100] [--physics jax|warp|c] [--compile-sets hopper animal_walkers] [--compile-only | --no-compile]
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import platform
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import tyro

from experiments.machine import cpu_model, host_cores, host_memory_gib, software_versions
from experiments.workers import Job, WorkerError, in_fresh_process
from swat_jax.compilation_cache import cache_directory, enable_caches
from swat_jax.envs.multi_task import MultiTaskEnv, MultiTaskState
from swat_jax.morphology import get_set, load
from swat_jax.morphology.mjcf import compile_model

DEFAULT_SETS = ("hopper", "walker", "animal_walkers", "cwhh")
DEFAULT_COPIES = {"cpu": (1, 16), "gpu": (1, 16, 64, 256, 1024, 4096)}
"""Copy counts per backend when ``--copies`` is not given (each one is a separate compilation)."""
DISPLAY_NAMES = {
    "hopper": "Hopper++",
    "walker": "Walker++",
    "cheetah": "Cheetah++",
    "humanoid": "Humanoid++",
    "animal_walkers": "Animal-Walkers",
    "wh": "WH++",
    "whh": "WHH++",
    "cwh": "CWH++",
    "cwhh": "CWHH++",
}
COMPILE_TARGETS = {"animal_walkers": (60.0, 10.0)}
"""Issue targets, cold and warm seconds to trace and compile the step, on a 2-core machine."""
GIB = 2**30
PROG = "python -m experiments.benchmarks.env"
Physics = Literal["jax", "warp", "c"]


@dataclasses.dataclass(frozen=True)
class Options:
    """Time the multi-task environment step against MuJoCo C alone, and measure its compile time and memory."""

    sets: tuple[str, ...] = DEFAULT_SETS
    """Environment sets (training bodies)."""
    copies: tuple[int, ...] = ()
    """Copies per body, one compilation each (none: 1 16 on CPU, 1 16 64 256 1024 4096 on GPU)."""
    largest_only_above: int = 10
    """Sets with more bodies than this run only the largest copy count (CWHH++ compiles for minutes per count); 0 runs every count for every set."""
    steps: int = 100
    """Env steps per timed call (one lax.scan)."""
    physics: Physics = "jax"
    """The environment's physics: MJX's jax or warp implementation, or MuJoCo C through its host callback."""
    repeats: int = 3
    """Timed calls per configuration (median)."""
    min_gain: float = 1.05
    """Stop a set's copy sweep once steps/s grows by less than this factor over the previous count."""
    c_steps: int = 1000
    """Env steps per body on MuJoCo C."""
    compile_sets: tuple[str, ...] = ("hopper", "animal_walkers")
    """Sets whose step is compiled cold and warm."""
    compile_copies: int = 16
    """Copies per body for the compile runs."""
    compile_only: bool = False
    """Only the cold and warm compile times (not with --no-compile)."""
    no_compile: tyro.conf.FlagCreatePairsOff[bool] = False
    """Skip the cold and warm compile times (not with --compile-only)."""


def display_name(set_name: str) -> str:
    return DISPLAY_NAMES.get(set_name, set_name)


def train_bodies(set_name: str) -> tuple[str, ...]:
    return get_set(set_name).split("train")


# --- measurements run inside worker processes -------------------------------------------------------


def peak_memory() -> dict[str, float | None]:
    """Peak RSS of this process and the first device's peak bytes in use (None where not reported), GiB."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / GIB  # ru_maxrss is KiB on Linux
    stats = jax.devices()[0].memory_stats() or {}
    device_peak = stats.get("peak_bytes_in_use")
    return {"rss_gib": rss, "device_peak_gib": None if device_peak is None else device_peak / GIB}


def make_rollout(env: MultiTaskEnv, steps: int) -> Callable[[MultiTaskState, jax.Array], Any]:
    """``(state, key) -> (state, checksum)``: ``steps`` env steps with uniform random actions in [-1, 1].

    The checksum sums every reward and observation, so no part of the step is optimized away.
    """
    shape = (env.num_bodies, *env.action_shape)

    def one_step(carry: tuple[MultiTaskState, jax.Array], key: jax.Array) -> tuple[Any, None]:
        state, checksum = carry
        action = jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)
        state, result = env.step(state, action)
        return (state, checksum + result.reward.sum() + result.next_observation.sum()), None

    def rollout(state: MultiTaskState, key: jax.Array) -> tuple[MultiTaskState, jax.Array]:
        (state, checksum), _ = jax.lax.scan(
            one_step, (state, jnp.zeros((), jnp.float32)), jax.random.split(key, steps)
        )
        return state, checksum

    return rollout


def throughput_worker(
    set_name: str, copies: int, steps: int, repeats: int, physics: str = "jax"
) -> dict[str, Any]:
    """MJX steps per second, trace and compile seconds of the scanned step, and peak memory."""
    env = MultiTaskEnv(train_bodies(set_name), copies, physics=physics)
    key = jax.random.key(0)
    state = jax.block_until_ready(jax.jit(env.reset)(key))
    start = time.perf_counter()
    lowered = jax.jit(make_rollout(env, steps), donate_argnums=0).lower(state, key)
    traced = time.perf_counter()
    rollout = lowered.compile()
    compiled = time.perf_counter()
    state, _ = jax.block_until_ready(rollout(state, key))  # warm-up
    seconds = []
    for repeat in range(repeats):
        start_call = time.perf_counter()
        state, _ = jax.block_until_ready(rollout(state, jax.random.key(repeat + 1)))
        seconds.append(time.perf_counter() - start_call)
    return {
        "bodies": env.num_bodies,
        "max_limbs": env.max_limbs,
        "trace_s": traced - start,
        "compile_s": compiled - traced,
        "steps_per_second": env.num_bodies * copies * steps / statistics.median(seconds),
        **peak_memory(),
    }


def compile_worker(set_name: str, copies: int, physics: str = "jax") -> dict[str, Any]:
    """Seconds to build the environment, trace and compile ``jax.jit(env.step)`` (abstract arguments)."""
    start = time.perf_counter()
    env = MultiTaskEnv(train_bodies(set_name), copies, physics=physics)
    built = time.perf_counter()
    state = jax.eval_shape(env.reset, jax.random.key(0))
    action = jax.ShapeDtypeStruct((env.num_bodies, *env.action_shape), jnp.float32)
    start_trace = time.perf_counter()
    lowered = jax.jit(env.step).lower(state, action)
    traced = time.perf_counter()
    lowered.compile()
    compiled = time.perf_counter()
    return {
        "bodies": env.num_bodies,
        "build_s": built - start,
        "trace_s": traced - start_trace,
        "compile_s": compiled - traced,
        **peak_memory(),
    }


def info_worker() -> dict[str, Any]:
    """Backend, device, device count and versions (``versions``: every installed package that matters)."""
    device = jax.devices()[0]
    return {
        "platform": device.platform,
        "device": device.device_kind,
        "device_count": jax.device_count(),
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
        "versions": software_versions(),
    }


# --- the orchestrating process (never touches the JAX backend) -----------------------------------------


def throughput_job(set_name: str, copies: int, steps: int, repeats: int, physics: str = "jax") -> Job:
    """One :func:`throughput_worker` measurement, for a fresh process."""
    arguments = {
        "set_name": set_name,
        "copies": copies,
        "steps": steps,
        "repeats": repeats,
        "physics": physics,
    }
    return Job(throughput_worker, arguments)


def machine_description(info: dict[str, Any]) -> str:
    cores, memory = host_cores(), host_memory_gib()
    host = f"{cpu_model()}, {cores} cores, {memory:.0f} GiB"
    accelerator = "CPU only" if info["platform"] == "cpu" else f"{info['device']} ({info['platform']})"
    return (
        f"Machine: {host}; {accelerator}\n"
        f"Software: jax {info['jax']}, mujoco {info['mujoco']}, Python {info['python']}"
    )


def c_steps_per_second(bodies: Sequence[str], steps: int, seed: int = 0) -> float:
    """Env steps per second of every body on MuJoCo C, one after another on one thread, summed."""
    rng = np.random.default_rng(seed)
    seconds = 0.0
    for name in bodies:
        morphology = load(name)
        model = compile_model(morphology)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        controls = rng.uniform(-1.0, 1.0, size=(steps, model.nu))
        start = time.perf_counter()
        for control in controls:
            data.ctrl[:] = control
            for _ in range(morphology.frame_skip):
                mujoco.mj_step(model, data)
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            mujoco.mj_comVel(model, data)
        seconds += time.perf_counter() - start
    return len(bodies) * steps / seconds


def c_steps_per_second_on_cores(bodies: Sequence[str], steps: int, processes: int) -> float:
    """Env steps per second of every body on MuJoCo C in ``processes`` concurrent processes (one per core,
    each running every body with its own random controls), summed over the processes. The processes are
    spawned, not forked: a fork of this process, whose JAX and MuJoCo C physics threads may hold locks,
    can deadlock in the child."""
    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        rates = pool.starmap(c_steps_per_second, [(tuple(bodies), steps, seed) for seed in range(processes)])
    return sum(rates)


def progress(message: str, started: float) -> None:
    print(f"[{time.perf_counter() - started:7.1f} s] {message}", file=sys.stderr, flush=True)


def gib(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def sweep_copies(
    set_name: str,
    copies: Sequence[int],
    measure: Callable[[int], dict[str, Any]],
    min_gain: float,
    started: float,
) -> tuple[list[dict[str, Any]], str]:
    """Throughput rows for increasing copy counts, and why the sweep stopped ("" when every count ran).

    ``measure(copies)`` times one configuration (a ``throughput_worker`` result). The sweep stops once
    throughput grows by less than ``min_gain`` over the previous count, or a run runs out of memory or time.
    """
    rows: list[dict[str, Any]] = []
    for count in sorted(copies):
        progress(f"{display_name(set_name)} x {count} copies: compiling and timing MJX", started)
        try:
            result = measure(count)
        except WorkerError as error:
            if not (error.out_of_memory or error.timed_out):
                raise
            reason = "out of memory" if error.out_of_memory else "out of time"
            progress(f"{display_name(set_name)} x {count} copies: {reason}, sweep stops", started)
            return rows, f"{reason} at {count} copies"
        rows.append({"set": set_name, "copies": count, **result})
        progress(f"  {result['steps_per_second']:.0f} steps/s (compile {result['compile_s']:.1f} s)", started)
        if len(rows) > 1 and result["steps_per_second"] < min_gain * rows[-2]["steps_per_second"]:
            progress(f"{display_name(set_name)}: throughput stopped growing, sweep stops", started)
            return rows, f"throughput stopped growing at {count} copies"
    return rows, ""


def copies_for_set(set_name: str, copies: Sequence[int], largest_only_above: int) -> list[int]:
    """All copy counts, or only the largest for sets with more than ``largest_only_above`` bodies."""
    if largest_only_above and len(train_bodies(set_name)) > largest_only_above:
        return [max(copies)]
    return list(copies)


def throughput_tables(args: Options, copies: Sequence[int], started: float) -> str:
    """The throughput table (MJX, C, ratio) and the per-configuration compile and memory table."""
    speed = [
        f"| set | bodies x max limbs | copies | physics {args.physics}: steps/s | per core ({host_cores()} cores) "
        "| MuJoCo C alone steps/s (1 thread) | per core / C alone |",
        "|---|---|---|---|---|---|---|",
    ]
    memory = [
        "| set | copies | trace (s) | compile (s) | peak RSS (GiB) | device peak (GiB) |",
        "|---|---|---|---|---|---|",
    ]
    for set_name in args.sets:
        progress(f"{display_name(set_name)}: MuJoCo C, {args.c_steps} steps per body", started)
        c_speed = c_steps_per_second(train_bodies(set_name), args.c_steps)

        def measure(count: int, set_name: str = set_name) -> dict[str, Any]:
            return in_fresh_process(throughput_job(set_name, count, args.steps, args.repeats, args.physics))

        set_copies = copies_for_set(set_name, copies, args.largest_only_above)
        rows, _ = sweep_copies(set_name, set_copies, measure, args.min_gain, started)
        for row in rows:
            name, env_speed = display_name(set_name), row["steps_per_second"]
            per_core = env_speed / host_cores()
            speed.append(
                f"| {name} | {row['bodies']}x{row['max_limbs']} | {row['copies']} | {env_speed:,.0f} "
                f"| {per_core:,.0f} | {c_speed:,.0f} | {per_core / c_speed:.2f} |"
            )
            memory.append(
                f"| {name} | {row['copies']} | {row['trace_s']:.1f} | {row['compile_s']:.1f} "
                f"| {gib(row['rss_gib'])} | {gib(row['device_peak_gib'])} |"
            )
    return "\n".join(speed) + "\n\n" + "\n".join(memory)


def compile_environment(cache_dir: str) -> dict[str, str]:
    """This process's environment with the persistent cache on and pointed at ``cache_dir`` only."""
    environment = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    environment.update(SWAT_JAX_COMPILATION_CACHE="1", SWAT_JAX_CACHE_DIR=cache_dir)
    return environment


def target_text(set_name: str) -> str:
    cold, warm = COMPILE_TARGETS.get(set_name, (None, None))
    return "-" if cold is None else f"< {cold:.0f} / < {warm:.0f}"


def compile_table(args: Options, started: float) -> str:
    """Cold and warm trace and compile seconds of ``jax.jit(env.step)``, each in a fresh process."""
    lines = [
        "| set | bodies | copies | env build (s) | cold trace (s) | cold compile (s) | cold total (s) "
        "| warm trace (s) | warm compile (s) | warm total (s) | target cold / warm (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for set_name in args.compile_sets:
        job = Job(
            compile_worker, {"set_name": set_name, "copies": args.compile_copies, "physics": args.physics}
        )
        with tempfile.TemporaryDirectory(prefix="swat_jax_cache_") as cache_dir:
            environment = compile_environment(cache_dir)
            progress(f"{display_name(set_name)}: cold compile of the step (empty cache)", started)
            cold = in_fresh_process(job, environment)
            progress(f"{display_name(set_name)}: warm compile of the step (cache filled)", started)
            warm = in_fresh_process(job, environment)
        totals = [run["trace_s"] + run["compile_s"] for run in (cold, warm)]
        lines.append(
            f"| {display_name(set_name)} | {cold['bodies']} | {args.compile_copies} | {warm['build_s']:.1f} "
            f"| {cold['trace_s']:.1f} | {cold['compile_s']:.1f} | {totals[0]:.1f} "
            f"| {warm['trace_s']:.1f} | {warm['compile_s']:.1f} | {totals[1]:.1f} | {target_text(set_name)} |"
        )
    return "\n".join(lines)


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog=PROG)
    if args.compile_only and args.no_compile:
        print(f"{PROG}: error: --compile-only and --no-compile exclude each other", file=sys.stderr)
        sys.exit(2)
    started = time.perf_counter()
    info = in_fresh_process(Job(info_worker))
    copies = args.copies or DEFAULT_COPIES["cpu" if info["platform"] == "cpu" else "gpu"]
    print(machine_description(info))
    print(f"Command: python {' '.join(sys.argv)}", flush=True)
    if not args.compile_only:
        tables = throughput_tables(args, copies, started)
        cache = cache_directory() or "off"
        print(
            f"\nThroughput ({args.steps} steps per timed call, median of {args.repeats}; "
            f"persistent compilation cache: {cache}):\n\n{tables}"
        )
    if not args.no_compile:
        print(f"\nCompile time of jax.jit(env.step):\n\n{compile_table(args, started)}")
    print(f"\nTotal {time.perf_counter() - started:.0f} s", flush=True)


if __name__ == "__main__":
    main()
