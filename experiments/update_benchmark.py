"""Time the TD3 update on a whole environment set: all tasks vmapped in one call against one task at a time.

Throughput is sampled transitions per second of update work (tasks x batch x updates / seconds) for
(a) ``Learner.update`` on the [T, B] batch of every training body of the set at once, and (b) the same
update called once per task with a one-task slice [1, B] (one compiled function serves every task, since
all slices have the same padded shape). Each timed call runs ``--updates`` updates in a ``lax.scan``
inside one jit, so dispatch does not dominate. Random transitions (fixed seed, observations zeroed on
padded limbs) stand in for replay samples. Compile time is reported separately; the throughput is the
median over repeats after one warm-up call. The vmapped update's achieved FLOP/s (XLA's cost analysis of
the compiled program over its median time) is compared with the matmul ceiling: a 2048 x 2048 float32
matmul timed in the same process.

    python experiments/update_benchmark.py [--set animal_walkers] [--network swat] [--batch 100]
        [--updates 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from machine import cpu_model

from swat_jax.envs.observation import KINEMATIC_FEATURES
from swat_jax.morphology import Morphology, StructureBatch, get_set, load, pad_structures
from swat_jax.networks import NetworkConfig, make_actor_critic, network_config, param_count
from swat_jax.td3.learner import Learner, LearnerState, TD3Config
from swat_jax.td3.replay import Transitions

UpdateLoop = Callable[[LearnerState, Transitions, StructureBatch, jax.Array], LearnerState]


def observation_features(bodies: list[Morphology]) -> int:
    """Observation values per limb (kinematics, limb-type one-hot, joint angle and range), shared by all."""
    widths = {KINEMATIC_FEATURES + body.family.num_limb_types + 3 for body in bodies}
    if len(widths) != 1:
        raise ValueError(f"bodies of the set differ in observation width: {sorted(widths)}")
    return widths.pop()


def random_transitions(structures: StructureBatch, batch: int, features: int) -> Transitions:
    """Fixed-seed transitions [T, batch, ...]; observations and actions are zero on padded limbs."""
    tasks, limbs = structures.limb_mask.shape
    rng = np.random.default_rng(0)
    mask = structures.limb_mask[:, None, :]

    def observation() -> jax.Array:
        return jnp.asarray(rng.normal(size=(tasks, batch, limbs, features)) * mask[..., None], jnp.float32)

    return Transitions(
        observation=observation(),
        action=jnp.asarray(rng.uniform(-1, 1, size=(tasks, batch, limbs)) * mask, jnp.float32),
        reward=jnp.asarray(rng.normal(size=(tasks, batch)), jnp.float32),
        next_observation=observation(),
        terminated=jnp.asarray(rng.uniform(size=(tasks, batch)) < 0.01),
    )


def update_loop(learner: Learner, updates: int) -> UpdateLoop:
    """``updates`` consecutive ``learner.update`` calls on the same batch, scanned inside one function."""

    def run(
        state: LearnerState, batch: Transitions, structure: StructureBatch, rng: jax.Array
    ) -> LearnerState:
        def step(state: LearnerState, key: jax.Array) -> tuple[LearnerState, None]:
            return learner.update(state, batch, structure, key)[0], None

        return jax.lax.scan(step, state, jax.random.split(rng, updates))[0]

    return run


def compile_seconds(function: UpdateLoop, *args) -> tuple[Callable[..., LearnerState], float, float]:
    """The jitted, compiled ``function`` for these arguments' shapes, the trace (lower) seconds and the XLA
    compile seconds."""
    start = time.perf_counter()
    lowered = jax.jit(function).lower(*args)
    traced = time.perf_counter()
    compiled = lowered.compile()
    return compiled, traced - start, time.perf_counter() - traced


def compiled_flops(compiled: Any) -> float:
    """Floating-point operations of one call of a compiled program, by XLA's cost analysis."""
    analysis = compiled.cost_analysis()
    if isinstance(analysis, list | tuple):
        analysis = analysis[0]
    return float(analysis["flops"])


def matmul_ceiling(size: int = 2048, repeats: int = 5) -> float:
    """FLOP/s of a ``size`` x ``size`` float32 matmul on the default device (median of ``repeats``)."""
    a = jax.random.normal(jax.random.key(0), (size, size), jnp.float32)
    product = jax.jit(lambda x: x @ x)
    return 2 * size**3 / median_seconds(lambda: product(a), repeats)


def median_seconds(run: Callable[[], Any], repeats: int) -> float:
    """Median wall time of ``run()`` after one warm-up call."""
    jax.block_until_ready(run())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(run())
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def task_slices(tree: Transitions | StructureBatch, tasks: int) -> list:
    """The one-task slices [k:k+1] of every leaf, for k in range(tasks)."""
    return [jax.tree_util.tree_map(lambda leaf, k=k: leaf[k : k + 1], tree) for k in range(tasks)]


class UpdateProblem(NamedTuple):
    """The inputs of ``loop``: the learner state, a [T, batch] batch, the [T, L] structures and a key."""

    loop: UpdateLoop
    state: LearnerState
    transitions: Transitions
    structures: StructureBatch
    rng: jax.Array


def update_problem(set_name: str, network: NetworkConfig, batch: int, updates: int) -> UpdateProblem:
    """A fresh learner of ``network`` on every training body of ``set_name``, random transitions [T, batch]
    and the loop of ``updates`` updates."""
    bodies = [load(name) for name in get_set(set_name).split("train")]
    features = observation_features(bodies)
    structures = jax.tree_util.tree_map(jnp.asarray, pad_structures(bodies))
    transitions = random_transitions(structures, batch, features)
    actor, critic = make_actor_critic(network, obs_features=features)
    learner = Learner(actor, critic, TD3Config(batch_size=batch))
    loop = update_loop(learner, updates)
    return UpdateProblem(loop, learner.init(jax.random.key(0)), transitions, structures, jax.random.key(1))


def vmapped_throughput(
    set_name: str, network: NetworkConfig, batch: int, updates: int, repeats: int
) -> dict[str, Any]:
    """Trace and compile seconds and throughput of the update on all tasks of ``set_name`` at once.

    Returns:
        ``tasks``, ``actor_parameters``, ``critic_parameters``, ``trace_s``, ``compile_s``,
        ``transitions_per_second`` (tasks x batch x updates / s), ``updates_per_second``,
        ``gflop_per_update`` (XLA's count) and ``gflop_per_second`` achieved.
    """
    problem = update_problem(set_name, network, batch, updates)
    compiled, trace_s, compile_s = compile_seconds(problem.loop, *problem[1:])
    seconds = median_seconds(lambda: compiled(*problem[1:]), repeats)
    tasks = problem.structures.limb_mask.shape[0]
    return {
        "tasks": tasks,
        "actor_parameters": param_count(problem.state.actor_params),
        "critic_parameters": param_count(problem.state.critic_params),
        "trace_s": trace_s,
        "compile_s": compile_s,
        "transitions_per_second": tasks * batch * updates / seconds,
        "updates_per_second": updates / seconds,
        "gflop_per_update": compiled_flops(compiled) / updates / 1e9,
        "gflop_per_second": compiled_flops(compiled) / seconds / 1e9,
    }


def benchmark(
    set_name: str, network: NetworkConfig, batch: int, updates: int, repeats: int
) -> dict[str, float]:
    """Compile seconds and transitions per second of the vmapped and the one-task-at-a-time update."""
    vmapped = vmapped_throughput(set_name, network, batch, updates, repeats)
    problem = update_problem(set_name, network, batch, updates)
    tasks = vmapped["tasks"]
    batches, structure_slices = (
        task_slices(problem.transitions, tasks),
        task_slices(problem.structures, tasks),
    )
    one_task, trace_s, compile_s = compile_seconds(
        problem.loop, problem.state, batches[0], structure_slices[0], problem.rng
    )

    def task_by_task() -> LearnerState:
        task_state = problem.state
        for task_batch, task_structure in zip(batches, structure_slices, strict=True):
            task_state = one_task(task_state, task_batch, task_structure, problem.rng)
        return task_state

    return {
        "tasks": tasks,
        "gflop_per_update": vmapped["gflop_per_update"],
        "gflop_per_second": vmapped["gflop_per_second"],
        "vmapped compile": vmapped["trace_s"] + vmapped["compile_s"],
        "one-task compile": trace_s + compile_s,
        "vmapped": vmapped["transitions_per_second"],
        "one-task": tasks * batch * updates / median_seconds(task_by_task, repeats),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--set", default="animal_walkers", help="environment set (training bodies) to update on"
    )
    parser.add_argument("--network", default="swat", help="network variant, any name network_config accepts")
    parser.add_argument("--batch", type=int, default=100, help="sampled transitions per task per update")
    parser.add_argument("--updates", type=int, default=10, help="updates per timed call (scanned in one jit)")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per measurement (median)")
    args = parser.parse_args()

    print(
        f"CPU: {cpu_model()}; jax {jax.__version__} on {jax.devices()[0].platform}; "
        f"{args.updates} updates per call, {args.repeats} repeats"
    )
    result = benchmark(args.set, network_config(args.network), args.batch, args.updates, args.repeats)
    ceiling = matmul_ceiling() / 1e9
    print(
        "| set | network | tasks x batch | compile vmapped / one-task (s) | vmapped transitions/s "
        "| one-task-at-a-time transitions/s | vmapped / one-task | GFLOP per update (XLA) "
        "| achieved GFLOP/s | matmul ceiling GFLOP/s | achieved / ceiling |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {args.set} | {args.network} | {result['tasks']}x{args.batch} "
        f"| {result['vmapped compile']:.1f} / {result['one-task compile']:.1f} "
        f"| {result['vmapped']:,.0f} | {result['one-task']:,.0f} | {result['vmapped'] / result['one-task']:.2f} "
        f"| {result['gflop_per_update']:.2f} | {result['gflop_per_second']:.1f} | {ceiling:.0f} "
        f"| {result['gflop_per_second'] / ceiling:.1%} |",
        flush=True,
    )


if __name__ == "__main__":
    main()
