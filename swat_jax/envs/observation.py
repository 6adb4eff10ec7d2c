"""The benchmark's per-limb observation, as a pure function.

One row per limb, limbs in pre-order (limb i is MuJoCo body i + 1):

    0:3       world position of the limb's frame origin, torso x subtracted
    3:6       linear velocity of the frame origin, world axes, clipped to [-10, 10]
    6:9       angular velocity, world axes
    9:12      exponential map of the world orientation (axis * angle, angle in [0, pi])
    12:12+T   limb-type one-hot (all zeros for an untyped limb)
    12+T      joint angle scaled to [0, 1] over the joint range; 0 for the torso
    13+T:15+T joint range ends as (180 + degrees) / 360; 0 for the torso

Works on MJX data under jit and on MuJoCo C data arrays alike (inputs are plain arrays).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import mujoco
import numpy as np

from swat_jax.morphology.types import Morphology

VELOCITY_CLIP = 10.0
KINEMATIC_FEATURES = 12
"""Position, linear velocity, angular velocity and orientation: the slots before the limb type."""


def features_per_limb(num_limb_types: int) -> int:
    """F, the values of one limb's observation for a family of ``num_limb_types`` limb types: the kinematic
    slots, the limb type one-hot, and the scaled joint angle and range (3)."""
    return KINEMATIC_FEATURES + num_limb_types + 3


class ObservationLayout(NamedTuple):
    """What a body's observation needs besides the simulator state (host-side constants).

    n = number of limbs, T = number of limb types of the family.
    """

    limb_type_one_hot: np.ndarray
    """[n, T] float32."""
    joint_qpos_address: np.ndarray
    """[n] int32 index into qpos of each limb's hinge; 0 for the torso (masked)."""
    joint_range: np.ndarray
    """[n, 2] float32 joint range in degrees; 0 for the torso."""
    has_joint: np.ndarray
    """[n] bool, False for the torso."""

    @property
    def features(self) -> int:
        return features_per_limb(self.limb_type_one_hot.shape[1])


def observation_layout(morphology: Morphology, model: mujoco.MjModel) -> ObservationLayout:
    """The layout of ``morphology``, compiled as ``model``."""
    types = np.asarray(morphology.limb_types)
    one_hot = (types[:, None] == np.arange(morphology.family.num_limb_types)[None, :]).astype(np.float32)
    addresses = np.zeros(morphology.num_limbs, np.int32)
    for limb, joint in enumerate(morphology.joint_names[1:], start=1):
        addresses[limb] = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
    return ObservationLayout(
        limb_type_one_hot=one_hot,
        joint_qpos_address=addresses,
        joint_range=morphology.joint_range_array(),
        has_joint=np.arange(morphology.num_limbs) > 0,
    )


def exponential_map(quaternion: jnp.ndarray) -> jnp.ndarray:
    """Rotation vector (axis * angle, angle folded into [0, pi]) of unit quaternions [..., 4] (w, x, y, z)."""
    q = jnp.where(quaternion[..., :1] < 0, -quaternion, quaternion)
    vector = q[..., 1:]
    sine = jnp.linalg.norm(vector, axis=-1, keepdims=True)
    angle = 2.0 * jnp.arctan2(sine, q[..., :1])
    safe = jnp.where(sine > 1e-12, sine, 1.0)
    return jnp.where(sine > 1e-12, vector / safe * angle, 0.0)


def frame_velocities(
    xpos: jnp.ndarray, cvel: jnp.ndarray, root_com: jnp.ndarray
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Linear and angular velocity [n, 3] of each frame origin, world axes, from MuJoCo's com-based cvel.

    cvel [n, 6] is (angular, linear) at the root subtree's centre of mass ``root_com`` [3]; moving the
    reference point to the frame origin p gives v_p = v + w x (p - root_com).
    """
    angular, linear = cvel[:, :3], cvel[:, 3:]
    return linear + jnp.cross(angular, xpos - root_com), angular


def limb_observation(
    layout: ObservationLayout,
    qpos: jnp.ndarray,
    xpos: jnp.ndarray,
    xquat: jnp.ndarray,
    cvel: jnp.ndarray,
    root_com: jnp.ndarray,
    *,
    torso_relative_x: bool = True,
) -> jnp.ndarray:
    """Per-limb observation [n, 15 + T] of one body.

    Args:
        layout: the body's ObservationLayout.
        qpos: [nq] joint positions.
        xpos, xquat, cvel: [n, 3], [n, 4], [n, 6] of the limbs (MuJoCo bodies 1..n).
        root_com: [3] centre of mass of the torso's subtree (``subtree_com[1]``).
        torso_relative_x: subtract the torso's x from every limb (the paper's intent). False reproduces
            the original code, which subtracts the torso's x from the torso's position inside the
            simulator's memory before it reads anything else: the torso reads x = 0, every other limb
            its absolute world x, and the torso's linear velocity is that of the point (0, y, z) of its
            frame (v + w x (-x, 0, 0)).
    """
    qpos, xpos, xquat, cvel, root_com = map(jnp.asarray, (qpos, xpos, xquat, cvel, root_com))
    torso_x = xpos[0, 0]
    position = xpos.at[:, 0].add(-torso_x) if torso_relative_x else xpos.at[0, 0].set(0.0)
    linear, angular = frame_velocities(xpos if torso_relative_x else position, cvel, root_com)
    angle = jnp.degrees(qpos[layout.joint_qpos_address])
    low, high = layout.joint_range[:, 0], layout.joint_range[:, 1]
    scaled = jnp.where(layout.has_joint, (angle - low) / jnp.where(layout.has_joint, high - low, 1.0), 0.0)
    ends = jnp.where(layout.has_joint[:, None], (180.0 + layout.joint_range) / 360.0, 0.0)
    return jnp.concatenate(
        [
            position,
            jnp.clip(linear, -VELOCITY_CLIP, VELOCITY_CLIP),
            angular,
            exponential_map(xquat),
            layout.limb_type_one_hot,
            scaled[:, None],
            ends,
        ],
        axis=-1,
    )
