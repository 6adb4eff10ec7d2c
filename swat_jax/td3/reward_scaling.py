"""Per-task reward scaling by the spread of each task's discounted returns (FastTD3's per-task reward
normaliser, Seo et al. 2025; the per-task normalisation of BRC, Nauman et al. 2025), so that a body whose
returns are large does not outweigh the others in the shared loss of the all-task update.

Collection tracks every copy's discounted return of its episode so far, G_t = r_t + discount G_{t-1}
(0 at an episode's start), and these statistics keep the mean and variance of the G_t of each task and
its largest |G_t|. The TD update divides a task's rewards by

    max(std(G) + EPSILON, max |G| / RETURN_BOUND),

so the task's scaled returns have a spread of about 1 and none seen so far beyond RETURN_BOUND. The
divisor changes as the statistics do, so the critic follows a slowly moving target, as in FastTD3.
Logged returns and evaluation stay in the environment's units.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax.networks.observation_stats import accumulate

RETURN_BOUND = 10.0
"""The largest scaled |G| the divisor allows (FastTD3's ``g_max``)."""
EPSILON = 1e-8
"""Added to the standard deviation of G."""


@struct.dataclass
class ReturnStats:
    """Statistics of the discounted returns of each of K tasks, over every copy and step seen."""

    mean: jax.Array
    """[K] mean of G."""
    variance: jax.Array
    """[K] population variance of G."""
    count: jax.Array
    """[] steps seen per task (summed over copies)."""
    peak: jax.Array
    """[K] largest |G|."""

    @classmethod
    def zeros(cls, tasks: int) -> ReturnStats:
        """Before any step: divisor 1, rewards unscaled."""
        return cls(
            mean=jnp.zeros(tasks, jnp.float32),
            variance=jnp.ones(tasks, jnp.float32),
            count=jnp.zeros((), jnp.float32),
            peak=jnp.zeros(tasks, jnp.float32),
        )

    def merged(self, returns: jax.Array, seen: jax.Array) -> ReturnStats:
        """These statistics with the G of ``returns`` [..., K, n] (per task K and copy n) merged in where
        ``seen`` [...] (the steps a seed took; broadcast against the leading axes)."""
        per_task_last = jnp.swapaxes(returns, -1, -2)  # [..., n, K]: a feature per task
        mask = jnp.broadcast_to(seen[..., None], per_task_last.shape[:-1])
        moments = accumulate(
            {"mean": self.mean, "variance": self.variance, "count": self.count}, per_task_last, mask
        )
        largest = jnp.max(
            jnp.where(mask[..., None], jnp.abs(per_task_last), 0.0), axis=tuple(range(mask.ndim))
        )
        return ReturnStats(
            mean=moments["mean"],
            variance=moments["variance"],
            count=moments["count"],
            peak=jnp.maximum(self.peak, largest),
        )

    def divisor(self) -> jax.Array:
        """[K] what each task's rewards are divided by: max(std(G) + EPSILON, max |G| / RETURN_BOUND)."""
        return jnp.maximum(jnp.sqrt(self.variance) + EPSILON, self.peak / RETURN_BOUND)


def discounted_returns(
    running: jax.Array, reward: jax.Array, ended: jax.Array, stepped: jax.Array, discount: float
) -> tuple[jax.Array, jax.Array]:
    """One step of every copy's discounted return.

    Args:
        running: [..., K, n] each copy's G before the step (0 at its episode's start).
        reward: [..., K, n] the step's rewards.
        ended: [..., K, n] bool, the step ended the copy's episode (terminated or truncated).
        stepped: [...] bool, the seeds that took the step (the others keep their G).

    Returns:
        (G after the step, for the statistics; the G the next step starts from: 0 where an episode ended).
    """
    took = stepped[..., None, None]
    now = jnp.where(took, reward + discount * running, running)
    return now, jnp.where(took & ended, 0.0, now)
