"""The TD3 updates of one iteration, in the order of a schedule (:attr:`IterationConfig.schedule`).

Every schedule is a short function of the same pieces: :class:`UpdateStep` takes one update of every seed
(sample a batch, :meth:`Learner.update`, nothing before the buffer holds a batch), and the schedule
scans it in its order.

- :func:`original`, the reference code's ``TD3.train``: the K tasks in the structure's order, each taking
  its run of updates on batches from its own ring alone, the actor stepping in update ``it`` of every run
  where ``it % policy_delay == 0`` (so in the first of each run).
- :func:`original_counted`, the same with lock-step rounds: each seed's tasks take their own number of
  updates (its counted steps over K), the slots of the run past it leaving the seed's learner alone.
- :func:`all_tasks`: each update one Adam step on the mean over tasks of every task's loss on its own
  batch, the actor stepping every ``policy_delay``-th update.

:func:`make_update_phase` picks the schedule and splits the keys: update ``it`` of task k takes key
``jax.random.split(rng, (K, updates))[k, it]`` of its seed (``split(rng, (updates,))[it]`` with
all_tasks), split into the key of its replay sample and that of its target smoothing noise.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable
from typing import Literal

import jax
import jax.numpy as jnp

from swat_jax import axes
from swat_jax.morphology import StructureBatch
from swat_jax.td3.learner import Learner, LearnerState
from swat_jax.td3.replay import ReplayBuffer, Transitions, sample, sample_n_step

Schedule = Literal["original", "all_tasks"]
SCHEDULES: tuple[str, ...] = typing.get_args(Schedule)

Updated = tuple[LearnerState, dict[str, jax.Array]]
"""A learner state after updates, their losses and whether each ran (``updated``, 1 or 0)."""
LOSSES = ("critic_loss", "actor_loss")
UPDATE_METRICS = (*LOSSES, "updated")


@dataclasses.dataclass(frozen=True)
class UpdateStep:
    """One TD3 update of every seed of a learner state [S, ...] (:func:`swat_jax.axes.seed_axes`)."""

    learner: Learner
    structure: StructureBatch
    """[K, ...] the tasks' structure, padded to the buffer's limb count."""
    seeds: int
    wait_for_batch: bool = True
    """Update only once the buffer holds a batch (False: from its first row, sampling with replacement, as
    the original's rounds do)."""
    stride: int = 1
    """Rows an insert writes per task (the copies per body): a copy's next step is this many rows on, for
    n-step returns (:func:`swat_jax.td3.replay.sample_n_step`)."""

    def delayed(self, it: jax.Array) -> jax.Array:
        """[] bool: update ``it`` of a task's run takes the actor and target step (the original's phase)."""
        return it % self.learner.config.policy_delay == 0

    def all_tasks(self, state: LearnerState, buffer: ReplayBuffer, keys: jax.Array) -> Updated:
        """An update of every seed on a batch from every task's ring; keys [S, 2] -> losses [S]."""
        filled = self._filled(buffer)

        def update(state: LearnerState, buffer: ReplayBuffer, key: jax.Array) -> Updated:
            sample_key, noise_key = jax.random.split(key)
            batch = self._sample(buffer, sample_key)
            return self._once_filled(
                filled, lambda s: self.learner.update(s, batch, self.structure, noise_key), state
            )

        return self._over_seeds(update, state, buffer)(state, buffer, keys)

    def _sample(self, buffer: ReplayBuffer, key: jax.Array) -> Transitions:
        """A batch [K, B] from every task's ring: one-step transitions, or with ``n_step`` > 1 n-step ones."""
        config = self.learner.config
        if config.n_step == 1:
            return sample(buffer, key, config.batch_size)
        return sample_n_step(buffer, key, config.batch_size, config.n_step, config.discount, self.stride)

    def task(
        self,
        state: LearnerState,
        buffer: ReplayBuffer,
        keys: jax.Array,
        task: jax.Array,
        delayed: jax.Array,
        active: jax.Array | None = None,
    ) -> Updated:
        """An update of every seed on a batch from task ``task``'s ring alone, with the actor and target step
        where ``delayed`` [] bool; keys [S, 2] -> losses [S]. With ``active`` [S] bool, only the active seeds
        update (the others keep their learner, losses 0); the critic step counter counts the slot either way."""
        single = dataclasses.replace(self.learner, buckets=())  # one-task batches at the padded limb count
        filled = self._filled(buffer)

        def update(
            state: LearnerState, buffer: ReplayBuffer, key: jax.Array, active: jax.Array | None = None
        ) -> Updated:
            sample_key, noise_key = jax.random.split(key)
            batch = _sample_task(buffer, task, sample_key, self.learner.config.batch_size)
            structure = jax.tree.map(lambda leaf: leaf[task][None], self.structure)
            updated, losses = self._once_filled(
                filled, lambda s: single.update(s, batch, structure, noise_key, delayed), state
            )
            if active is None:
                return updated, losses
            kept = jax.tree.map(lambda new, old: jnp.where(active, new, old), updated, state)
            return kept.replace(critic_steps=updated.critic_steps), jax.tree.map(
                lambda loss: jnp.where(active, loss, 0.0), losses
            )

        if active is None:
            return self._over_seeds(update, state, buffer)(state, buffer, keys)
        return self._over_seeds(update, state, buffer, 0)(state, buffer, keys, active)

    def _filled(self, buffer: ReplayBuffer) -> jax.Array:
        """[] bool, shared by the seeds: every seed's buffer [S] holds a batch (a row, without
        :attr:`wait_for_batch`). One flag for all seeds keeps the update a branch, not a select under the
        seeds' ``vmap``."""
        least = self.learner.config.batch_size if self.wait_for_batch else 1
        return jnp.min(buffer.size) >= least

    @staticmethod
    def _once_filled(
        filled: jax.Array, update: Callable[[LearnerState], Updated], state: LearnerState
    ) -> Updated:
        """``update(state)`` where ``filled`` (:meth:`_filled`), else the state unchanged with zero losses."""
        skipped = {name: jnp.zeros(()) for name in UPDATE_METRICS}

        def updated(state: LearnerState) -> Updated:
            state, losses = update(state)
            return state, {**losses, "updated": jnp.ones(())}

        return jax.lax.cond(filled, updated, lambda s: (s, skipped), state)

    def _over_seeds(
        self, update: Callable, state: LearnerState, buffer: ReplayBuffer, *more: int
    ) -> Callable:
        """``update(state, buffer, key, *more)`` of one seed over the seed axis of every argument."""
        learner_axes = axes.seed_axes(state)
        return axes.over_seeds(self.seeds)(
            update, in_axes=(learner_axes, axes.seed_axes(buffer), 0, *more), out_axes=(learner_axes, 0)
        )


def all_tasks(step: UpdateStep, state: LearnerState, buffer: ReplayBuffer, keys: jax.Array) -> Updated:
    """Updates on batches from every task; keys [updates, S, 2] -> losses [updates, S]."""
    return jax.lax.scan(lambda s, key: step.all_tasks(s, buffer, key), state, keys)


def original(step: UpdateStep, state: LearnerState, buffer: ReplayBuffer, keys: jax.Array) -> Updated:
    """Task after task, each its run of updates; keys [K, updates, S, 2] -> losses [K, updates, S]."""

    def task_run(state: LearnerState, task_and_keys: tuple[jax.Array, jax.Array]) -> Updated:
        task, run_keys = task_and_keys

        def update(state: LearnerState, it_and_key: tuple[jax.Array, jax.Array]) -> Updated:
            it, key = it_and_key
            return step.task(state, buffer, key, task, step.delayed(it))

        return jax.lax.scan(update, state, (jnp.arange(run_keys.shape[0]), run_keys))

    return jax.lax.scan(task_run, state, (jnp.arange(keys.shape[0]), keys))


def original_counted(
    step: UpdateStep, state: LearnerState, buffer: ReplayBuffer, keys: jax.Array, counts: jax.Array
) -> Updated:
    """:func:`original` where each seed's tasks take ``counts`` [S] updates each, in the first slots of their
    runs; keys [K, slots, S, 2] -> losses [K, slots, S], 0 in the slots a seed skips. Only the slots below
    the largest count run (a loop of that many steps, not a scan over every slot)."""
    slots = keys.shape[1]

    def task_run(state: LearnerState, task_and_keys: tuple[jax.Array, jax.Array]) -> Updated:
        task, run_keys = task_and_keys

        def slot(it: jax.Array, carry: Updated) -> Updated:
            state, losses = carry
            state, taken = step.task(state, buffer, run_keys[it], task, step.delayed(it), it < counts)
            return state, jax.tree.map(lambda all_, one: all_.at[it].set(one), losses, taken)

        no_losses = {name: jnp.zeros((slots, step.seeds)) for name in UPDATE_METRICS}
        return jax.lax.fori_loop(0, jnp.max(counts), slot, (state, no_losses))

    return jax.lax.scan(task_run, state, (jnp.arange(keys.shape[0]), keys))


UpdatePhase = Callable[..., Updated]
"""``update_phase(learner_state, buffer, rng, counts=None) -> (learner_state, losses)``: the TD3 updates of
one iteration (:func:`make_update_phase`)."""


def make_update_phase(
    structure: StructureBatch,
    learner: Learner,
    schedule: Schedule,
    updates: int,
    seeds: int,
    counted: bool = False,
    wait_for_batch: bool = True,
    copies: int = 1,
) -> UpdatePhase:
    """The TD3 updates of one iteration of every seed, ``update_phase(learner_state, buffer, rng [S],
    counts=None)``, in the order of ``schedule``.

    Args:
        structure: [K, ...] the tasks' structure, padded to the buffer's limb count.
        updates: with ``original``, the updates of each task's run (with ``counted``, its slots); with
            ``all_tasks``, the updates in all.
        seeds: S, the size of the seed axis of the learner state, buffer and keys.
        counted: lock-step rounds (``original`` only): ``update_phase`` takes ``counts`` [S] int32, the
            updates of each of a seed's tasks (:func:`original_counted`).
        wait_for_batch: :attr:`UpdateStep.wait_for_batch`.
        copies: the rows an insert writes per task (:attr:`UpdateStep.stride`).

    losses: ``critic_loss`` and ``actor_loss`` [S, K x updates] (task after task) or [S, updates], in the
    order the updates ran, and ``updated`` of the same shape: 1 where the update ran, 0 where it was
    skipped (a buffer without a batch yet, a seed past its count).
    """
    if counted and schedule != "original":
        raise ValueError("update counts (lock-step rounds) need the original schedule")
    if learner.config.n_step > 1 and schedule != "all_tasks":
        raise ValueError("n-step returns need the all_tasks schedule")
    if learner.config.reward_scaling and schedule != "all_tasks":
        raise ValueError(
            "reward scaling divides every task's rewards of a batch: it needs the all_tasks schedule"
        )
    step = UpdateStep(learner, jax.tree.map(jnp.asarray, structure), seeds, wait_for_batch, copies)
    shape = (structure.limb_mask.shape[0], updates) if schedule == "original" else (updates,)
    run = {"all_tasks": all_tasks, "original": original_counted if counted else original}[schedule]

    def update_phase(
        state: LearnerState, buffer: ReplayBuffer, rng: jax.Array, counts: jax.Array | None = None
    ) -> Updated:
        # The scans run over the schedule's axes: the seed axis goes behind them, and in front again after.
        keys = jnp.moveaxis(jax.vmap(lambda key: jax.random.split(key, shape))(rng), 0, len(shape))
        state, losses = run(step, state, buffer, keys, counts) if counted else run(step, state, buffer, keys)
        return state, jax.tree.map(lambda loss: loss.reshape(-1, seeds).T, losses)

    return update_phase


def _sample_task(buffer: ReplayBuffer, task: jax.Array, rng: jax.Array, batch_size: int) -> Transitions:
    """[1, batch_size, ...] transitions of task ``task``'s ring: the rows :func:`sample` draws from a buffer
    of that ring alone, gathered from the whole buffer (slicing the ring out first would copy it)."""
    rows = jax.random.randint(rng, (1, batch_size), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda stored: stored[task, rows], buffer.data)
