"""End-to-end training throughput of the presets: environment steps and update work per second of wall clock.

For each preset (and any ``--copies`` variants of ``fast``), the script builds the run's experiment,
compiles its training iteration (reported separately), runs one warm-up iteration and then times
``--iterations`` iterations; the policy acts from the first step (``random_steps=0``) so the timed
iterations are the steady state. Reported: environment steps per second summed over bodies (with the
paper preset's lock-step rounds, the steps it counts: fewer than it takes), sampled transitions per second
of TD3 update work (updates x batch / s), and both as ratios to the first preset (``paper`` by default) measured in
the same run. ``--collection`` adds the paper preset's collection alone.

    python -m experiments.benchmarks.presets [--env hopper] [--algo swat] [--iterations 3]
        [--capacity 100000] [--fast-copies 16 64] [--fast-updates 1 64] [--fast-batches 50 100] [--physics auto|c|jax]
        [--seeds 1] [--sizes 32 1 64] [--presets paper fast] [--collection]

``--fast-updates 1`` with the fast preset's row splits its iteration into stepping (and replay) and
updates; ``--physics`` compares MJX with MuJoCo C.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import jax
import tyro

from experiments.machine import cpu_model
from swat_jax.compilation_cache import enable_caches
from swat_jax.envs.physics import Physics
from swat_jax.runs.config import PRESETS, Preset, TrainConfig
from swat_jax.runs.experiment import Experiment


@dataclasses.dataclass(frozen=True)
class Measurement:
    label: str
    config: TrainConfig
    compile_seconds: float
    env_steps_per_second: float
    """Steps counted toward the budget per second, summed over bodies, of one seed (the first)."""
    updates_per_second: float
    """Adam steps of the critic per second, summed over bodies."""
    transitions_per_second: float
    """Transitions sampled by those updates per second."""
    seconds_per_iteration: float
    stored_per_counted: float
    """Environment steps taken (and stored) per step counted: above 1 with lock-step rounds."""


def measure(
    label: str, config: TrainConfig, iterations: int, devices: Sequence[jax.Device] | None = None
) -> Measurement:
    """Compile, warm up, and time ``iterations`` training iterations of ``config`` (over ``devices``, default
    every device)."""
    experiment = Experiment.build(config, devices)
    state = experiment.init_state()
    start = time.perf_counter()
    iteration = experiment.iteration().lower(state).compile()
    compile_seconds = time.perf_counter() - start
    state, _ = iteration(state)
    jax.block_until_ready(state)
    counted_before = int(state.counted.reshape(-1)[0])
    start = time.perf_counter()
    for _ in range(iterations):
        state, _ = iteration(state)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    bodies = experiment.env.num_bodies
    counted = int(state.counted.reshape(-1)[0])
    if config.iteration.rounds:
        updates = bodies * (counted // bodies - counted_before // bodies)
    elif config.iteration.schedule == "original":
        updates = iterations * config.iteration.updates * bodies
    else:
        updates = iterations * config.iteration.updates
    batch_rows = config.td3.batch_size * (1 if config.iteration.schedule == "original" else bodies)
    stored = iterations * config.iteration.chunk * config.envs.copies * bodies
    return Measurement(
        label,
        config,
        compile_seconds,
        (counted - counted_before) / seconds,
        updates / seconds,
        updates * batch_rows / seconds,
        seconds / iterations,
        stored / max(counted - counted_before, 1),
    )


def update_ms(run: Measurement, stepping: Measurement | None) -> str:
    """Milliseconds per update of ``run`` (a fast row): its iteration less ``stepping``'s (the same iteration
    with one update) over the updates added; "-" with no such row or for other presets."""
    if stepping is None or run.config.preset != "fast" or run.config.iteration.updates <= 1:
        return "-"
    seconds = run.seconds_per_iteration - stepping.seconds_per_iteration
    return f"{1000 * seconds / (run.config.iteration.updates - 1):.1f}"


@dataclasses.dataclass(frozen=True)
class Options:
    """End-to-end training throughput of the presets: environment steps and update work per second of wall clock."""

    env: str = "hopper"
    """Environment set."""
    algo: str = "swat"
    """Network (paper-sized)."""
    presets: tuple[Preset, ...] = ("paper", "fast")
    """Presets to time, the first the baseline."""
    iterations: int = 3
    """Timed iterations per preset."""
    capacity: int = 100_000
    """Replay rows per body."""
    fast_copies: tuple[int, ...] = ()
    """Also time fast with these copy counts."""
    fast_updates: tuple[int, ...] = ()
    """Also time fast with these updates per iteration."""
    fast_batches: tuple[int, ...] = ()
    """Also time fast with these batches per body (with ``--fast-updates 1``, the milliseconds per update at each)."""
    physics: Physics = "auto"
    """Every run's physics."""
    seeds: int = 1
    """Seeds in each program."""
    sizes: tuple[int, int, int] | None = None
    """Network sizes of every preset: WIDTH LAYERS FEEDFORWARD (None: the algorithm's, paper-sized, also for fast, whose own network is smaller)."""
    collection: bool = False
    """Also time the paper preset's collection alone (no rounds, 1 update per body): with the paper row it splits an iteration into stepping the bodies and updating."""


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.presets")

    def configured(preset: str, **changes) -> TrainConfig:
        base = PRESETS[preset]
        iteration = dataclasses.replace(
            base.iteration, random_steps=0, capacity=args.capacity, **changes.pop("iteration", {})
        )
        sizes = dict(zip(("width", "layers", "feedforward"), args.sizes or (None,) * 3, strict=True))
        stale = base.envs.stale_kinematics and args.physics != "warp"
        envs = dataclasses.replace(
            base.envs, physics=args.physics, stale_kinematics=stale, **changes.pop("envs", {})
        )
        return dataclasses.replace(
            base, env=args.env, algo=args.algo, iteration=iteration, seeds=args.seeds, envs=envs,
            network=dataclasses.replace(base.network, **sizes), **changes,
        )  # fmt: skip

    runs = [(preset, configured(preset)) for preset in args.presets]
    runs += [(f"fast, {n} copies", configured("fast", envs={"copies": n})) for n in args.fast_copies]
    runs += [(f"fast, {n} updates", configured("fast", iteration={"updates": n})) for n in args.fast_updates]
    runs += [
        (f"fast, batch {n}", configured("fast", td3=dataclasses.replace(PRESETS["fast"].td3, batch_size=n)))
        for n in args.fast_batches
    ]
    if args.collection:
        paper = configured("paper")
        collection = dataclasses.replace(paper.iteration, loop="per_body", updates=1)
        runs.append(("paper, collection only", dataclasses.replace(paper, iteration=collection)))
    results = []
    for label, config in runs:
        results.append(measure(label, config, args.iterations))
        r = results[-1]
        print(
            f"{label}: compile {r.compile_seconds:.0f} s, {r.env_steps_per_second:,.1f} env steps/s, "
            f"{r.seconds_per_iteration:.1f} s per iteration, {r.stored_per_counted:.2f} steps stored per counted",
            flush=True,
        )

    paper = results[0]
    stepping = next((r for r in results if r.label == "fast, 1 updates"), None)
    device = jax.devices()[0]
    print(
        f"\n{args.env}, {args.algo}, physics {args.physics}, {args.seeds} seeds; {device.platform}: "
        f"{cpu_model() if device.platform == 'cpu' else device.device_kind}"
    )
    print(
        "\n| preset | copies | chunk | updates / iteration | batch per body | compile (s) "
        "| env steps/s | stored per counted | s per iteration | update transitions/s | env steps/s vs paper "
        "| transitions/s vs paper | ms per update |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        c = r.config
        print(
            f"| {r.label} | {c.envs.copies} | {c.iteration.chunk} | {c.iteration.updates} | {c.td3.batch_size} "
            f"| {r.compile_seconds:.0f} | {r.env_steps_per_second:,.1f} | {r.stored_per_counted:.2f} "
            f"| {r.seconds_per_iteration:.1f} | {r.transitions_per_second:,.0f} "
            f"| {r.env_steps_per_second / paper.env_steps_per_second:.2f} "
            f"| {r.transitions_per_second / paper.transitions_per_second:.2f} | {update_ms(r, stepping)} |"
        )


if __name__ == "__main__":
    main()
