"""The 3D task (SGRL, Chen et al. 2023): a body with a free torso walks toward a point on the floor.

Pure functions of the torso's state, used by :class:`~swat_jax.envs.body.BodyEnv` for a 3D family
(:class:`~swat_jax.morphology.types.Target`):

- at reset the torso faces a random heading and a target point is drawn at a random direction;
- the reward is the rate at which the torso's distance to the target shrinks, plus (walkers, humanoids,
  cheetahs) its velocity along the heading it had at the start of the step, plus the alive bonus, minus
  the control cost;
- a torso within ``reach`` of the target gets a new one (after the step's observation was made).

Quaternions are MuJoCo's (w, x, y, z), read from qpos as they are, not normalised (the reset noise
leaves them slightly off unit length; the angles below are those of the matrix the benchmark builds
from them).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from swat_jax.morphology.types import Target

FREE_QUATERNION = slice(3, 7)
"""The torso's orientation in qpos (its free joint: position 0:3, quaternion 3:7)."""


def raw_key(key: jax.Array) -> jax.Array:
    """``key`` as [2] uint32 data (a typed key's data; a raw key as it is), to keep in a state pytree."""
    return jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key


def heading_quaternion(heading: jax.Array) -> jax.Array:
    """[4] the rotation by ``heading`` (rad) about the vertical axis."""
    half = 0.5 * heading
    return jnp.stack([jnp.cos(half), jnp.zeros_like(half), jnp.zeros_like(half), jnp.sin(half)])


def rotation_matrix(quaternion: jax.Array) -> jax.Array:
    """[3, 3] the rotation matrix of a (w, x, y, z) quaternion, by the unit-quaternion formula."""
    w, x, y, z = quaternion
    return jnp.array(
        [
            [1 - 2 * y**2 - 2 * z**2, 2 * x * y - 2 * z * w, 2 * x * z + 2 * y * w],
            [2 * x * y + 2 * z * w, 1 - 2 * x**2 - 2 * z**2, 2 * y * z - 2 * x * w],
            [2 * x * z - 2 * y * w, 2 * y * z + 2 * x * w, 1 - 2 * x**2 - 2 * y**2],
        ]
    )


def heading_pitch_roll(quaternion: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The torso's yaw about the vertical, pitch and roll (rad), z-y-x Euler angles of ``quaternion``."""
    r = rotation_matrix(quaternion)
    heading = jnp.arctan2(r[1, 0], r[0, 0])
    pitch = jnp.arctan2(-r[2, 0], jnp.sqrt(r[2, 1] ** 2 + r[2, 2] ** 2))
    roll = jnp.arctan2(r[2, 1], r[2, 2])
    return heading, pitch, roll


def tilt(quaternion: jax.Array) -> jax.Array:
    """The angle (rad) between the torso's z axis and the vertical."""
    w, x, y, z = quaternion
    return 2.0 * jnp.arctan2(jnp.sqrt(x * x + y * y), jnp.sqrt(w * w + z * z))


def new_target(task: Target, rng: jax.Array, origin: jax.Array) -> jax.Array:
    """[2] a point at a uniform random direction from ``origin`` [2], at a distance uniform in
    ``task.distance``."""
    direction_key, distance_key = jax.random.split(rng)
    angle = jax.random.uniform(direction_key, (), minval=-jnp.pi, maxval=jnp.pi)
    low, high = task.distance
    distance = low if low == high else jax.random.uniform(distance_key, (), minval=low, maxval=high)
    return origin + distance * jnp.stack([jnp.cos(angle), jnp.sin(angle)])


def next_target(
    task: Target, target: jax.Array, key: jax.Array, position: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """(target [2], key [2] uint32) for the next step: a new point once the torso at ``position`` [2] is
    within ``task.reach`` of ``target`` (and the target is not within ``reach`` of the origin, as the
    benchmark checks), else the same; ``key`` advances only when a point is drawn."""
    reached = (jnp.linalg.norm(target - position) < task.reach) & (jnp.linalg.norm(target) > task.reach)
    advanced, draw = jax.random.split(jax.random.wrap_key_data(key))
    origin = position if task.from_torso else jnp.zeros_like(position)
    drawn = new_target(task, draw, origin).astype(target.dtype)
    return jnp.where(reached, drawn, target), jnp.where(reached, jax.random.key_data(advanced), key)


def progress(target: jax.Array, before: jax.Array, after: jax.Array, dt: float) -> jax.Array:
    """The rate (m/s) at which the distance from the torso to ``target`` shrank, positions [2].

    |t - b| - |t - a| is computed as (a - b) . (2 t - b - a) / (|t - b| + |t - a|): the plain difference
    of two float32 distances of 10 km keeps millimetres, 0.1 m/s over a step of 8 ms.
    """
    to_before, to_after = target - before, target - after
    shrink = jnp.dot(after - before, to_before + to_after)
    return shrink / (jnp.linalg.norm(to_before) + jnp.linalg.norm(to_after)) / dt


def heading_velocity(quaternion: jax.Array, before: jax.Array, after: jax.Array, dt: float) -> jax.Array:
    """The torso's horizontal velocity along its heading at the start of the step (``quaternion``)."""
    heading, _, _ = heading_pitch_roll(quaternion)
    return jnp.dot(after - before, jnp.stack([jnp.cos(heading), jnp.sin(heading)])) / dt
