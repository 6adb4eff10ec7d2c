"""Time the TD3 update on a whole environment set: all tasks vmapped in one call against one task at a time.

Throughput is sampled transitions per second of update work (tasks x batch x updates / seconds) for
(a) ``Learner.update`` on the [T, B] batch of every training body of the set at once, and (b) the same
update called once per task with a one-task slice [1, B] (one compiled function serves every task, since
all slices have the same padded shape). Each timed call runs ``--updates`` updates in a ``lax.scan``
inside one jit, so dispatch does not dominate. Random transitions (fixed seed, observations zeroed on
padded limbs) stand in for replay samples. Compile time is reported separately; the throughput is the
median over repeats after one warm-up call.

FLOPs come from XLA's cost analysis of one unscanned update (a scan's body is counted once, a lax.cond's
costlier branch whole), less the actor step's skipped share: the average update does the critic step
and 1/policy_delay of an actor step. "Padded" counts the program as it runs (every task padded to the
set's largest body); "useful" sums each body at its own limb count, the work the reference code does.
Achieved FLOP/s is compared with the matmul ceiling, a 2048 x 2048 float32 matmul timed in the same
process. ``--reference RUN_SH`` runs the original PyTorch update (``run.sh SET UPDATES``) right after, in
the same sitting, and prints both ratios (for ``--network swat``; the reference is SWAT's update, so for
the other networks only the ratio of transitions per second).

    python -m experiments.benchmarks.update [--set animal_walkers] [--network swat] [--batch 100]
        [--updates 10] [--repeats 3] [--reference ../shared/tools/reference-update/run.sh]
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from experiments.machine import cpu_model
from experiments.timing import median_seconds
from swat_jax.compilation_cache import enable_caches
from swat_jax.envs.observation import features_per_limb
from swat_jax.morphology import StructureBatch, get_set, limb_buckets, load, pad_structures
from swat_jax.networks import NetworkConfig, make_actor_critic, network_config, param_count
from swat_jax.td3.learner import Learner, LearnerState, TD3Config
from swat_jax.td3.replay import Transitions

UpdateLoop = Callable[[LearnerState, Transitions, StructureBatch, jax.Array], LearnerState]


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


def compiled_flops(program: Any) -> float:
    """Floating-point operations of one call of a lowered or compiled program, by XLA's cost analysis."""
    analysis = program.cost_analysis()
    if isinstance(analysis, list | tuple):
        analysis = analysis[0]
    return float(analysis["flops"])


def update_flops(learner: Learner, problem: UpdateProblem) -> float:
    """FLOPs of the average update of ``problem``: a critic step, and an actor step every policy_delay-th.

    XLA counts the update's lax.cond as its costlier branch (the actor step), so the actor step, counted
    on its own, is taken out again for the calls that skip it.
    """
    state, transitions, structures = problem.state, problem.transitions, problem.structures
    every_update = compiled_flops(jax.jit(learner.update).lower(state, transitions, structures, problem.rng))
    actor_step = compiled_flops(
        jax.jit(learner.actor_step).lower(
            state.actor_params, state.actor_optimizer, state.critic_params, transitions, structures
        )
    )
    return every_update - actor_step * (1 - 1 / learner.config.policy_delay)


def useful_flops(learner: Learner, problem: UpdateProblem) -> float:
    """FLOPs of the average update with every body at its own limb count (no padding), summed over bodies."""
    total, one_body = 0.0, dataclasses.replace(learner, buckets=())
    for task, limbs in enumerate(np.asarray(problem.structures.num_limbs).tolist()):
        body = UpdateProblem(
            one_body,
            problem.state,
            trimmed_transitions(problem.transitions, task, limbs),
            trimmed_structures(problem.structures, task, limbs),
            problem.rng,
        )
        total += update_flops(one_body, body)
    return total


def trimmed_transitions(transitions: Transitions, task: int, limbs: int) -> Transitions:
    """Task ``task``'s slice [1, B, ...] of a batch, without the padded limbs beyond ``limbs``."""
    return Transitions(
        observation=transitions.observation[task : task + 1, :, :limbs],
        action=transitions.action[task : task + 1, :, :limbs],
        reward=transitions.reward[task : task + 1],
        next_observation=transitions.next_observation[task : task + 1, :, :limbs],
        terminated=transitions.terminated[task : task + 1],
    )


def trimmed_structures(structures: StructureBatch, task: int, limbs: int) -> StructureBatch:
    """Task ``task``'s structure [1, limbs, ...], without the padded limbs beyond ``limbs``."""
    one = jax.tree_util.tree_map(lambda leaf: leaf[task : task + 1], structures)
    return one._replace(
        **{
            name: getattr(one, name)[:, :limbs]
            for name in (
                "limb_mask",
                "parents",
                "traversal_positions",
                "limb_types",
                "motor_mask",
            )
        },
        relations=one.relations[:, :limbs, :limbs],
    )


def matmul_ceiling(size: int = 2048, repeats: int = 5) -> float:
    """FLOP/s of a ``size`` x ``size`` float32 matmul on the default device (median of ``repeats``)."""
    a = jax.random.normal(jax.random.key(0), (size, size), jnp.float32)
    product = jax.jit(lambda x: x @ x)
    return 2 * size**3 / median_seconds(lambda: product(a), repeats)


def task_slices(tree: Transitions | StructureBatch, tasks: int) -> list:
    """The one-task slices [k:k+1] of every leaf, for k in range(tasks)."""
    return [jax.tree_util.tree_map(lambda leaf, k=k: leaf[k : k + 1], tree) for k in range(tasks)]


class UpdateProblem(NamedTuple):
    """A learner and the inputs of its update: state, a [T, batch] batch, the [T, L] structures and a key."""

    learner: Learner
    state: LearnerState
    transitions: Transitions
    structures: StructureBatch
    rng: jax.Array

    def inputs(self) -> tuple[LearnerState, Transitions, StructureBatch, jax.Array]:
        return self.state, self.transitions, self.structures, self.rng


def update_problem(set_name: str, network: NetworkConfig, batch: int, buckets: int = 1) -> UpdateProblem:
    """A fresh learner of ``network`` on every training body of ``set_name`` and random transitions [T, batch];
    ``buckets`` > 1 computes the tasks in that many limb buckets."""
    bodies = [load(name) for name in get_set(set_name).split("train")]
    features = features_per_limb(bodies[0].family.num_limb_types)  # one vocabulary per set
    structures = jax.tree_util.tree_map(jnp.asarray, pad_structures(bodies))
    transitions = random_transitions(structures, batch, features)
    actor, critic = make_actor_critic(network, obs_features=features)
    chosen = limb_buckets([body.num_limbs for body in bodies], buckets) if buckets > 1 else ()
    learner = Learner(actor, critic, TD3Config(batch_size=batch), chosen)
    return UpdateProblem(learner, learner.init(jax.random.key(0)), transitions, structures, jax.random.key(1))


def vmapped_throughput(
    set_name: str, network: NetworkConfig, batch: int, updates: int, repeats: int, buckets: int = 1
) -> dict[str, Any]:
    """Trace and compile seconds, throughput and FLOPs of the update on all tasks of ``set_name`` at once.

    Returns:
        ``tasks``, ``actor_parameters``, ``critic_parameters``, ``trace_s``, ``compile_s``,
        ``transitions_per_second`` (tasks x batch x updates / s), ``updates_per_second``,
        ``padded_gflop`` / ``useful_gflop`` (per average update of all tasks as compiled, :func:`update_flops`,
        and with no padding at all, :func:`useful_flops`) and ``fill`` (real limbs over the limb slots
        computed).
    """
    problem = update_problem(set_name, network, batch, buckets)
    compiled, trace_s, compile_s = compile_seconds(update_loop(problem.learner, updates), *problem.inputs())
    seconds = median_seconds(lambda: compiled(*problem.inputs()), repeats)
    tasks = problem.structures.limb_mask.shape[0]
    buckets_used = problem.learner.buckets or limb_buckets(
        np.asarray(problem.structures.num_limbs).tolist(), 1
    )
    computed_slots = sum(len(bucket.tasks) * bucket.limbs for bucket in buckets_used)
    return {
        "tasks": tasks,
        "actor_parameters": param_count(problem.state.actor_params),
        "critic_parameters": param_count(problem.state.critic_params),
        "trace_s": trace_s,
        "compile_s": compile_s,
        "transitions_per_second": tasks * batch * updates / seconds,
        "updates_per_second": updates / seconds,
        "padded_gflop": update_flops(problem.learner, problem) / 1e9,
        "useful_gflop": useful_flops(problem.learner, problem) / 1e9,
        "fill": float(np.asarray(problem.structures.num_limbs).sum() / computed_slots),
    }


def one_task_throughput(
    set_name: str, network: NetworkConfig, batch: int, updates: int, repeats: int
) -> float:
    """Transitions per second of the same update called once per task on one-task slices [1, batch]."""
    problem = update_problem(set_name, network, batch)
    tasks = problem.structures.limb_mask.shape[0]
    batches, structure_slices = (
        task_slices(problem.transitions, tasks),
        task_slices(problem.structures, tasks),
    )
    one_task = compile_seconds(
        update_loop(problem.learner, updates), problem.state, batches[0], structure_slices[0], problem.rng
    )[0]

    def task_by_task() -> LearnerState:
        task_state = problem.state
        for task_batch, task_structure in zip(batches, structure_slices, strict=True):
            task_state = one_task(task_state, task_batch, task_structure, problem.rng)
        return task_state

    return tasks * batch * updates / median_seconds(task_by_task, repeats)


def reference_throughput(run_sh: str, set_name: str, updates: int) -> float:
    """Sampled transitions per second of the original PyTorch update, from ``run_sh SET UPDATES``'s output."""
    output = subprocess.run(
        [run_sh, set_name, str(updates)], capture_output=True, text=True, check=True
    ).stdout
    print(output.strip())
    return float(re.search(r"-> (\d+) sampled transitions/s", output).group(1))


def reference_report(
    reference: float, network: str, result: dict[str, float], batch: int, ceiling: float
) -> str:
    """The reference's transitions/s against ``result`` (:func:`vmapped_throughput`'s); for SWAT also the
    reference's useful GFLOP/s and share of the ``ceiling`` (GFLOP/s). The reference is SWAT's update, so
    another network's FLOPs say nothing about it: only the ratio of transitions per second is given."""
    ratio = f"vmapped / reference: {result['transitions_per_second'] / reference:.2f}x"
    if network != "swat":
        return f"reference (PyTorch SWAT): {reference:,.0f} transitions/s; {ratio}"
    rate = reference / (result["tasks"] * batch) * result["useful_gflop"]
    return f"reference: {reference:,.0f} transitions/s, {rate:.0f} useful GFLOP/s ({rate / ceiling:.0%} of the ceiling); {ratio}"


@dataclasses.dataclass(frozen=True)
class Options:
    """Time the TD3 update on a whole environment set: all tasks vmapped in one call against one task at a time."""

    set: str = "animal_walkers"
    """Environment set (training bodies) to update on."""
    network: str = "swat"
    """Network variant, any name network_config accepts."""
    batch: int = 100
    """Sampled transitions per task per update."""
    updates: int = 10
    """Updates per timed call (scanned in one jit)."""
    repeats: int = 3
    """Timed calls per measurement (median)."""
    limb_buckets: int = 1
    """Compute the tasks in this many limb buckets (1: all padded)."""
    reference: str | None = None
    """The original PyTorch update's run.sh (RUN_SH): run it right after (same set, --updates per body)."""


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.update")

    print(
        f"CPU: {cpu_model()}; jax {jax.__version__} on {jax.devices()[0].platform}; "
        f"{args.updates} updates per call, {args.repeats} repeats"
    )
    network = network_config(args.network)
    result = vmapped_throughput(args.set, network, args.batch, args.updates, args.repeats, args.limb_buckets)
    one_task = one_task_throughput(args.set, network, args.batch, args.updates, args.repeats)
    ceiling = matmul_ceiling() / 1e9
    padded_rate, useful_rate = (
        result[key] * result["updates_per_second"] for key in ("padded_gflop", "useful_gflop")
    )
    print(
        "| set | network | limb buckets | tasks x batch | limb slots filled | compile (s) | vmapped transitions/s "
        "| one-task-at-a-time transitions/s | GFLOP per update padded / useful "
        "| achieved GFLOP/s padded / useful | matmul ceiling GFLOP/s | achieved / ceiling |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {args.set} | {args.network} | {args.limb_buckets} | {result['tasks']}x{args.batch} | {result['fill']:.0%} "
        f"| {result['trace_s'] + result['compile_s']:.1f} | {result['transitions_per_second']:,.0f} "
        f"| {one_task:,.0f} | {result['padded_gflop']:.1f} / {result['useful_gflop']:.1f} "
        f"| {padded_rate:.0f} / {useful_rate:.0f} | {ceiling:.0f} | {padded_rate / ceiling:.0%} |",
        flush=True,
    )
    if args.reference:
        reference = reference_throughput(args.reference, args.set, args.updates)
        print(reference_report(reference, args.network, result, args.batch, ceiling))


if __name__ == "__main__":
    main()
