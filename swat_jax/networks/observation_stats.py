"""Observation normalisation: each limb feature standardised by running statistics (FastTD3's empirical
normaliser, Seo et al. 2025), one set of statistics over every real limb of every body, so the same map
applies to every token and a new body needs nothing new.

The statistics are variables of the actor and of the critic (collection :data:`STATS`, beside
``params``), so a policy file or an exported policy carries them with its weights. Training accumulates
them from the observations it collects (:func:`accumulate`, :meth:`swat_jax.td3.learner.Learner.observe`);
the gradient never reaches them. ``NetworkConfig.observation_normalisation`` switches it on.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

STATS = "observation_stats"
"""The variable collection of the statistics: {"mean": [F], "variance": [F], "count": []}."""

NORMALISER = "observation_normaliser"
"""The normaliser's module name in the actor and the critic: the statistics are
``variables[STATS][NORMALISER]``."""

STD_EPSILON = 1e-2
"""Added to the standard deviation: a feature constant so far (a 2D body's y, a type one-hot) maps to 0
instead of dividing by 0, and before any data (mean 0, variance 1) the map is x / 1.01."""


class ObservationNormaliser(nn.Module):
    """(limb_obs - mean) / (std + STD_EPSILON) per feature; padded limbs stay 0."""

    @nn.compact
    def __call__(self, limb_obs: jax.Array, limb_mask: jax.Array) -> jax.Array:
        """limb_obs [batch, limbs, F], limb_mask [limbs] -> [batch, limbs, F]."""
        features = limb_obs.shape[-1]
        mean = self.variable(STATS, "mean", jnp.zeros, (features,), jnp.float32)
        variance = self.variable(STATS, "variance", jnp.ones, (features,), jnp.float32)
        self.variable(STATS, "count", jnp.zeros, (), jnp.float32)
        std = jnp.sqrt(jax.lax.stop_gradient(variance.value))
        scaled = (limb_obs - jax.lax.stop_gradient(mean.value)) / (std + STD_EPSILON)
        return jnp.where(limb_mask[:, None], scaled, 0.0)


def accumulate(stats: dict[str, Any], observations: jax.Array, limb_mask: jax.Array) -> dict[str, Any]:
    """``stats`` ({"mean", "variance", "count"}) merged with the real limbs of ``observations`` [..., L, F]
    (``limb_mask`` [..., L], broadcast against its leading axes): the mean and variance of everything seen
    (Chan et al.'s parallel update; the population variance)."""
    weights = jnp.broadcast_to(limb_mask, observations.shape[:-1]).astype(jnp.float32)[..., None]
    axes = tuple(range(observations.ndim - 1))
    seen = jnp.sum(weights)
    batch_mean = jnp.sum(weights * observations, axis=axes) / jnp.maximum(seen, 1.0)
    batch_variance = jnp.sum(weights * (observations - batch_mean) ** 2, axis=axes) / jnp.maximum(seen, 1.0)
    count = stats["count"]
    total = jnp.maximum(count + seen, 1.0)
    delta = batch_mean - stats["mean"]
    merged = {
        "mean": stats["mean"] + delta * seen / total,
        "variance": (stats["variance"] * count + batch_variance * seen + delta**2 * count * seen / total)
        / total,
        "count": count + seen,
    }
    return jax.tree.map(lambda new, old: jnp.where(seen > 0, new, old), merged, stats)


def with_stats(variables: dict[str, Any], stats: dict[str, Any]) -> dict[str, Any]:
    """A network's ``variables`` with its observation statistics replaced by ``stats``."""
    return {**variables, STATS: {NORMALISER: stats}}
