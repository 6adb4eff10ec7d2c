"""Time the paper-sized SWAT, AMORPHEUS and SMP actor and critic on whole environment sets.

Forward and forward+backward (gradient of the mean action / mean Q over real limbs) per call,
for a batch of 100 observations per task, vmapped over every training body of the set
(Animal-Walkers: 5 tasks of up to 13 limbs; CWHH++: 25 tasks of up to 9). Random limb features
stand in for observations. Reports the median over repeats after one warm-up call, and SWAT and SMP
relative to AMORPHEUS from the same run.

    python -m experiments.benchmarks.network [--repeats 5] [--batch 100]
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from experiments.machine import cpu_model
from experiments.timing import median_seconds
from swat_jax.compilation_cache import enable_caches
from swat_jax.morphology import StructureBatch, get_set, load, pad_structures
from swat_jax.networks import LimbNetwork, make_actor_critic, network_config

SETS = (("animal_walkers", "Animal-Walkers", 21), ("cwhh", "CWHH++", 19))
"""(set name for get_set, display name, observation values per limb)."""
NETWORKS = ("swat", "amorpheus", "smp")
COLUMNS = ("actor forward", "actor fwd+bwd", "critic forward", "critic fwd+bwd")


def timed_functions(
    actor: LimbNetwork, critic: LimbNetwork, structures: StructureBatch
) -> dict[str, Callable[..., Any]]:
    """The four jitted, task-vmapped calls: (actor_params, critic_params, obs, actions) -> output."""
    mask = jnp.asarray(structures.limb_mask)[:, None, :]
    act = jax.vmap(actor.apply, in_axes=(None, 0, 0))
    criticize = jax.vmap(critic.apply, in_axes=(None, 0, 0, 0))

    def mean_action(actor_params, obs):
        return jnp.sum(act(actor_params, obs, structures) * mask) / (mask.sum() * obs.shape[1])

    def mean_q(critic_params, obs, actions):
        q1, q2 = criticize(critic_params, obs, actions, structures)
        return jnp.sum((q1 + q2) * mask) / (2 * mask.sum() * obs.shape[1])

    return {
        "actor forward": jax.jit(lambda ap, cp, obs, actions: act(ap, obs, structures)),
        "actor fwd+bwd": jax.jit(lambda ap, cp, obs, actions: jax.grad(mean_action)(ap, obs)),
        "critic forward": jax.jit(lambda ap, cp, obs, actions: criticize(cp, obs, actions, structures)),
        "critic fwd+bwd": jax.jit(lambda ap, cp, obs, actions: jax.grad(mean_q)(cp, obs, actions)),
    }


def benchmark_set(set_name: str, features: int, batch: int, repeats: int) -> tuple[StructureBatch, dict]:
    """Milliseconds per call, {network: {column: ms}}, for every training body of one set."""
    structures = pad_structures([load(name) for name in get_set(set_name).train])
    tasks, limbs = structures.limb_mask.shape
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.normal(size=(tasks, batch, limbs, features)), jnp.float32)
    actions = jnp.asarray(rng.uniform(-1, 1, size=(tasks, batch, limbs)), jnp.float32)
    results = {}
    for name in NETWORKS:
        actor, critic = make_actor_critic(network_config(name), features)
        args = (actor.init(jax.random.key(0)), critic.init(jax.random.key(1)), obs, actions)
        functions = timed_functions(actor, critic, structures)
        results[name] = {
            column: 1000 * median_seconds(lambda f=functions[column], args=args: f(*args), repeats)
            for column in COLUMNS
        }
    return structures, results


@dataclasses.dataclass(frozen=True)
class Options:
    """Time the paper-sized SWAT, AMORPHEUS and SMP actor and critic on whole environment sets."""

    repeats: int = 5
    """Timed calls per measurement (median)."""
    batch: int = 100
    """Observations per task."""


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.network")

    print(f"CPU: {cpu_model()}; jax {jax.__version__} on {jax.devices()[0].platform}; {args.repeats} repeats")
    print(
        f"| set | tasks x limbs | network | {' | '.join(f'{c} (ms)' for c in COLUMNS)} | ratio to AMORPHEUS |"
    )
    print("|---|---|---|" + "---|" * len(COLUMNS) + "---|")
    for set_name, display, features in SETS:
        structures, results = benchmark_set(set_name, features, args.batch, args.repeats)
        shape = "x".join(map(str, structures.limb_mask.shape))
        for name in NETWORKS:
            times = " | ".join(f"{results[name][column]:.1f}" for column in COLUMNS)
            ratios = " / ".join(f"{results[name][c] / results['amorpheus'][c]:.2f}" for c in COLUMNS)
            print(f"| {display} | {shape} | {name} | {times} | {ratios} |", flush=True)


if __name__ == "__main__":
    main()
