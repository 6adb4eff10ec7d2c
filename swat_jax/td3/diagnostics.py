"""What a seed's learning looks like from inside the iteration, per body: the signs of a seed stranded on
a plateau (every body diving forward to fall in a few steps) beside those of one that breaks out.

Recorded in the jitted collection at every step of every copy (no host round trip); the critics evaluate the
chunk's states in one batch after it (one call instead of one per step, whose latency would slow the
sequential collection), and the sums per seed and body over the iteration go to the host, where :class:`swat_jax.runs.metrics.MetricsWindow` turns the sums into the ``diag/*``
columns of ``metrics.csv``:

- **estimate against return.** At each episode's first state s_0 the twin critics' estimate
  Q(s_0, pi(s_0)) (their mean over the body's real limbs, as the critic regresses every limb on the
  body's TD target, and the mean of the twins), beside the discounted return the episode then got,
  sum_t discount^t r_t, acting with the exploration noise of the run. With reward scaling the critic
  learns scaled rewards, so its estimate is multiplied back by the body's divisor
  (:meth:`~swat_jax.td3.reward_scaling.ReturnStats.divisor`) into the environment's units. An episode cut
  by the time limit counts its return up to the cut, so a long-lived body's return reads low beside the
  estimate (which bootstraps past it); a diving body's episodes end by termination and compare exactly.
- **twin disagreement**: |Q1 - Q2| of the same estimate at every state acted on.
- **saturation**: the share of the policy's actions (of the real motors) at |pi(s)| >= :data:`SATURATED`.
- **exploration noise applied**: the root mean square of (the action taken - pi(s)) over the real motors,
  after clipping to [-1, 1] (so a saturated policy explores less than its noise's std), in the policy
  phase only.
- **update share**: the updates that took a batch of the body (:mod:`swat_jax.td3.schedules`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax import axes
from swat_jax.morphology import StructureBatch
from swat_jax.networks.policies import Params

SATURATED = 0.99
"""|action| from which a policy's action counts as saturated (the actor ends in tanh)."""


@struct.dataclass
class EpisodeValues:
    """Each copy's episode so far, for the estimate against the return; [K, n] per seed (with the seed axis
    in front in a :class:`~swat_jax.td3.iteration.TrainState`)."""

    start_value: jax.Array = axes.field(task=0, copy=1)
    """The critics' estimate at the episode's first state, in reward units."""
    discounted: jax.Array = axes.field(task=0, copy=1)
    """sum_t discount^t r_t of the episode's steps so far."""
    discount: jax.Array = axes.field(task=0, copy=1)
    """discount^t of the episode's next step: 1 at its start (where the next step records its estimate)."""

    @classmethod
    def fresh(cls, shape: tuple[int, ...]) -> EpisodeValues:
        """Every copy at an episode's start, for arrays of ``shape`` ([S, K, n])."""
        return cls(
            start_value=jnp.zeros(shape, jnp.float32),
            discounted=jnp.zeros(shape, jnp.float32),
            discount=jnp.ones(shape, jnp.float32),
        )


@struct.dataclass
class StepDiagnostics:
    """One collection step of every copy, [S, K, n] each (stacked over the chunk)."""

    ended_estimate: jax.Array
    """The estimate at the start of the episode this step ended (0 where none ended)."""
    ended_return: jax.Array
    """The discounted return of the episode this step ended (0 where none ended)."""
    ended: jax.Array
    """1 where this step ended an episode of a stepping seed, else 0."""
    twin_gap: jax.Array
    """|Q1 - Q2| at the state acted on (0 where the seed did not step)."""
    saturated: jax.Array
    """The share of the policy's real motor actions at |pi(s)| >= SATURATED (0 where the seed did not step)."""
    noise_square: jax.Array
    """Mean over the real motors of (action taken - pi(s))^2, in the policy phase (0 elsewhere)."""
    stepped: jax.Array
    """1 where the copy stepped (its seed did not wait)."""
    explored: jax.Array
    """1 where the copy stepped in the policy phase."""


@struct.dataclass
class Acted:
    """What one collection step acted on, for the diagnostics, of every copy: [S, K, n, ...] (stacked over
    the chunk by the iteration's scan)."""

    observation: jax.Array
    """[S, K, n, L, F] the observation acted on."""
    policy: jax.Array
    """[S, K, n, L(, M)] pi(s), the policy's action before exploration."""
    action: jax.Array
    """[S, K, n, L(, M)] the action taken."""
    ended: jax.Array
    """[S, K, n] bool, the step ended the copy's episode (terminated or truncated)."""
    policy_phase: jax.Array
    """[S] bool, the policy acted (not the uniform random phase)."""


SUMS = ("estimate", "return", "episodes", "twin_gap", "saturated", "noise_square", "steps", "policy_steps")
"""The per-seed, per-body sums [S, K] of an iteration (:func:`summed`), with ``updates`` from the schedule."""

ValueEstimate = Callable[[Params, jax.Array, jax.Array, jax.Array], tuple[jax.Array, jax.Array]]
"""``estimate(critic_params, divisor [K], observation [K, n, L, F], policy [K, n, L(, M)])`` -> the twin
critics' values (Q1, Q2) [K, n] of one seed, in reward units."""


def make_value_estimate(
    values: Callable[[Params, jax.Array, jax.Array, StructureBatch], tuple[jax.Array, jax.Array]],
    structure: StructureBatch,
) -> ValueEstimate:
    """One seed's :data:`ValueEstimate` from ``values(critic_params, observation [B, L, F], action, structure)
    -> (Q1, Q2) [B]`` of one task (:meth:`~swat_jax.td3.learner.Learner.body_values`), over the tasks of
    ``structure`` [K, ...]."""

    def estimate(
        critic_params: Params, divisor: jax.Array, observation: jax.Array, policy: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        q1, q2 = jax.vmap(values, in_axes=(None, 0, 0, 0))(critic_params, observation, policy, structure)
        return q1 * divisor[:, None], q2 * divisor[:, None]

    return estimate


def chunk_estimates(estimate: ValueEstimate, critic_params: Params, divisor: jax.Array, acted: Acted):
    """The twin critics' estimates (Q1, Q2) [chunk, S, K, n] of every state of the chunk ``acted``
    ([chunk, S, ...]) after the policy's action, in one batch per seed: the chunk joins the copy axis.
    ``estimate`` maps the seeds (:data:`ValueEstimate` over the seed axis), ``divisor`` [S, K]."""
    chunk, seeds, tasks, copies = acted.ended.shape

    def batched(array: jax.Array) -> jax.Array:
        """[chunk, S, K, n, ...] -> [S, K, n x chunk, ...]."""
        moved = jnp.moveaxis(array, 0, 3)
        return moved.reshape(seeds, tasks, copies * chunk, *moved.shape[4:])

    q1, q2 = estimate(critic_params, divisor, batched(acted.observation), batched(acted.policy))
    return tuple(jnp.moveaxis(q.reshape(seeds, tasks, copies, chunk), 3, 0) for q in (q1, q2))


def iteration_sums(
    values: EpisodeValues,
    acted: Acted,
    q1: jax.Array,
    q2: jax.Array,
    reward: jax.Array,
    stepped: jax.Array,
    mask: jax.Array,
    discount: float,
) -> tuple[EpisodeValues, dict[str, jax.Array]]:
    """Every copy's episode carried through the chunk and the iteration's sums per seed and body [S, K]
    (:data:`SUMS`), from what it acted on ``acted`` and the estimates ``q1``, ``q2`` [chunk, S, K, n]
    (:func:`chunk_estimates`), its rewards [chunk, S, K, n] and ``stepped`` [chunk, S]."""

    def one(values: EpisodeValues, at: tuple) -> tuple[EpisodeValues, StepDiagnostics]:
        acted, q1, q2, reward, stepped = at
        return step(
            values, q1, q2, acted.policy, acted.action, mask, reward, acted.ended, stepped,
            acted.policy_phase, discount,
        )  # fmt: skip

    values, steps = jax.lax.scan(one, values, (acted, q1, q2, reward, stepped))
    return values, summed(steps)


def step(
    values: EpisodeValues,
    q1: jax.Array,
    q2: jax.Array,
    policy: jax.Array,
    action: jax.Array,
    mask: jax.Array,
    reward: jax.Array,
    ended: jax.Array,
    stepping: jax.Array,
    policy_phase: jax.Array,
    discount: float,
) -> tuple[EpisodeValues, StepDiagnostics]:
    """One collection step's diagnostics and every copy's episode carried on.

    Args:
        values: [S, K, n] each copy's episode before the step.
        q1, q2: [S, K, n] the twin critics' estimate of the state acted on (:data:`ValueEstimate`).
        policy, action: [S, K, n, L(, M)] pi(s) and the action taken.
        mask: [K, 1, L(, M)] the real motors (the structure's motor_mask: not the torso, not padding).
        reward: [S, K, n] the step's rewards.
        ended: [S, K, n] bool, the step ended the copy's episode (terminated or truncated).
        stepping: [S] bool, the seeds that took the step (a seed waiting for its round's updates keeps
            its episode as it is).
        policy_phase: [S] bool, the policy acted (not the uniform random phase).
    """
    took = jnp.broadcast_to(stepping[:, None, None], reward.shape)
    start_value = jnp.where(values.discount == 1.0, (q1 + q2) / 2.0, values.start_value)
    discounted = values.discounted + values.discount * reward
    finished = took & ended
    motor_axes = tuple(range(3, policy.ndim))
    motors = jnp.maximum(jnp.sum(mask, axis=tuple(range(2, mask.ndim))), 1)[None]  # [1, K, 1]
    saturated = jnp.sum((jnp.abs(policy) >= SATURATED) & mask, axis=motor_axes) / motors
    noise_square = jnp.sum(jnp.where(mask, (action - policy) ** 2, 0.0), axis=motor_axes) / motors
    explored = took & policy_phase[:, None, None]
    carried = EpisodeValues(
        start_value=jnp.where(took, start_value, values.start_value),
        discounted=jnp.where(finished, 0.0, jnp.where(took, discounted, values.discounted)),
        discount=jnp.where(finished, 1.0, jnp.where(took, values.discount * discount, values.discount)),
    )
    diagnostics = StepDiagnostics(
        ended_estimate=jnp.where(finished, start_value, 0.0),
        ended_return=jnp.where(finished, discounted, 0.0),
        ended=finished.astype(jnp.float32),
        twin_gap=jnp.where(took, jnp.abs(q1 - q2), 0.0),
        saturated=jnp.where(took, saturated, 0.0),
        noise_square=jnp.where(explored, noise_square, 0.0),
        stepped=took.astype(jnp.float32),
        explored=explored.astype(jnp.float32),
    )
    return carried, diagnostics


def summed(steps: StepDiagnostics) -> dict[str, jax.Array]:
    """The iteration's sums per seed and body, [S, K] each (:data:`SUMS`), from its steps stacked over the
    chunk [chunk, S, K, n]."""
    total = jax.tree.map(lambda leaf: jnp.sum(leaf, axis=(0, 3)), steps)
    return {
        "estimate": total.ended_estimate,
        "return": total.ended_return,
        "episodes": total.ended,
        "twin_gap": total.twin_gap,
        "saturated": total.saturated,
        "noise_square": total.noise_square,
        "steps": total.stepped,
        "policy_steps": total.explored,
    }
