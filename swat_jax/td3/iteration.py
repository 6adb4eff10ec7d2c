"""One training iteration as one jitted function: collect a chunk of steps in every task, then update.

    state -> lax.scan(act + env.step + insert, chunk steps) -> the schedule's TD3 updates:
        original:  lax.scan over tasks (lax.scan(sample the task's ring + TD3 update, updates))
        all_tasks: lax.scan(sample every ring + TD3 update, updates)

Tasks are the batch axis of collection: the multi-task environment steps every body's copies and the
replay buffer holds one ring per task. The update schedule (:attr:`IterationConfig.schedule`) is the
reference code's by default: the tasks one after another, each taking its run of updates on its own
batches (its ``TD3.train``); ``all_tasks`` instead vmaps every update's losses over all tasks. Exploration
follows the paper: uniform random actions for each task's first ``random_steps`` steps, then the policy
plus Gaussian noise (std ``exploration_noise``, or one per copy: :func:`exploration_scales`), clipped to
[-1, 1]. Updates start once every task's buffer holds a full batch.

Seeds are one more batch axis: :func:`make_seeded_train_iteration` runs the iteration over a leading
seed axis of the state (:data:`SEED_AXES`), so N independent runs are one compiled program.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from collections.abc import Callable
from typing import Any, Literal

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
    counted: jax.Array
    """[] int32 environment steps counted so far, summed over tasks and copies: every step, or with lock-step
    rounds (:attr:`IterationConfig.rounds`) only the steps the original code counts."""


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
    counted=0,
)
"""vmap axes of a multi-seed :class:`TrainState`.

Each seed owns its networks, optimizer states, replay data, environments and keys (axis 0). The step
counters are equal in every seed and shared (no axis): the branches that depend on them (updates start
once the buffers hold a batch, the delayed actor step) then stay branches under vmap, instead of
becoming selects that compute both sides for every seed.
"""


Schedule = Literal["original", "all_tasks"]
SCHEDULES: tuple[str, ...] = typing.get_args(Schedule)


@dataclasses.dataclass(frozen=True)
class IterationConfig:
    """Sizes of one iteration and the order of its updates."""

    chunk: int = 100
    """Environment steps per copy collected per iteration."""
    updates: int = 100
    """TD3 updates per iteration: per body with the original schedule (chunk x copies of them give one Adam step per environment step, as the reference code), in all with all_tasks. With rounds, the counted steps set them instead."""
    rounds: bool = False
    """The original code's lock-step rounds (needs the original schedule): a round lasts until every copy has ended its first episode of the round, then all copies restart; only the steps of those first episodes count, and each body takes (counted steps summed over bodies) / bodies updates, so the copies that ended early store more transitions than are updated on. The random phase then lasts random_steps x bodies counted steps, as the original's."""
    schedule: Schedule = "original"
    """Update order after collecting. original (the reference code's): body after body, each takes its updates on batches from its own replay alone, one Adam step each, with the delayed actor step in the first of every policy_delay of them. all_tasks: each update is one Adam step on the mean loss over a batch from every body."""
    random_steps: int = 10_000
    """Per task: steps with uniform random actions before the policy acts."""
    exploration_noise: float = 0.126
    """Std of the Gaussian noise added to the policy's actions (of the first copy, with exploration_noise_max)."""
    exploration_noise_max: float | None = None
    """With it, each copy of a body explores with its own noise std, spread evenly from exploration_noise (the first copy) to this (the last), so one run explores both near its policy and far from it (FastTD3's noise drawn per environment, Seo et al. 2025); None: every copy exploration_noise."""
    capacity: int = 500_000
    """Replay rows per task (the paper: 500K)."""


def exploration_scales(config: IterationConfig, copies: int) -> jax.Array:
    """[copies] std of each copy's Gaussian exploration noise (:attr:`IterationConfig.exploration_noise_max`)."""
    if config.exploration_noise_max is None:
        return jnp.full(copies, config.exploration_noise, jnp.float32)
    return jnp.linspace(config.exploration_noise, config.exploration_noise_max, copies, dtype=jnp.float32)


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
        counted=over_seeds(lambda _: jnp.zeros((), jnp.int32))(learner_key),
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

    metrics: per-update critic and actor losses in the order the updates ran ([K * updates] with the
    original schedule, [updates] with all_tasks; :func:`make_updates`), per-task rewards of the chunk
    [chunk, K, n], ``episodes``, the sums over the episodes each task finished during this iteration
    (EpisodeStats, [K]), and ``counted_steps`` [], the steps counted since the run's start
    (:attr:`TrainState.counted`). With rounds, each task's run of updates has chunk x copies slots, the
    first (counted steps summed over tasks) / K of them updating (:func:`make_updates`).
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


Updated = tuple[LearnerState, dict[str, jax.Array]]
"""A learner state after updates, and their losses."""
UpdatePhase = Callable[..., Updated]
"""``updates(learner_state, buffer, rng[, counts]) -> (learner_state, metrics)``: the TD3 updates of one
iteration (``counts``: see :func:`make_updates`)."""


def make_updates(
    structure: StructureBatch,
    learner: Learner,
    config: IterationConfig,
    seeds: int | None = None,
    most_updates: int | None = None,
) -> UpdatePhase:
    """The TD3 updates of one iteration, ``updates(learner_state, buffer, rng, counts=None)``, in the order of
    ``config.schedule``:

    - ``original``, the reference code's ``TD3.train``: the K tasks in ``structure``'s order, each taking
      ``config.updates`` consecutive updates on batches from its own ring alone (one-task batches and
      structures [1, ...] at the padded limb count, so without ``learner.buckets``); update ``it`` of a
      task's run (from 0, for every task and iteration) takes the actor and target step when
      ``it % policy_delay == 0``, so the first of every run does. Update ``it`` of task k uses key
      ``jax.random.split(rng, (K, updates))[k, it]``.
    - ``all_tasks``: ``config.updates`` updates, each one Adam step on the mean over tasks of every
      task's loss on its own batch, the actor stepping every ``policy_delay``-th update
      (:meth:`Learner.update`); update i uses key ``jax.random.split(rng, (updates,))[i]``.

    An update's key splits into the key of its replay sample and that of its target smoothing noise; an
    update before the buffer holds ``batch_size`` rows per task leaves the learner as it is (losses 0).

    With ``counts`` [(S)] int32 (the original schedule only: lock-step rounds), each task's run has
    ``most_updates`` slots of which the first ``counts`` update (per seed); the rest leave the learner as
    it is (losses 0), and slots past every seed's count are skipped.

    Args:
        structure: [K, ...] the tasks' structure, padded to the buffer's limb count.
        seeds: the size of the leading seed axis of the learner state, buffer and ``rng``
            (:data:`SEED_AXES`); None for a state without one.
        most_updates: the slots of each task's run with ``counts``; None: ``config.updates``.

    metrics: ``critic_loss`` and ``actor_loss`` per update, in the order the updates ran: [K * updates]
    (task after task) or [updates], behind a leading [S] with a seed axis.
    """
    structure = jax.tree_util.tree_map(jnp.asarray, structure)
    num_tasks = structure.limb_mask.shape[0]
    over_seeds = _seed_map(seeds)
    batch_size = learner.config.batch_size
    task_learner = dataclasses.replace(learner, buckets=())

    def once_filled(
        buffer: ReplayBuffer, step: Callable[[LearnerState], Updated], learner_state: LearnerState
    ) -> Updated:
        """``step(learner_state)`` once the buffer holds a batch, else the state unchanged with zero losses."""
        skipped = {"critic_loss": jnp.zeros(()), "actor_loss": jnp.zeros(())}
        return jax.lax.cond(buffer.size >= batch_size, step, lambda s: (s, skipped), learner_state)

    def all_tasks_update(learner_state: LearnerState, buffer: ReplayBuffer, rng: jax.Array) -> Updated:
        """One update of one seed on a batch from every task's ring."""
        sample_key, noise_key = jax.random.split(rng)
        batch = sample(buffer, sample_key, batch_size)
        return once_filled(buffer, lambda s: learner.update(s, batch, structure, noise_key), learner_state)

    def task_update(
        learner_state: LearnerState, buffer: ReplayBuffer, rng: jax.Array, task: jax.Array, delayed: jax.Array
    ) -> Updated:
        """One update of one seed on a batch from task ``task``'s ring alone; ``delayed`` [] bool: with the
        actor and target step."""
        sample_key, noise_key = jax.random.split(rng)
        batch = _sample_task(buffer, task, sample_key, batch_size)
        task_structure = jax.tree.map(lambda leaf: leaf[task][None], structure)
        return once_filled(
            buffer, lambda s: task_learner.update(s, batch, task_structure, noise_key, delayed), learner_state
        )

    def counted_task_update(
        learner_state: LearnerState,
        buffer: ReplayBuffer,
        rng: jax.Array,
        task: jax.Array,
        delayed: jax.Array,
        active: jax.Array,
    ) -> Updated:
        """:func:`task_update` where ``active`` [] bool, else the state unchanged with zero losses. The
        update counter is shared by the seeds and counts the slot either way (the original schedule's
        delayed step is ``delayed``, not the counter's)."""
        updated, metrics = task_update(learner_state, buffer, rng, task, delayed)
        kept = jax.tree.map(lambda new, old: jnp.where(active, new, old), updated, learner_state)
        return kept.replace(updates=updated.updates), jax.tree.map(
            lambda m: jnp.where(active, m, 0.0), metrics
        )

    seeded_axes = (SEED_AXES.learner, SEED_AXES.buffer, 0)
    all_tasks_updated = over_seeds(all_tasks_update, in_axes=seeded_axes, out_axes=(SEED_AXES.learner, 0))
    task_updated = over_seeds(
        task_update, in_axes=(*seeded_axes, None, None), out_axes=(SEED_AXES.learner, 0)
    )
    counted_task_updated = over_seeds(
        counted_task_update, in_axes=(*seeded_axes, None, None, 0), out_axes=(SEED_AXES.learner, 0)
    )
    run_length = config.updates if most_updates is None else most_updates
    seed_shape = () if seeds is None else (seeds,)

    def all_tasks(
        learner_state: LearnerState, buffer: ReplayBuffer, keys: jax.Array, counts: jax.Array | None
    ) -> Updated:
        """keys [updates, (S,) 2] -> metrics [updates, (S)]."""
        if counts is not None:
            raise ValueError("update counts (lock-step rounds) need the original schedule")
        return jax.lax.scan(lambda s, key: all_tasks_updated(s, buffer, key), learner_state, keys)

    def original(
        learner_state: LearnerState, buffer: ReplayBuffer, keys: jax.Array, counts: jax.Array | None
    ) -> Updated:
        """keys [K, run_length, (S,) 2] -> metrics [K, run_length, (S)]."""

        def task_run(learner_state: LearnerState, task_and_keys: tuple[jax.Array, jax.Array]) -> Updated:
            task, task_keys = task_and_keys

            def step(learner_state: LearnerState, it_and_key: tuple[jax.Array, jax.Array]) -> Updated:
                it, key = it_and_key
                delayed = it % learner.config.policy_delay == 0
                return task_updated(learner_state, buffer, key, task, delayed)

            if counts is None:
                return jax.lax.scan(step, learner_state, (jnp.arange(run_length), task_keys))

            def counted_step(it: jax.Array, carry: Updated) -> Updated:
                """Slot ``it``: an update for the seeds whose count it is below; losses into row ``it``."""
                learner_state, losses = carry
                delayed = it % learner.config.policy_delay == 0
                learner_state, metrics = counted_task_updated(
                    learner_state, buffer, task_keys[it], task, delayed, it < counts
                )
                return learner_state, jax.tree.map(lambda all_, one: all_.at[it].set(one), losses, metrics)

            # Only as many slots as the largest count: a loop of that many steps, not a scan of run_length.
            no_losses = {name: jnp.zeros((run_length, *seed_shape)) for name in ("critic_loss", "actor_loss")}
            return jax.lax.fori_loop(0, jnp.max(counts), counted_step, (learner_state, no_losses))

        return jax.lax.scan(task_run, learner_state, (jnp.arange(num_tasks), keys))

    run, shape = {
        "original": (original, (num_tasks, run_length)),
        "all_tasks": (all_tasks, (config.updates,)),
    }[config.schedule]
    seed_dims = 0 if seeds is None else 1

    def updates(
        learner_state: LearnerState, buffer: ReplayBuffer, rng: jax.Array, counts: jax.Array | None = None
    ) -> Updated:
        keys = over_seeds(lambda key: jax.random.split(key, shape))(rng)
        # The scans run over the schedule's axes: the seed axis goes behind them, and in front again after.
        keys = jnp.moveaxis(keys, 0, len(shape)) if seed_dims else keys
        learner_state, metrics = run(learner_state, buffer, keys, counts)
        flat = jax.tree.map(lambda leaf: leaf.reshape(-1, *leaf.shape[len(shape) :]), metrics)
        return learner_state, jax.tree.map(lambda leaf: jnp.moveaxis(leaf, 0, seed_dims), flat)

    return updates


def _sample_task(buffer: ReplayBuffer, task: jax.Array, rng: jax.Array, batch_size: int) -> Transitions:
    """[1, batch_size, ...] transitions of task ``task``'s ring: the rows :func:`sample` draws from a buffer
    of that ring alone, gathered from the whole buffer (slicing the ring out first would copy it)."""
    rows = jax.random.randint(rng, (1, batch_size), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda stored: stored[task, rows], buffer.data)


def _make_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig, seeded: bool
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """The iteration of :func:`make_train_iteration` (``seeded`` False) or :func:`make_seeded_train_iteration`."""
    structure = jax.tree_util.tree_map(jnp.asarray, structure)
    mask = structure.limb_mask[:, None, :]
    noise_scales = exploration_scales(config, env.copies)[None, :, None]

    num_tasks = structure.limb_mask.shape[0]

    def random_phase(state: TrainState) -> jax.Array:
        """[] bool, shared by the seeds: every task has taken fewer than ``random_steps`` steps; with rounds
        [(S)], per seed: fewer than ``random_steps`` x tasks steps counted (the original's rule)."""
        if config.rounds:
            return state.counted < config.random_steps * num_tasks
        return state.env_steps < config.random_steps

    def act(
        actor_params: Params, observation: jax.Array, uniform_phase: jax.Array, rng: jax.Array
    ) -> jax.Array:
        """[K, n, L] exploration actions for the observations [K, n, L, F] of one seed."""
        policy_key, random_key = jax.random.split(rng)
        policy = jax.vmap(learner.actor.apply, in_axes=(None, 0, 0))(actor_params, observation, structure)
        noise = noise_scales * jax.random.normal(policy_key, policy.shape)
        uniform = jax.random.uniform(random_key, policy.shape, minval=-1.0, maxval=1.0)
        action = jnp.where(uniform_phase, uniform, jnp.clip(policy + noise, -1.0, 1.0))
        return jnp.where(mask, action, 0.0)

    def iteration(state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        seeds = state.rng.shape[:1] if seeded else ()
        over_seeds = _seed_map(seeds[0] if seeds else None)
        split = over_seeds(lambda key: tuple(jax.random.split(key)))
        inserted = over_seeds(insert, in_axes=(SEED_AXES.buffer, 0), out_axes=SEED_AXES.buffer)
        acted = over_seeds(act, in_axes=(0, 0, 0 if config.rounds else None, 0))
        updates = make_updates(
            structure,
            learner,
            config,
            seeds[0] if seeds else None,
            most_updates=config.chunk * env.copies if config.rounds else None,
        )

        def collect(state: TrainState, _) -> tuple[TrainState, jax.Array]:
            rng, act_key = split(state.rng)
            action = acted(state.learner.actor_params, state.env.observation, random_phase(state), act_key)
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
                counted=state.counted + jnp.sum(result.counted, axis=(-2, -1), dtype=jnp.int32),
            )
            return next_state, result.reward

        state = state.replace(env=state.env.replace(episodes=EpisodeStats.zeros(env.num_bodies, seeds)))
        counted_before = state.counted
        state, rewards = jax.lax.scan(collect, state, None, length=config.chunk)
        rng, update_key = split(state.rng)
        # The original's per_morph_iter: each task takes (counted steps summed over tasks) // tasks updates;
        # counting from the run's start carries the remainder to the next iteration.
        counts = state.counted // num_tasks - counted_before // num_tasks if config.rounds else None
        learner_state, metrics = updates(state.learner, state.buffer, update_key, counts)
        # Scans stack their outputs in front: the seed axis goes back first.
        metrics = {
            **metrics,
            "reward": jnp.moveaxis(rewards, 0, len(seeds)),
            "episodes": state.env.episodes,
            "counted_steps": state.counted,
        }
        return state.replace(learner=learner_state, rng=rng), metrics

    return iteration
