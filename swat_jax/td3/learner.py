"""The TD3 update over all tasks at once (Fujimoto et al. 2018; paper section 5 and Table 1).

Each task's loss is computed with ``vmap`` over the task axis (its own structure slice and batch), padded
limbs are masked out, the losses are averaged over tasks, and one gradient step updates the shared
parameters. With limb buckets, tasks of similar size are computed together at their own limb count
instead of the set's largest (the same losses, fewer FLOPs: padded limbs never change a real limb's
output). A task of one body gives exactly the original code's update of that body.

The transformer critics give one Q value per limb and every limb is regressed on its own TD target, as
the original SWAT code does (its ``TD3.py``), or with ``atoms`` a distribution of it (C51, below):

    y_l = r + discount * (1 - terminated) * min(Q1'_l(s', a'), Q2'_l(s', a')),
    loss = mean over batch and real limbs of (Q1_l - y_l)^2 + (Q2_l - y_l)^2

with a' the target policy's action plus clipped Gaussian noise (target policy smoothing), so truncated
transitions bootstrap and terminated ones do not; ``target_pessimism`` below 1 moves the min toward the two
target critics' mean (0: the mean, FastTD3's option). With ``n_step`` N > 1, r is the sum of up to N discounted
rewards of the copy's next steps and discount is discount^m for the m summed (cut at the episode's end;
``Transitions.bootstrap``). With ``reward_scaling`` each task's r is first divided by the spread of its
discounted returns (:mod:`swat_jax.td3.reward_scaling`). SMP's critic sums its limbs' values into one Q per
sample (:attr:`~swat_jax.networks.NetworkConfig.sums_limb_values`), and the same formulas then hold with
one "limb". The actor maximises the mean over limbs (SMP: the sum) of Q1 and is updated every
``policy_delay`` critic updates, or when the caller says so (``delayed``: the original schedule's phase);
target networks follow with rate ``tau`` after each actor update.

A distributional critic (``TD3Config.atoms``, FastTD3's) gives each limb's return as probabilities over
atoms z on [value_min, value_max]; its target is the lower-mean one of the two target distributions, its
atoms moved to r + discount * (1 - terminated) * z and projected onto the support, and both critics
minimise the cross-entropy to it. Q is the distribution's mean wherever a value is needed (the actor).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

from swat_jax import axes
from swat_jax.morphology.batch import LimbBucket, StructureBatch, bucket_slice, bucket_structures
from swat_jax.networks.observation_stats import NORMALISER, STATS, accumulate, with_stats
from swat_jax.networks.policies import LimbNetwork, Params, action_mask, motor_slots
from swat_jax.td3.replay import Transitions
from swat_jax.td3.reward_scaling import ReturnStats


@dataclasses.dataclass(frozen=True)
class TD3Config:
    """TD3 hyperparameters; defaults are the paper's."""

    discount: float = 0.99
    """Reward discount."""
    tau: float = 0.046
    """Target network update rate."""
    policy_noise: float = 0.2
    """Std of the target policy smoothing noise."""
    noise_clip: float = 0.5
    """The smoothing noise is clipped to [-noise_clip, noise_clip]."""
    policy_delay: int = 2
    """Actor and target updates happen every policy_delay critic updates."""
    learning_rate: float = 1e-4
    """Adam learning rate of actor and critic."""
    max_grad_norm: float = 0.1
    """Global gradient-norm clip of each network's update."""
    batch_size: int = 100
    """Transitions sampled per task per update."""
    atoms: int = 0
    """0: each critic gives a Q value per limb (TD3). N >= 2: a distribution of each limb's return over N
    atoms evenly spaced on [value_min, value_max], trained by cross-entropy on the projected target
    distribution (C51, Bellemare et al. 2017; FastTD3's critic, Seo et al. 2025)."""
    value_min: float = -100.0
    """Smallest atom of the distributional critic: returns below it count as it."""
    value_max: float = 400.0
    """Largest atom of the distributional critic: returns above it count as it."""
    target_pessimism: float = 1.0
    """How far below the two target critics' mean the TD target bootstraps, in halves of their gap:
    mean - pessimism * |Q1' - Q2'| / 2. 1: their minimum (TD3's clipped double Q); 0: their mean (FastTD3's
    option, less pessimistic). With atoms only 1 (the lower-mean distribution) or 0 (the mean of the two
    distributions)."""
    n_step: int = 1
    """Rewards summed into each TD target before it bootstraps: 1 is TD3's one-step target; N > 1 the N-step return of a copy's consecutive steps in the replay, cut at the episode's end, bootstrapping with discount^N (needs the all_tasks schedule; the fast preset's 3 was measured, docs/training.md)."""

    action_penalty: float = 0.0
    """Weight of a penalty on the actor's pre-tanh outputs u: its loss adds action_penalty x the mean over the
    body's real motors of max(|u| - action_penalty_from, 0)^2 (with action_penalty_from 0, u^2: the action
    regulariser of Andrychowicz et al. 2017, on tanh's input instead of its output, so that its gradient
    does not vanish where tanh is flat). It keeps the policy off its action bounds, where the critic's
    gradient vanishes and clipping removes half of the exploration noise (which marked the ostrich's dive
    plateau; the dive itself can outlast it, docs/training.md). 0: TD3's loss."""
    action_penalty_from: float = 0.0
    """|u| up to which the action penalty is 0: 0 penalises every output; 2 only the ones whose action is
    beyond tanh(2) = 0.96 in magnitude, near the bounds."""

    reward_scaling: bool = False
    """Divide each task's rewards by the spread of its discounted returns so far (FastTD3's per-task reward normaliser; :mod:`swat_jax.td3.reward_scaling`), so that no body's returns outweigh the others' in the all-task loss (needs the all_tasks schedule)."""

    @property
    def episode_ends(self) -> bool:
        """Whether the replay stores where each copy's episodes end (:attr:`Transitions.ended`): n-step
        returns cut their sums there."""
        return self.n_step > 1


@struct.dataclass
class LearnerState:
    """Everything the update changes."""

    actor_params: Params
    critic_params: Params
    target_actor_params: Params
    target_critic_params: Params
    actor_optimizer: optax.OptState
    critic_optimizer: optax.OptState
    critic_steps: jax.Array = axes.field(seeded=False)
    """[] int32 critic steps taken (one per update), shared by the seeds."""
    returns: ReturnStats | None = None
    """Each task's return statistics, with :attr:`TD3Config.reward_scaling` (None without)."""


@dataclasses.dataclass(frozen=True)
class Learner:
    """TD3 for one actor/critic pair; ``init`` and ``update`` are pure and jit."""

    actor: LimbNetwork
    critic: LimbNetwork
    config: TD3Config
    buckets: tuple[LimbBucket, ...] = ()
    """Task groups computed at their own limb count (:func:`~swat_jax.morphology.limb_buckets`); empty:
    every task at the padded limb count."""

    def __post_init__(self) -> None:
        atoms = getattr(self.critic.module, "atoms", 0)
        if atoms != self.config.atoms:
            raise ValueError(f"the critic has {atoms} atoms, the TD3 config {self.config.atoms}")
        if not 0.0 <= self.config.target_pessimism <= 1.0 or (
            self.config.atoms and self.config.target_pessimism not in (0.0, 1.0)
        ):
            raise ValueError(
                f"target_pessimism must be in [0, 1] (0 or 1 with a distributional critic), got "
                f"{self.config.target_pessimism}"
            )
        if self.config.atoms and not self.config.value_min < self.config.value_max:
            raise ValueError(
                f"value_min ({self.config.value_min}) must be below value_max ({self.config.value_max})"
            )

    @property
    def normalises_observations(self) -> bool:
        """Whether actor and critic standardise observations by statistics training accumulates
        (:meth:`observe`)."""
        return self.actor.module.config.observation_normalisation

    def support(self) -> jax.Array:
        """[atoms] the returns the distributional critic's atoms stand for."""
        return jnp.linspace(self.config.value_min, self.config.value_max, self.config.atoms)

    def optimizer(self) -> optax.GradientTransformation:
        return optax.chain(
            optax.clip_by_global_norm(self.config.max_grad_norm), optax.adam(self.config.learning_rate)
        )

    def init(self, rng: jax.Array, tasks: int = 1) -> LearnerState:
        """Fresh networks, targets equal to them, and with reward scaling the return statistics of
        ``tasks`` tasks."""
        actor_key, critic_key = jax.random.split(rng)
        actor_params, critic_params = self.actor.init(actor_key), self.critic.init(critic_key)
        return LearnerState(
            actor_params=actor_params,
            critic_params=critic_params,
            target_actor_params=jax.tree_util.tree_map(jnp.copy, actor_params),
            target_critic_params=jax.tree_util.tree_map(jnp.copy, critic_params),
            actor_optimizer=self.optimizer().init(actor_params),
            critic_optimizer=self.optimizer().init(critic_params),
            critic_steps=jnp.zeros((), jnp.int32),
            returns=ReturnStats.zeros(tasks) if self.config.reward_scaling else None,
        )

    def observe(self, state: LearnerState, observations: jax.Array, limb_mask: jax.Array) -> LearnerState:
        """``state`` with the observation statistics of its four networks merged with the real limbs of
        ``observations`` [..., L, F] (``limb_mask`` broadcast against them); unchanged when the networks do
        not normalise observations (:mod:`swat_jax.networks.observation_stats`)."""
        if not self.normalises_observations:
            return state
        stats = accumulate(state.actor_params[STATS][NORMALISER], observations, limb_mask)
        return state.replace(
            actor_params=with_stats(state.actor_params, stats),
            critic_params=with_stats(state.critic_params, stats),
            target_actor_params=with_stats(state.target_actor_params, stats),
            target_critic_params=with_stats(state.target_critic_params, stats),
        )

    def observe_returns(self, state: LearnerState, returns: jax.Array, seen: jax.Array) -> LearnerState:
        """``state`` with its return statistics merged with the discounted returns ``returns`` [..., K, n]
        where ``seen`` [...] (:meth:`ReturnStats.merged`); unchanged without reward scaling."""
        if state.returns is None:
            return state
        _check_tasks(state.returns, returns.shape[-2], "the returns'")
        return state.replace(returns=state.returns.merged(returns, seen))

    def update(
        self,
        state: LearnerState,
        batch: Transitions,
        structure: StructureBatch,
        rng: jax.Array,
        delayed: jax.Array | None = None,
    ) -> tuple[LearnerState, dict[str, jax.Array]]:
        """One critic step, and an actor + target step every policy_delay-th call (or when ``delayed``).

        Args:
            batch: [T, B, ...] transitions, one slice per task.
            structure: [T, ...] structure of the tasks.
            rng: key for the target policy smoothing noise.
            delayed: [] bool: take the actor and target step in this update; None: in every
                ``policy_delay``-th update (``state.critic_steps + 1`` a multiple of it).
        """
        noise = jax.random.normal(rng, batch.action.shape)
        return self.update_with_noise(state, batch, structure, noise, delayed)

    def update_with_noise(
        self,
        state: LearnerState,
        batch: Transitions,
        structure: StructureBatch,
        noise: jax.Array,
        delayed: jax.Array | None = None,
    ) -> tuple[LearnerState, dict[str, jax.Array]]:
        """:meth:`update` with the target policy smoothing noise given: ``noise`` [T, B, L] standard
        normal, scaled by ``policy_noise`` and clipped to ``noise_clip`` here (the parity tests feed the
        original code's draws)."""
        if state.returns is not None:
            _check_tasks(state.returns, batch.reward.shape[0], "the batch's")
            batch = batch.replace(reward=batch.reward / state.returns.divisor()[:, None])
        critic_loss, critic_grads = jax.value_and_grad(self._critic_loss)(
            state.critic_params, state, batch, structure, noise
        )
        critic_step, critic_optimizer = self.optimizer().update(
            critic_grads, state.critic_optimizer, state.critic_params
        )
        critic_params = optax.apply_updates(state.critic_params, critic_step)
        stepped = state.replace(critic_params=critic_params, critic_optimizer=critic_optimizer)

        if delayed is None:
            delayed = (state.critic_steps + 1) % self.config.policy_delay == 0
        next_state, actor_loss = jax.lax.cond(
            delayed,
            self.delayed_step,
            _without_delayed_step,
            stepped,
            batch,
            structure,
        )
        next_state = next_state.replace(critic_steps=state.critic_steps + 1)
        return next_state, {"critic_loss": critic_loss, "actor_loss": actor_loss}

    def delayed_step(
        self, state: LearnerState, batch: Transitions, structure: StructureBatch
    ) -> tuple[LearnerState, jax.Array]:
        """The delayed step of ``update``, taken after its critic step (``state`` holds the new critic): the
        actor step on the new critic, then both target networks follow their networks with rate ``tau``.

        Args:
            batch: [T, B, ...] transitions, one slice per task.
            structure: [T, ...] structure of the tasks.

        Returns:
            The state with new actor, actor optimizer and targets; the [] actor loss.
        """
        actor_params, actor_optimizer, actor_loss = self.actor_step(
            state.actor_params, state.actor_optimizer, state.critic_params, batch, structure
        )
        rate = jnp.float32(self.config.tau)  # 1 - rate then rounds to float32 as the parameters do
        next_state = state.replace(
            actor_params=actor_params,
            actor_optimizer=actor_optimizer,
            target_actor_params=optax.incremental_update(actor_params, state.target_actor_params, rate),
            target_critic_params=optax.incremental_update(
                state.critic_params, state.target_critic_params, rate
            ),
        )
        return next_state, actor_loss

    def actor_step(
        self,
        actor_params: Params,
        actor_optimizer: optax.OptState,
        critic_params: Params,
        batch: Transitions,
        structure: StructureBatch,
    ) -> tuple[Params, optax.OptState, jax.Array]:
        """The delayed actor step of ``update``: one Adam step on the actor loss; returns the new actor
        parameters, optimizer state and the loss."""
        loss, grads = jax.value_and_grad(self._actor_loss)(actor_params, critic_params, batch, structure)
        steps, actor_optimizer = self.optimizer().update(grads, actor_optimizer, actor_params)
        return optax.apply_updates(actor_params, steps), actor_optimizer, loss

    def _critic_loss(
        self,
        critic_params: Params,
        state: LearnerState,
        batch: Transitions,
        structure: StructureBatch,
        noise: jax.Array,
    ) -> jax.Array:
        per_task = jax.vmap(
            lambda batch, structure, noise: self._task_critic_loss(
                critic_params, state.target_actor_params, state.target_critic_params, batch, structure, noise
            )
        )
        return self._task_mean(per_task, batch, structure, noise)

    def _task_critic_loss(
        self,
        critic_params: Params,
        target_actor_params: Params,
        target_critic_params: Params,
        batch: Transitions,
        structure: StructureBatch,
        noise: jax.Array,
    ) -> jax.Array:
        """Mean squared TD error of one task over its batch and real limbs (SMP: over its batch), or with
        atoms its cross-entropy (:meth:`_distributional_errors`); ``noise`` [B, L] ([B, L, M] in 3D) standard
        normal."""
        mask = structure.limb_mask
        noise = jnp.clip(self.config.policy_noise * noise, -self.config.noise_clip, self.config.noise_clip)
        next_action = self.actor.apply(target_actor_params, batch.next_observation, structure)
        next_action = jnp.where(action_mask(structure), jnp.clip(next_action + noise, -1.0, 1.0), 0.0)
        discount = self.config.discount if batch.bootstrap is None else batch.bootstrap[:, None]
        continues = discount * (1.0 - batch.terminated[:, None])
        if self.config.atoms:
            errors = self._distributional_errors(
                critic_params, target_critic_params, batch, next_action, structure, continues
            )
            return _masked_mean(errors, mask)
        target_q1, target_q2 = self._q_values(
            target_critic_params, batch.next_observation, next_action, structure
        )
        next_value = pessimistic_value(target_q1, target_q2, self.config.target_pessimism)
        target = jax.lax.stop_gradient(batch.reward[:, None] + continues * next_value)
        q1, q2 = self._q_values(critic_params, batch.observation, batch.action, structure)
        squared = (q1 - target) ** 2 + (q2 - target) ** 2
        return _masked_mean(squared, self._value_mask(mask))

    def _distributional_errors(
        self,
        critic_params: Params,
        target_critic_params: Params,
        batch: Transitions,
        next_action: jax.Array,
        structure: StructureBatch,
        continues: jax.Array,
    ) -> jax.Array:
        """[B, L] cross-entropy of both critics' distributions against the target: of the two target
        critics, the distribution whose mean is lower (the clipped double Q of TD3; at pessimism 0, the mean
        of the two distributions), its atoms moved to r + continues * z and projected back onto the support
        (:func:`project`); ``continues`` [B, 1]."""
        support = self.support()
        next1, next2 = (
            jax.nn.softmax(logits)
            for logits in self.critic.apply(
                target_critic_params, batch.next_observation, next_action, structure
            )
        )
        if self.config.target_pessimism == 1.0:
            lower = (next1 @ support < next2 @ support)[..., None]
            next_distribution = jnp.where(lower, next1, next2)
        else:
            next_distribution = (next1 + next2) / 2.0
        moved = batch.reward[:, None, None] + continues[..., None] * support
        target = jax.lax.stop_gradient(project(next_distribution, moved, support))
        logits1, logits2 = self.critic.apply(critic_params, batch.observation, batch.action, structure)
        return -jnp.sum(target * (jax.nn.log_softmax(logits1) + jax.nn.log_softmax(logits2)), axis=-1)

    def _actor_loss(
        self, actor_params: Params, critic_params: Params, batch: Transitions, structure: StructureBatch
    ) -> jax.Array:
        def task_loss(batch: Transitions, structure: StructureBatch) -> jax.Array:
            if not self.config.action_penalty:
                action = self.actor.apply(actor_params, batch.observation, structure)
                q1, _ = self._q_values(critic_params, batch.observation, action, structure)
                return -_masked_mean(q1, self._value_mask(structure.limb_mask))
            outputs = self.actor.apply(actor_params, batch.observation, structure, squash=False)
            q1, _ = self._q_values(critic_params, batch.observation, jnp.tanh(outputs), structure)
            loss = -_masked_mean(q1, self._value_mask(structure.limb_mask))
            excess = jnp.maximum(jnp.abs(outputs) - self.config.action_penalty_from, 0.0)
            squares = jnp.square(excess).reshape(outputs.shape[0], -1)
            return loss + self.config.action_penalty * _masked_mean(
                squares, motor_slots(structure).reshape(-1)
            )

        return self._task_mean(jax.vmap(task_loss), batch, structure)

    def body_values(
        self, critic_params: Params, observation: jax.Array, action: jax.Array, structure: StructureBatch
    ) -> tuple[jax.Array, jax.Array]:
        """The twin critics' estimates (Q1, Q2) [B] of a body's return from ``observation`` [B, L, F] after
        ``action`` [B, L(, M)]: each critic's mean over the body's real limbs (every limb is regressed on the
        body's TD target), in the units the critic learns (scaled rewards, with reward scaling)."""
        mask = self._value_mask(structure.limb_mask)
        q1, q2 = self._q_values(critic_params, observation, action, structure)
        count = jnp.sum(mask)
        return (
            jnp.sum(jnp.where(mask, q1, 0.0), axis=-1) / count,
            jnp.sum(jnp.where(mask, q2, 0.0), axis=-1) / count,
        )

    def _q_values(
        self, critic_params: Params, observation: jax.Array, action: jax.Array, structure: StructureBatch
    ) -> tuple[jax.Array, jax.Array]:
        """(Q1, Q2), each [B, L] per limb (a distributional critic's means), or [B, 1] when the critic sums
        its limbs' values (SMP)."""
        q1, q2 = self.critic.apply(critic_params, observation, action, structure)
        if self.config.atoms:
            return jax.nn.softmax(q1) @ self.support(), jax.nn.softmax(q2) @ self.support()
        if self.critic.module.config.sums_limb_values:
            return jnp.sum(q1, axis=-1, keepdims=True), jnp.sum(q2, axis=-1, keepdims=True)
        return q1, q2

    def _value_mask(self, limb_mask: jax.Array) -> jax.Array:
        """[L] real limbs, or [1] True for a critic that sums its limbs' values."""
        return jnp.ones(1, bool) if self.critic.module.config.sums_limb_values else limb_mask

    def _task_mean(
        self,
        task_losses: Callable[..., jax.Array],
        batch: Transitions,
        structure: StructureBatch,
        *per_limb: jax.Array,
    ) -> jax.Array:
        """The mean over tasks of ``task_losses(batch, structure, *per_limb)`` ([T] losses), computed bucket by
        bucket when there are limb buckets; ``per_limb`` arrays are [T, B, L]."""
        if not self.buckets:
            return jnp.mean(task_losses(batch, structure, *per_limb))
        total = sum(
            jnp.sum(
                task_losses(
                    batch.bucket(bucket),
                    bucket_structures(structure, bucket),
                    *(bucket_slice(array, bucket, (2,)) for array in per_limb),
                )
            )
            for bucket in self.buckets
        )
        return total / batch.reward.shape[0]


def _without_delayed_step(
    state: LearnerState, batch: Transitions, structure: StructureBatch
) -> tuple[LearnerState, jax.Array]:
    """The branch of ``update`` without the delayed step: ``state`` untouched (actor and targets
    included) and a [] actor loss of 0."""
    return state, jnp.zeros((), jnp.float32)


def project(probabilities: jax.Array, moved: jax.Array, support: jax.Array) -> jax.Array:
    """The distribution with ``probabilities`` [..., A] on the atoms ``moved`` [..., A] (clipped to the
    support), projected onto ``support`` [A] (evenly spaced): each atom's probability split between its
    two neighbours on the support in proportion to closeness (C51's projection, Bellemare et al. 2017,
    Algorithm 1). Keeps the total probability, and the mean where nothing is clipped."""
    spacing = (support[-1] - support[0]) / (support.shape[0] - 1)
    moved = jnp.clip(moved, support[0], support[-1])
    closeness = jnp.clip(1.0 - jnp.abs(moved[..., :, None] - support) / spacing, 0.0, 1.0)
    return jnp.einsum("...j,...ji->...i", probabilities, closeness)


def pessimistic_value(q1: jax.Array, q2: jax.Array, pessimism: float) -> jax.Array:
    """[...] the twin critics' value for a TD target: their mean less ``pessimism`` halves of their gap
    (1: their minimum, TD3's clipped double Q, computed as such; 0: their mean)."""
    if pessimism == 1.0:
        return jnp.minimum(q1, q2)
    return (q1 + q2) / 2.0 - pessimism * jnp.abs(q1 - q2) / 2.0


def _masked_mean(values: jax.Array, mask: jax.Array) -> jax.Array:
    """[B, L] values, [L] mask -> [] mean over the batch and the masked-in columns."""
    return jnp.sum(jnp.where(mask, values, 0.0)) / (jnp.sum(mask) * values.shape[0])


def _check_tasks(stats: ReturnStats, tasks: int, what: str) -> None:
    """Refuse ``tasks`` tasks against return statistics of another number of tasks, which would broadcast
    one task's divisor over every task (trace time: the shapes are static)."""
    if stats.mean.shape[0] != tasks:
        raise ValueError(
            f"{what} {tasks} tasks against return statistics of {stats.mean.shape[0]}: give "
            f"Learner.init(rng, tasks={tasks})"
        )
