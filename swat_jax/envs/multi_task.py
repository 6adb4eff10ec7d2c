"""K bodies with n parallel copies each, stepped in one jitted function and padded to one limb count.

Bodies with different trees compile to different MJX programs, so each body is vmapped over its own
copies and the K programs sit side by side in the same jitted step (a Python loop at trace time, none at
run time). Observations and actions are padded to L = max_limbs so that the policy sees one batch
``[K, n, L, F]`` (paper section 3); the structure of the bodies, which tells real limbs from padding, is
the task set's (:func:`swat_jax.networks.task_set`), not the environment's.

Finished copies (terminated, truncated, or unstable) start a new episode in the same step. The step
returns the observation reached *before* that reset, for the replay buffer, and the state holds the
observation after it, for acting.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax.envs.body import BodyEnv, EnvState
from swat_jax.envs.physics import Implementation
from swat_jax.morphology.mjcf import load
from swat_jax.morphology.types import Morphology


@struct.dataclass
class EpisodeStats:
    """Sums over the episodes each body finished since the stats were last cleared, [K] each."""

    return_sum: jax.Array
    length_sum: jax.Array
    count: jax.Array

    @classmethod
    def zeros(cls, num_bodies: int) -> EpisodeStats:
        return cls(
            return_sum=jnp.zeros(num_bodies, jnp.float32),
            length_sum=jnp.zeros(num_bodies, jnp.float32),
            count=jnp.zeros(num_bodies, jnp.int32),
        )


@struct.dataclass
class MultiTaskState:
    """All copies of all bodies; K bodies, n copies, L = max_limbs, F features."""

    bodies: tuple[EnvState, ...]
    """K per-body states, each with a leading copy axis [n]."""
    observation: jax.Array
    """[K, n, L, F] observations to act on (after any automatic reset), zero on padded limbs."""
    rng: jax.Array
    """Key for the reset noise of the next automatic resets."""
    episodes: EpisodeStats
    """Finished-episode sums per body, for logging; clear with ``state.replace(episodes=...)``."""


@struct.dataclass
class StepResult:
    """What one step of every copy produced, for the replay buffer; [K, n] unless stated."""

    next_observation: jax.Array
    """[K, n, L, F] observation reached by the step, before any automatic reset."""
    reward: jax.Array
    terminated: jax.Array
    """bool: the episode ended by a termination condition; the TD target does not bootstrap."""
    truncated: jax.Array
    """bool: the episode hit the time limit; the TD target bootstraps from ``next_observation``."""


class MultiTaskEnv:
    """K bodies x n copies on MJX with padded observations and automatic resets.

    Args:
        bodies: loaded bodies, benchmark names or MJCF paths (K of them); all must share one
            observation width (families with the same limb-type vocabulary).
        copies: n, parallel copies of each body.
        max_limbs: L, the padded limb count; defaults to the largest body's.
        torso_relative_x: see :class:`~swat_jax.envs.body.BodyEnv`.
        physics: MJX implementation, "jax" or "warp" (:class:`~swat_jax.envs.physics.Simulator`).
        runs: how many instances of this environment one program vmaps over (seeds); "warp" sizes its
            contact buffers for ``2 * copies * runs`` simulations per call (a step derives the stepped
            and the fresh copies together).

    Raises:
        ValueError: no bodies, ``copies`` < 1, a body larger than ``max_limbs``, or bodies whose
            observations have different widths.
    """

    def __init__(
        self,
        bodies: Sequence[Morphology | str],
        copies: int,
        *,
        max_limbs: int | None = None,
        torso_relative_x: bool = True,
        physics: Implementation = "jax",
        runs: int = 1,
    ):
        if copies < 1:
            raise ValueError(f"copies must be at least 1, got {copies}")
        morphologies = [body if isinstance(body, Morphology) else load(body) for body in bodies]
        if not morphologies:
            raise ValueError("MultiTaskEnv needs at least one body")
        largest = max(morphologies, key=lambda body: body.num_limbs)
        if max_limbs is not None and max_limbs < largest.num_limbs:
            raise ValueError(f"{largest.name} has {largest.num_limbs} limbs, more than max_limbs={max_limbs}")
        self.envs = tuple(
            BodyEnv(body, torso_relative_x=torso_relative_x, physics=physics, worlds=2 * copies * runs)
            for body in morphologies
        )
        widths = {env.morphology.name: env.observation_features for env in self.envs}
        if len(set(widths.values())) > 1:
            raise ValueError(
                "these bodies have observations of different widths and cannot share a policy: "
                + ", ".join(f"{name} ({width} features)" for name, width in widths.items())
                + "; train families with different limb-type vocabularies separately"
            )
        self.copies = copies
        self.max_limbs = largest.num_limbs if max_limbs is None else max_limbs
        self.observation_features = self.envs[0].observation_features

    @property
    def num_bodies(self) -> int:
        return len(self.envs)

    @property
    def body_names(self) -> tuple[str, ...]:
        return tuple(env.morphology.name for env in self.envs)

    def reset(self, rng: jax.Array) -> MultiTaskState:
        """Start an episode in every copy of every body."""
        rng, *keys = jax.random.split(rng, self.num_bodies + 1)
        bodies = tuple(
            jax.vmap(env.reset)(jax.random.split(key, self.copies))
            for env, key in zip(self.envs, keys, strict=True)
        )
        return MultiTaskState(
            bodies=bodies,
            observation=self._padded_observation(bodies),
            rng=rng,
            episodes=EpisodeStats.zeros(self.num_bodies),
        )

    def step(self, state: MultiTaskState, action: jax.Array) -> tuple[MultiTaskState, StepResult]:
        """Apply ``action`` [K, n, L] (padded limbs ignored) to every copy; reset finished copies."""
        rng, *keys = jax.random.split(state.rng, self.num_bodies + 1)
        stepped, continued = [], []
        for env, body_state, body_action, key in zip(self.envs, state.bodies, action, keys, strict=True):
            after_step, fresh = _step_and_restart(env, body_state, body_action[:, : env.num_limbs], key)
            stepped.append(after_step)
            continued.append(_where_done(after_step.done, fresh, after_step))
        finished = jnp.stack([body.done for body in stepped])
        result = StepResult(
            next_observation=self._padded_observation(stepped),
            reward=jnp.stack([body.reward for body in stepped]),
            terminated=jnp.stack([body.terminated for body in stepped]),
            truncated=jnp.stack([body.truncated for body in stepped]),
        )
        episodes = EpisodeStats(
            return_sum=state.episodes.return_sum
            + jnp.sum(jnp.where(finished, jnp.stack([b.episode_return for b in stepped]), 0.0), axis=1),
            length_sum=state.episodes.length_sum
            + jnp.sum(jnp.where(finished, jnp.stack([b.episode_length for b in stepped]), 0), axis=1),
            count=state.episodes.count + jnp.sum(finished, axis=1, dtype=jnp.int32),
        )
        continued = tuple(continued)
        next_state = MultiTaskState(
            bodies=continued,
            observation=self._padded_observation(continued),
            rng=rng,
            episodes=episodes,
        )
        return next_state, result

    def _padded_observation(self, bodies: Sequence[EnvState]) -> jax.Array:
        """[K, n, L, F] from K per-body observations [n, limbs_k, F], zeros on padded limbs."""
        return jnp.stack(
            [
                jnp.pad(body.observation, ((0, 0), (0, self.max_limbs - env.num_limbs), (0, 0)))
                for env, body in zip(self.envs, bodies, strict=True)
            ]
        )


def _step_and_restart(
    env: BodyEnv, state: EnvState, action: jax.Array, rng: jax.Array
) -> tuple[EnvState, EnvState]:
    """Every copy [n] stepped, and a fresh episode for every copy (used where the step ended one).

    The stepped and the fresh simulator states share one kinematics pass over 2n copies, so the
    compiled step holds one kinematics program per body instead of two.
    """
    copies = action.shape[0]
    simulated = jax.vmap(env.simulate)(state.data, action)
    initial = jax.vmap(env.initial_data)(jax.random.split(rng, copies))
    both = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), simulated, initial)
    both = jax.vmap(env.kinematics)(both)
    simulated, initial = (
        jax.tree_util.tree_map(lambda x, s=s: x[s], both) for s in (slice(None, copies), slice(copies, None))
    )
    return jax.vmap(env.finish_step)(state, simulated), jax.vmap(env.start)(initial)


def _where_done(done: jax.Array, fresh: EnvState, stepped: EnvState) -> EnvState:
    """Per copy, ``fresh`` where ``done`` [n] else ``stepped``.

    Selected copy by copy (vmapped) with ``mjx.Data.where``, which leaves alone the buffers a Warp state
    shares across copies (:class:`~swat_jax.envs.physics.Simulator`).
    """

    def select(done: jax.Array, fresh: EnvState, stepped: EnvState) -> EnvState:
        others = jax.tree_util.tree_map(
            lambda new, old: jnp.where(done, new, old), fresh.replace(data=None), stepped.replace(data=None)
        )
        return others.replace(data=stepped.data.where(done, fresh.data))

    return jax.vmap(select)(done, fresh, stepped)
