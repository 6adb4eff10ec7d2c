"""Deterministic evaluation of a policy in every task at once: the paper's evaluation return.

One program steps every body of a :class:`~swat_jax.envs.multi_task.MultiTaskEnv` (its ``copies`` are
the evaluation episodes of each body) with the actor's actions, no exploration noise, for every seed of
a run (a leading seed axis of the actor parameters), until each copy's first episode has terminated or
reached the time limit. Every seed meets the same initial states. Used by ``python -m swat_jax.eval``
and, every ``--eval-interval`` steps, by training.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax.envs.multi_task import MultiTaskEnv, MultiTaskState
from swat_jax.morphology import StructureBatch
from swat_jax.networks import LimbNetwork, Params


@struct.dataclass
class Episodes:
    """The first episode of every evaluation copy."""

    returns: jax.Array
    """[S, K, E] undiscounted returns (S seeds, K bodies, E episodes per body)."""
    lengths: jax.Array
    """[S, K, E] int32 lengths in environment steps."""
    qpos: tuple[jax.Array, ...]
    """Per body, [max_steps + 1, nq_k] joint positions of the first seed's first episode: its first
    ``length`` rows are the initial pose and the poses after each step but the last (the copy is reset in
    the step that ends its episode); zeros after them; [0, nq_k] unless recorded."""
    targets: tuple[jax.Array, ...]
    """Per body, [max_steps + 1, 2] the target of each of those poses for a 3D body (rows as ``qpos``);
    [0, 2] unless recorded, and for a planar body."""


Tracks = tuple[tuple[jax.Array, jax.Array], ...]
"""Per body, the recorded (joint positions [rows, nq_k], targets [rows, 2]) of seed 0's first episode."""
Carry = tuple[jax.Array, MultiTaskState, jax.Array, jax.Array, jax.Array, Tracks]
"""What the evaluation carries from step to step: the step t [], the environments (every seed), and the
copies' finished flags, returns and lengths [S, K, E], and the tracks."""


def make_evaluation(
    env: MultiTaskEnv, structure: StructureBatch, actor: LimbNetwork, *, record: bool = False
) -> Callable[[Params, jax.Array], Episodes]:
    """The pure ``evaluate(params [S, ...], rng) -> Episodes``; jit it once per run.

    Args:
        env: the bodies to evaluate; ``env.copies`` episodes per body.
        structure: their StructureBatch [K, ...] padded to ``env.max_limbs`` (the task set's).
        actor: the policy network (``actor.apply(params, observation [n, L, F], structure)``).
        record: also keep the joint positions (and a 3D body's targets) of seed 0's first episode of every
            body (for videos).
    """
    structure = jax.tree_util.tree_map(jnp.asarray, structure)
    max_steps = max(body.morphology.family.max_episode_steps for body in env.envs)
    act = jax.vmap(jax.vmap(actor.apply, in_axes=(None, 0, 0)), in_axes=(0, 0, None))

    def unfinished(carry: Carry) -> jax.Array:
        """[] bool: a copy's first episode goes on, and the longest time limit is not reached."""
        t, _, finished, *_ = carry
        return (t < max_steps) & ~jnp.all(finished)

    def step(params: Params, carry: Carry) -> Carry:
        """One deterministic step of every copy of every seed; returns and lengths count until a copy's first
        episode ends, and with ``record`` the tracks take seed 0's poses (and targets) after it."""
        t, states, finished, returns, lengths, tracks = carry
        actions = act(params, states.observation, structure)
        next_states, result = env.step(states, actions)  # the seeds stepped as one state
        returns = returns + jnp.where(finished, 0.0, result.reward)
        lengths = lengths + (~finished).astype(jnp.int32)
        finished = finished | result.terminated | result.truncated
        if record:
            tracks = _extended_tracks(tracks, next_states, finished, t)
        return t + 1, next_states, finished, returns, lengths, tracks

    def evaluate(params: Params, rng: jax.Array) -> Episodes:
        seeds = jax.tree_util.tree_leaves(params)[0].shape[0]
        start = env.reset(rng)
        # vmap broadcasts the start to every seed and leaves a Warp state's shared buffers unbatched.
        states = jax.vmap(lambda _: start)(jnp.arange(seeds))
        shape = (seeds, env.num_bodies, env.copies)
        carry = (
            jnp.zeros((), jnp.int32),
            states,
            jnp.zeros(shape, bool),
            jnp.zeros(shape, jnp.float32),
            jnp.zeros(shape, jnp.int32),
            _initial_tracks(env, start, max_steps + 1 if record else 0),
        )
        *_, returns, lengths, tracks = jax.lax.while_loop(unfinished, functools.partial(step, params), carry)
        return Episodes(
            returns=returns,
            lengths=lengths,
            qpos=tuple(poses for poses, _ in tracks),
            targets=tuple(targets for _, targets in tracks),
        )

    return evaluate


def _initial_tracks(env: MultiTaskEnv, start: MultiTaskState, rows: int) -> Tracks:
    """Every body's tracks [rows, width] holding copy 0's initial pose (and target) in row 0; [0, width]
    when ``rows`` is 0 (nothing recorded) and for a value the body does not have (a planar body's target)."""

    def first_rows(value: jax.Array | None, width: int) -> jax.Array:
        """A track of copy 0's ``value`` [n, width] (None: the body has none)."""
        track = jnp.zeros((rows if value is not None else 0, width))
        return track if value is None else track.at[:1].set(value[:1])

    return tuple(
        (first_rows(data.data.qpos, body.mj_model.nq), first_rows(data.target, 2))
        for body, data in zip(env.envs, start.bodies, strict=True)
    )


def _extended_tracks(tracks: Tracks, states: MultiTaskState, finished: jax.Array, t: jax.Array) -> Tracks:
    """``tracks`` with seed 0's copy 0's pose (and target) of ``states`` in row t + 1, 0 once its episode has
    ended (``finished`` [S, K, E])."""

    def extended(track: jax.Array, value: jax.Array | None, k: int) -> jax.Array:
        """Body ``k``'s ``track`` with its ``value`` [S, n, width] (None: the body has none)."""
        if value is None:
            return track
        return track.at[t + 1].set(jnp.where(finished[0, k, 0], 0.0, value[0, 0]))

    return tuple(
        (extended(poses, body.data.qpos, k), extended(targets, body.target, k))
        for k, ((poses, targets), body) in enumerate(zip(tracks, states.bodies, strict=True))
    )
