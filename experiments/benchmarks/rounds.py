"""The update phase of one paper-preset iteration with and without lock-step rounds.

The ``original`` schedule runs, body after body, a fixed ``updates`` per body without rounds; with rounds
(``--iteration.loop rounds``) each seed takes its own count (its counted steps / bodies), so the loop runs the
largest seed's count of slots and the other seeds skip the slots past theirs. This times one iteration's
update phase (``make_update_phase``) on a replay of random rows, for several seeds in one program: the fixed
``chunk`` updates per body (the baseline) and per-seed counts, all equal to ``chunk`` and spread below it,
and prints each against the baseline measured in the same run (per slot: per update the loop runs).

    python -m experiments.benchmarks.rounds [--set walker] [--seeds 4] [--width 32] [--layers 1]
        [--capacity 50000] [--repeats 3]
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import tyro

from experiments.machine import cpu_model
from experiments.timing import median_seconds
from swat_jax.compilation_cache import enable_caches
from swat_jax.envs.observation import features_per_limb
from swat_jax.morphology import get_set, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.td3.learner import Learner, TD3Config
from swat_jax.td3.replay import ReplayBuffer, Transitions, init_buffer
from swat_jax.td3.schedules import make_update_phase

CHUNK = 100


def random_replay(
    seeds: int, tasks: int, capacity: int, limbs: int, features: int, rng: jax.Array
) -> ReplayBuffer:
    """A full replay [S, K, capacity, ...] of random rows."""
    shape = init_buffer(tasks, capacity, limbs, features).data.action.shape
    keys = jax.random.split(rng, 4)
    data = Transitions(
        observation=jax.random.normal(keys[0], (seeds, *shape, features)),
        action=jax.random.uniform(keys[1], (seeds, *shape), minval=-1.0),
        reward=jax.random.normal(keys[2], (seeds, *shape[:2])),
        next_observation=jax.random.normal(keys[3], (seeds, *shape, features)),
        terminated=jnp.zeros((seeds, *shape[:2]), bool),
    )
    return ReplayBuffer(
        data=data, position=jnp.zeros(seeds, jnp.int32), size=jnp.full(seeds, capacity, jnp.int32)
    )


@dataclasses.dataclass(frozen=True)
class Options:
    """The update phase of one paper-preset iteration with and without lock-step rounds."""

    set: str = "walker"
    """Environment set whose bodies are updated."""
    seeds: int = 4
    """Seeds in one program."""
    width: int = 32
    """SWAT width (the paper's is 128)."""
    layers: int = 1
    """SWAT layers (the paper's is 3)."""
    capacity: int = 50_000
    """Replay rows per body."""
    repeats: int = 3
    """Timed calls per measurement."""


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.rounds")

    bodies = [load(name) for name in get_set(args.set).train]
    limbs = max(body.num_limbs for body in bodies)
    features = features_per_limb(bodies[0].family.num_limb_types)  # one vocabulary per set
    structure = pad_structures(bodies, max_limbs=limbs)
    network = network_config(
        "swat", width=args.width, heads=2, layers=args.layers, feedforward=2 * args.width
    )
    actor, critic = make_actor_critic(network, features)
    learner = Learner(actor, critic, TD3Config(batch_size=100), ())
    seeds, tasks = args.seeds, len(bodies)
    replay = random_replay(seeds, tasks, args.capacity, limbs, features, jax.random.PRNGKey(0))
    state = jax.vmap(learner.init)(jax.random.split(jax.random.PRNGKey(1), seeds))
    state = state.replace(critic_steps=state.critic_steps[0])
    rngs = jax.random.split(jax.random.PRNGKey(2), seeds)

    fixed = jax.jit(make_update_phase(structure, learner, "original", CHUNK, seeds))
    counted = jax.jit(make_update_phase(structure, learner, "original", CHUNK, seeds, counted=True))
    baseline = median_seconds(lambda: fixed(state, replay, rngs), args.repeats)
    cases = [(f"no rounds: {CHUNK} updates per body", baseline, CHUNK)]
    spread = jnp.linspace(0.7 * CHUNK, 0.85 * CHUNK, seeds).astype(jnp.int32)
    for counts in (jnp.full((seeds,), CHUNK, jnp.int32), spread):
        seconds = median_seconds(lambda counts=counts: counted(state, replay, rngs, counts), args.repeats)
        cases.append((f"rounds, counts {int(counts.min())}-{int(counts.max())}", seconds, int(counts.max())))
    print(
        f"{args.set}: {tasks} bodies, {seeds} seeds, SWAT width {args.width} x {args.layers} layers; {cpu_model()}"
    )
    print("| update phase | s per iteration | ms per slot | per slot vs no rounds |")
    print("|---|---|---|---|")
    per_slot_baseline = baseline / (tasks * CHUNK)
    for label, seconds, slots in cases:
        per_slot = seconds / (tasks * slots)
        print(f"| {label} | {seconds:.2f} | {per_slot * 1e3:.1f} | {per_slot / per_slot_baseline:.2f} |")


if __name__ == "__main__":
    main()
