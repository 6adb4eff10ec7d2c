"""One training iteration as one jitted function: collect a chunk of steps in every task, then update.

    state -> lax.scan(act + env.step + insert, chunk steps) -> lax.scan(sample + TD3 update, updates)

Tasks are the batch axis everywhere: the multi-task environment steps every body's copies, the replay
buffer holds one ring per task, and the update vmaps its losses over tasks. Exploration follows the
paper: uniform random actions for each task's first ``random_steps`` steps, then the policy plus
Gaussian noise (std ``exploration_noise``), clipped to [-1, 1]. Updates start once every task's buffer
holds a full batch.

Seeds are one more batch axis: :func:`make_seeded_train_iteration` runs the iteration over a leading
seed axis of the state (:data:`SEED_AXES`), so N independent runs are one compiled program.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax.envs.multi_task import EpisodeStats, MultiTaskEnv, MultiTaskState
from swat_jax.morphology import StructureBatch
from swat_jax.networks.policies import Params
from swat_jax.td3.learner import Learner, LearnerState
from swat_jax.td3.replay import ReplayBuffer, Transitions, init_buffer, insert, sample


@struct.dataclass
class TrainState:
    """Everything that changes during training (what a checkpoint must hold)."""

    learner: LearnerState
    buffer: ReplayBuffer
    env: MultiTaskState
    rng: jax.Array
    env_steps: jax.Array
    """[] int32 environment steps taken per task, summed over its copies (copies x chunk per iteration)."""


SEED_AXES = TrainState(
    learner=LearnerState(
        actor_params=0,
        critic_params=0,
        target_actor_params=0,
        target_critic_params=0,
        actor_optimizer=0,
        critic_optimizer=0,
        updates=None,
    ),
    buffer=ReplayBuffer(data=0, position=None, size=None),
    env=0,
    rng=0,
    env_steps=None,
)
"""vmap axes of a multi-seed :class:`TrainState`.

Each seed owns its networks, optimizer states, replay data, environments and keys (axis 0). The step
counters are equal in every seed and shared (no axis): the branches that depend on them (updates start
once the buffers hold a batch, the delayed actor step) then stay branches under vmap, instead of
becoming selects that compute both sides for every seed.
"""


@dataclasses.dataclass(frozen=True)
class IterationConfig:
    """Sizes of one iteration."""

    chunk: int = 100
    """Environment steps per copy collected per iteration."""
    updates: int = 100
    """TD3 updates per iteration (each samples ``batch_size`` transitions from every task)."""
    random_steps: int = 10_000
    """Per task: steps with uniform random actions before the policy acts."""
    exploration_noise: float = 0.126
    """Std of the Gaussian noise added to the policy's actions."""
    capacity: int = 500_000
    """Replay rows per task (the paper: 500K)."""


def init_train_state(
    env: MultiTaskEnv, learner: Learner, config: IterationConfig, rng: jax.Array
) -> TrainState:
    """Fresh networks, an empty buffer and reset environments."""
    return _init_state(env, learner, config, rng, _seed_map(None))


def init_seeded_train_state(
    env: MultiTaskEnv, learner: Learner, config: IterationConfig, rngs: jax.Array
) -> TrainState:
    """One fresh :func:`init_train_state` per key of ``rngs`` [S], stacked on a leading seed axis (the
    environments reset as runs of one :class:`MultiTaskEnv` state, see :func:`make_seeded_train_iteration`)."""
    return _init_state(env, learner, config, rngs, _seed_map(rngs.shape[0]))


def _init_state(
    env: MultiTaskEnv, learner: Learner, config: IterationConfig, rng: jax.Array, over_seeds: SeedMap
) -> TrainState:
    learner_key, env_key, rng = over_seeds(lambda key: tuple(jax.random.split(key, 3)))(rng)
    buffer = functools.partial(
        init_buffer, env.num_bodies, config.capacity, env.max_limbs, env.observation_features
    )
    return TrainState(
        learner=over_seeds(learner.init, out_axes=SEED_AXES.learner)(learner_key),
        buffer=over_seeds(lambda _: buffer(), out_axes=SEED_AXES.buffer)(learner_key),
        env=env.reset(env_key),
        rng=rng,
        env_steps=jnp.zeros((), jnp.int32),
    )


def seed_keys(first_seed: int, seeds: int) -> jax.Array:
    """[seeds] keys of seeds ``first_seed .. first_seed + seeds - 1``; key k is ``PRNGKey(first_seed + k)``,
    so seed k of a multi-seed run is the single-seed run with that seed."""
    return jax.vmap(jax.random.PRNGKey)(jnp.arange(first_seed, first_seed + seeds))


def make_train_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """The pure ``iteration(state) -> (state, metrics)`` of one run; jit it once.

    ``structure`` is the bodies' StructureBatch [K, ...] padded to ``env.max_limbs``, in ``env``'s body
    order (the task set's, :func:`swat_jax.networks.task_set`).

    metrics: per-update critic and actor losses [updates], per-task rewards of the chunk [chunk, K, n], and
    ``episodes``, the sums over the episodes each task finished during this iteration (EpisodeStats, [K]).
    """
    return _make_iteration(env, structure, learner, config, seeded=False)


def make_seeded_train_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """:func:`make_train_iteration` over a leading seed axis (:data:`SEED_AXES`); metrics get a leading
    [S] axis. Jit it once: one compilation serves every seed.

    The seed axis is not an outer ``vmap`` of the iteration: the seeds' environments step as runs of one
    :class:`MultiTaskEnv` state (their copies folded into one physics batch), and only the per-seed pieces
    (acting, replay, the TD3 update) are vmapped, inside the loops. An outer ``vmap`` batches every loop of
    the traced program once more (MJX's physics loops included), which doubled the tracing of a two-seed
    iteration. One seed runs those pieces on the seed's slice, without ``vmap``.
    """
    return _make_iteration(env, structure, learner, config, seeded=True)


SeedMap = Callable[..., Callable]
"""``over_seeds(function, in_axes=0, out_axes=0)``: ``function`` of one seed applied to every seed."""


def _seed_map(seeds: int | None) -> SeedMap:
    """How per-seed functions meet a seed axis of size ``seeds``: ``vmap`` for several, the seed's slice for
    one (``vmap`` over an axis of size 1 buys nothing and costs a pass over the traced program), and the
    function itself for a state without a seed axis (None)."""

    def over_seeds(function: Callable, in_axes: Any = 0, out_axes: Any = 0) -> Callable:
        if seeds is None:
            return function
        if seeds > 1:
            return jax.vmap(function, in_axes=in_axes, out_axes=out_axes)

        def on_the_slice(*args: Any) -> Any:
            axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
            args = tuple(
                _seed_axis(arg, axis, lambda leaf: leaf[0]) for arg, axis in zip(args, axes, strict=True)
            )
            return _seed_axis(function(*args), out_axes, lambda leaf: leaf[None])

        return on_the_slice

    return over_seeds


def _seed_axis(tree: Any, axes: Any, change: Callable[[jax.Array], jax.Array]) -> Any:
    """``tree`` with ``change`` applied to the arrays that have a seed axis in ``axes`` (a vmap axes prefix
    of ``tree``: 0 or None per subtree)."""
    axes = jax.tree.broadcast(axes, tree, is_leaf=lambda x: x is None)
    return jax.tree.map(
        lambda leaf, axis: leaf if axis is None else change(leaf), tree, axes, is_leaf=lambda x: x is None
    )


def _make_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig, seeded: bool
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """The iteration of :func:`make_train_iteration` (``seeded`` False) or :func:`make_seeded_train_iteration`."""
    structure = jax.tree_util.tree_map(jnp.asarray, structure)
    mask = structure.limb_mask[:, None, :]

    def act(actor_params: Params, observation: jax.Array, env_steps: jax.Array, rng: jax.Array) -> jax.Array:
        """[K, n, L] exploration actions for the observations [K, n, L, F] of one seed."""
        policy_key, random_key = jax.random.split(rng)
        policy = jax.vmap(learner.actor.apply, in_axes=(None, 0, 0))(actor_params, observation, structure)
        noise = config.exploration_noise * jax.random.normal(policy_key, policy.shape)
        uniform = jax.random.uniform(random_key, policy.shape, minval=-1.0, maxval=1.0)
        action = jnp.where(env_steps < config.random_steps, uniform, jnp.clip(policy + noise, -1.0, 1.0))
        return jnp.where(mask, action, 0.0)

    def update(
        learner_state: LearnerState, buffer: ReplayBuffer, rng: jax.Array
    ) -> tuple[LearnerState, dict[str, jax.Array]]:
        """One TD3 update of one seed, once its buffer holds a batch."""
        sample_key, noise_key = jax.random.split(rng)
        batch = sample(buffer, sample_key, learner.config.batch_size)
        return jax.lax.cond(
            buffer.size >= learner.config.batch_size,
            lambda s: learner.update(s, batch, structure, noise_key),
            lambda s: (s, {"critic_loss": jnp.zeros(()), "actor_loss": jnp.zeros(())}),
            learner_state,
        )

    def iteration(state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        seeds = state.rng.shape[:1] if seeded else ()
        over_seeds = _seed_map(seeds[0] if seeds else None)
        split = over_seeds(lambda key: tuple(jax.random.split(key)))
        inserted = over_seeds(insert, in_axes=(SEED_AXES.buffer, 0), out_axes=SEED_AXES.buffer)
        acted = over_seeds(act, in_axes=(0, 0, None, 0))
        updated = over_seeds(
            update, in_axes=(SEED_AXES.learner, SEED_AXES.buffer, 0), out_axes=(SEED_AXES.learner, 0)
        )

        def collect(state: TrainState, _) -> tuple[TrainState, jax.Array]:
            rng, act_key = split(state.rng)
            action = acted(state.learner.actor_params, state.env.observation, state.env_steps, act_key)
            env_state, result = env.step(state.env, action)
            transitions = Transitions(
                observation=state.env.observation,
                action=action,
                reward=result.reward,
                next_observation=result.next_observation,
                terminated=result.terminated,
            )
            next_state = state.replace(
                buffer=inserted(state.buffer, transitions),
                env=env_state,
                rng=rng,
                env_steps=state.env_steps + env.copies,
            )
            return next_state, result.reward

        def update_step(carry: tuple[LearnerState, ReplayBuffer], rng: jax.Array):
            learner_state, buffer = carry
            learner_state, metrics = updated(learner_state, buffer, rng)
            return (learner_state, buffer), metrics

        state = state.replace(env=state.env.replace(episodes=EpisodeStats.zeros(env.num_bodies, seeds)))
        state, rewards = jax.lax.scan(collect, state, None, length=config.chunk)
        rng, update_key = split(state.rng)
        update_keys = over_seeds(lambda key: jax.random.split(key, config.updates))(update_key)
        (learner_state, _), metrics = jax.lax.scan(
            update_step, (state.learner, state.buffer), jnp.moveaxis(update_keys, len(seeds), 0)
        )
        # Scans stack their outputs in front: the seed axis goes back first.
        metrics = {
            **jax.tree.map(lambda leaf: jnp.moveaxis(leaf, 0, len(seeds)), metrics),
            "reward": jnp.moveaxis(rewards, 0, len(seeds)),
            "episodes": state.env.episodes,
        }
        return state.replace(learner=learner_state, rng=rng), metrics

    return iteration
