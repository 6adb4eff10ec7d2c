"""One training iteration as one jitted function: collect a chunk of steps in every task, then update.

    state -> lax.scan(act + env.step + insert, chunk steps) -> lax.scan(sample + TD3 update, updates)

Tasks are the batch axis everywhere: the multi-task environment steps every body's copies, the replay
buffer holds one ring per task, and the update vmaps its losses over tasks. Exploration follows the
paper: uniform random actions for each task's first ``random_steps`` steps, then the policy plus
Gaussian noise (std ``exploration_noise``), clipped to [-1, 1]. Updates start once every task's buffer
holds a full batch.

Seeds are one more batch axis: :func:`make_seeded_train_iteration` vmaps the iteration over a leading
seed axis of the state (:data:`SEED_AXES`), so N independent runs are one compiled program.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax.envs.multi_task import EpisodeStats, MultiTaskEnv, MultiTaskState
from swat_jax.morphology import StructureBatch
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
    learner_key, env_key, rng = jax.random.split(rng, 3)
    return TrainState(
        learner=learner.init(learner_key),
        buffer=init_buffer(env.num_bodies, config.capacity, env.max_limbs, env.observation_features),
        env=env.reset(env_key),
        rng=rng,
        env_steps=jnp.zeros((), jnp.int32),
    )


def init_seeded_train_state(
    env: MultiTaskEnv, learner: Learner, config: IterationConfig, rngs: jax.Array
) -> TrainState:
    """One fresh :func:`init_train_state` per key of ``rngs`` [S], stacked on a leading seed axis (one seed
    without ``vmap``, as in :func:`make_seeded_train_iteration`)."""
    init = functools.partial(init_train_state, env, learner, config)
    if rngs.shape[0] > 1:
        return jax.vmap(init, out_axes=SEED_AXES)(rngs)
    return _seed_axis(init(rngs[0]), lambda leaf: leaf[None])


def seed_keys(first_seed: int, seeds: int) -> jax.Array:
    """[seeds] keys of seeds ``first_seed .. first_seed + seeds - 1``; key k is ``PRNGKey(first_seed + k)``,
    so seed k of a multi-seed run is the single-seed run with that seed."""
    return jax.vmap(jax.random.PRNGKey)(jnp.arange(first_seed, first_seed + seeds))


def make_seeded_train_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """:func:`make_train_iteration` over a leading seed axis (:data:`SEED_AXES`); metrics get a leading
    [S] axis. Jit it once: one compilation serves every seed.

    One seed (S = 1) runs the iteration on the seed's slice instead of through ``vmap``: batching the
    traced program over an axis of size 1 buys nothing and costs a pass over every operation of it
    (12 of the 34 s that tracing the Animal-Walkers iteration takes).
    """
    iteration = make_train_iteration(env, structure, learner, config)
    batched = jax.vmap(iteration, in_axes=(SEED_AXES,), out_axes=(SEED_AXES, 0))

    def seeded(state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        if state.rng.shape[0] > 1:
            return batched(state)
        state, metrics = iteration(_seed_axis(state, lambda leaf: leaf[0]))
        return _seed_axis(state, lambda leaf: leaf[None]), jax.tree.map(lambda leaf: leaf[None], metrics)

    return seeded


def _seed_axis(state: TrainState, change: Callable[[jax.Array], jax.Array]) -> TrainState:
    """``state`` with ``change`` applied to the arrays that have a seed axis (:data:`SEED_AXES`)."""
    axes = jax.tree.broadcast(SEED_AXES, state, is_leaf=lambda x: x is None)
    return jax.tree.map(
        lambda leaf, axis: leaf if axis is None else change(leaf), state, axes, is_leaf=lambda x: x is None
    )


def make_train_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """The pure ``iteration(state) -> (state, metrics)``; jit it once.

    ``structure`` is the bodies' StructureBatch [K, ...] padded to ``env.max_limbs``, in ``env``'s body
    order (the task set's, :func:`swat_jax.networks.task_set`).

    metrics: per-update critic and actor losses [updates], per-task rewards of the chunk [chunk, K, n], and
    ``episodes``, the sums over the episodes each task finished during this iteration (EpisodeStats, [K]).
    """
    structure = jax.tree_util.tree_map(jnp.asarray, structure)
    mask = structure.limb_mask[:, None, :]

    def act(state: TrainState, rng: jax.Array) -> jax.Array:
        """[K, n, L] exploration actions for the current observations."""
        policy_key, random_key = jax.random.split(rng)
        policy = jax.vmap(learner.actor.apply, in_axes=(None, 0, 0))(
            state.learner.actor_params, state.env.observation, structure
        )
        noise = config.exploration_noise * jax.random.normal(policy_key, policy.shape)
        uniform = jax.random.uniform(random_key, policy.shape, minval=-1.0, maxval=1.0)
        action = jnp.where(
            state.env_steps < config.random_steps, uniform, jnp.clip(policy + noise, -1.0, 1.0)
        )
        return jnp.where(mask, action, 0.0)

    def collect(state: TrainState, _) -> tuple[TrainState, jax.Array]:
        rng, act_key = jax.random.split(state.rng)
        action = act(state, act_key)
        env_state, result = env.step(state.env, action)
        transitions = Transitions(
            observation=state.env.observation,
            action=action,
            reward=result.reward,
            next_observation=result.next_observation,
            terminated=result.terminated,
        )
        next_state = state.replace(
            buffer=insert(state.buffer, transitions),
            env=env_state,
            rng=rng,
            env_steps=state.env_steps + env.copies,
        )
        return next_state, result.reward

    def update(carry: tuple[LearnerState, ReplayBuffer], rng: jax.Array):
        learner_state, buffer = carry
        sample_key, noise_key = jax.random.split(rng)
        batch = sample(buffer, sample_key, learner.config.batch_size)
        ready = buffer.size >= learner.config.batch_size
        learner_state, metrics = jax.lax.cond(
            ready,
            lambda s: learner.update(s, batch, structure, noise_key),
            lambda s: (s, {"critic_loss": jnp.zeros(()), "actor_loss": jnp.zeros(())}),
            learner_state,
        )
        return (learner_state, buffer), metrics

    def iteration(state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        state = state.replace(env=state.env.replace(episodes=EpisodeStats.zeros(env.num_bodies)))
        state, rewards = jax.lax.scan(collect, state, None, length=config.chunk)
        rng, update_key = jax.random.split(state.rng)
        (learner_state, _), metrics = jax.lax.scan(
            update, (state.learner, state.buffer), jax.random.split(update_key, config.updates)
        )
        metrics = {**metrics, "reward": rewards, "episodes": state.env.episodes}
        return state.replace(learner=learner_state, rng=rng), metrics

    return iteration
