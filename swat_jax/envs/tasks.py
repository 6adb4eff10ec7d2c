"""What a body is asked to do: its reward, its termination, and what an episode carries besides the physics.

:class:`RunForward` is the planar benchmark's task: move along +x, with the family's reward and
termination (swat_jax/morphology/families.py). :class:`WalkToTarget` is the 3D benchmark's (SGRL, Chen et
al. 2023): from a random heading, walk toward a target point, which the episode carries and redraws once
reached (:mod:`swat_jax.envs.walk_to_target`). :func:`body_task` gives a body its task; both are frozen
sets of constants with pure methods of the same names, so :class:`~swat_jax.envs.body.BodyEnv` steps
every body through one code path.

``before`` and ``after`` are the simulator states (kinematics computed) at the start and the end of a
step; anything with MuJoCo's field names will do (MJX data, C physics data, ``mujoco.MjData``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from swat_jax.envs.walk_to_target import (
    FREE_QUATERNION,
    heading_pitch_roll,
    heading_quaternion,
    heading_velocity,
    new_target,
    next_target,
    progress,
    raw_key,
    tilt,
)
from swat_jax.morphology.types import FamilySpec, Morphology, Target

BOUNDED_STATE_LIMIT = 100.0
"""abs(qpos) (the torso's position coordinates excepted) and abs(qvel) stay below this for bodies with
``Termination.bounded_state``."""

TargetState = tuple[jax.Array, jax.Array]
"""3D: (target [2] float32, key [2] uint32): the point the body walks toward and the key that draws the next."""


@dataclasses.dataclass(frozen=True, eq=False)
class RunForward:
    """The planar task: reward for moving along +x, the family's termination by height, angle, bounded state
    and minimum site heights."""

    family: FamilySpec
    control_dt: float
    """Seconds per environment step (frame skip x timestep)."""
    site_ids: np.ndarray
    """[s] int32: the MuJoCo sites that must stay above their minimum heights."""

    reads_joint_axes = False
    """Whether the observation reads every hinge's axis (3D bodies)."""

    def episode(self, rng: jax.Array) -> tuple[jax.Array, TargetState | None]:
        """The key of an episode's initial pose, and what the episode carries besides it: nothing."""
        return rng, None

    def orient(self, qpos0: jax.Array, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The initial pose before its reset noise, and the key the noise draws from: as they are."""
        return qpos0, rng

    def advance(self, target: None, key: None, after: Any) -> tuple[None, None]:
        """What the next step carries: nothing."""
        return None, None

    def reward(self, before: Any, after: Any, target: None = None) -> jax.Array:
        """forward_weight * dx/dt + alive_bonus - control_cost * sum(a^2), x the torso's slide coordinate."""
        reward = self.family.reward
        forward = (after.qpos[0] - before.qpos[0]) / self.control_dt
        return (
            reward.forward_weight * forward
            + reward.alive_bonus
            - reward.control_cost * jnp.sum(after.ctrl**2)
        )

    def alive(self, before: Any, after: Any) -> jax.Array:
        """[] bool: every termination condition of the family holds after the step (``before`` unread)."""
        termination = self.family.termination
        alive = jnp.ones((), bool)
        if termination.height is not None:
            low, high = termination.height
            alive &= (after.qpos[1] > low) & (after.qpos[1] < high)
        if termination.max_abs_angle is not None:
            alive &= jnp.abs(after.qpos[2]) < termination.max_abs_angle
        if termination.bounded_state:
            alive &= jnp.all(jnp.abs(after.qpos[2:]) < BOUNDED_STATE_LIMIT)
            alive &= jnp.all(jnp.abs(after.qvel) < BOUNDED_STATE_LIMIT)
        if len(self.site_ids):
            minimum = np.array([z for _, z in termination.site_min_heights], np.float32)
            alive &= jnp.all(after.site_xpos[self.site_ids, 2] > minimum)
        return alive


@dataclasses.dataclass(frozen=True, eq=False)
class WalkToTarget:
    """The 3D task: from a random heading, walk toward a target point; termination by the torso's height
    (or its lowest named limb's), tilt, pitch and roll, bounded state and minimum speed, per family."""

    family: FamilySpec
    control_dt: float
    target: Target
    """Where targets are drawn and when one is reached (the family's)."""
    height_limbs: np.ndarray
    """[h] int32: limbs (by index) whose heights count toward the torso's for termination."""

    reads_joint_axes = True

    def episode(self, rng: jax.Array) -> tuple[jax.Array, TargetState]:
        """The key of an episode's initial pose, and its first target: a point at a random direction from
        the origin, with the key that draws the next."""
        pose_key, target_key = jax.random.split(rng)
        draw, key = jax.random.split(target_key)
        point = new_target(self.target, draw, jnp.zeros(2, jnp.float32)).astype(jnp.float32)
        return pose_key, (point, raw_key(key))

    def orient(self, qpos0: jax.Array, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The initial pose turned to a random heading about the vertical, and the key left for its noise."""
        rng, heading_key = jax.random.split(rng)
        heading = jax.random.uniform(heading_key, (), minval=-jnp.pi, maxval=jnp.pi)
        return qpos0.at[FREE_QUATERNION].set(heading_quaternion(heading).astype(qpos0.dtype)), rng

    def advance(self, target: jax.Array, key: jax.Array, after: Any) -> TargetState:
        """The next step's target: a new one once the torso has reached this one."""
        return next_target(self.target, target, key, after.xpos[1, :2])

    def reward(self, before: Any, after: Any, target: jax.Array) -> jax.Array:
        """forward_weight * (rate of approach to ``target``) + heading_weight * (velocity along the torso's
        heading at the start of the step) + alive_bonus - control_cost * sum(a^2), from the torso's frame
        positions before and after the step."""
        reward = self.family.reward
        start, end = before.xpos[1, :2], after.xpos[1, :2]
        value = reward.forward_weight * progress(target, start, end, self.control_dt)
        if reward.heading_weight:
            heading = heading_velocity(before.qpos[FREE_QUATERNION], start, end, self.control_dt)
            value += reward.heading_weight * heading
        return value + reward.alive_bonus - reward.control_cost * jnp.sum(after.ctrl**2)

    def alive(self, before: Any, after: Any) -> jax.Array:
        """[] bool: every termination condition of the family holds after the step (pitch and roll: at its
        start)."""
        termination = self.family.termination
        height = after.qpos[2]
        if len(self.height_limbs):
            height = jnp.minimum(height, jnp.min(after.xpos[self.height_limbs + 1, 2]))
        alive = jnp.ones((), bool)
        if termination.height is not None:
            low, high = termination.height
            alive &= (height > low) & (height < high)
        if termination.max_tilt is not None:
            alive &= jnp.abs(tilt(after.qpos[FREE_QUATERNION])) < termination.max_tilt
        if termination.max_pitch_roll is not None:
            _, pitch, roll = heading_pitch_roll(before.qpos[FREE_QUATERNION])
            limit = termination.max_pitch_roll
            alive &= (jnp.abs(pitch) < limit) & (jnp.abs(roll) < limit)
        if termination.bounded_state:
            alive &= jnp.all(jnp.abs(after.qpos[3:]) < BOUNDED_STATE_LIMIT)
            alive &= jnp.all(jnp.abs(after.qvel) < BOUNDED_STATE_LIMIT)
        if termination.min_speed_squared is not None:
            alive &= jnp.sum(after.qvel**2) > termination.min_speed_squared
        return alive


Task = RunForward | WalkToTarget


def body_task(morphology: Morphology, model: mujoco.MjModel) -> Task:
    """``morphology``'s task, its constants read from its compiled ``model``."""
    family = morphology.family
    control_dt = morphology.control_dt
    if family.target is None:
        sites = [
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
            for name, _ in family.termination.site_min_heights
        ]
        return RunForward(family, control_dt, np.array(sites, np.int32))
    limbs = [
        morphology.limb_names.index(name)
        for name in family.termination.height_bodies
        if name in morphology.limb_names
    ]
    return WalkToTarget(family, control_dt, family.target, np.array(limbs, np.int32))
