"""The benchmark's per-limb observation, as a pure function.

One row per limb, limbs in pre-order (limb i is MuJoCo body i + 1):

    0:3       world position of the limb's frame origin, torso x subtracted
    3:6       linear velocity of the frame origin, world axes, clipped to [-10, 10]
    6:9       angular velocity, world axes
    9:12      exponential map of the world orientation (axis * angle, angle in [0, pi])
    12:12+T   limb-type one-hot (all zeros for an untyped limb)
    12+T      joint angle scaled to [0, 1] over the joint range; 0 for the torso
    13+T:15+T joint range ends as (180 + degrees) / 360; 0 for the torso

Works on MJX data under jit and on MuJoCo C data arrays alike (inputs are plain arrays). Every function
takes the array namespace it computes in as ``xp``: NumPy by default, ``jax.numpy`` inside the environment.
The module imports no jax, so a controller without JAX builds the observation a policy file expects with
NumPy and MuJoCo alone (:func:`data_observation`, docs/evaluation-and-export.md).
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING, Any, NamedTuple

import mujoco
import numpy as np

if TYPE_CHECKING:  # the package of morphology/types.py imports jax, which this module does not need
    from swat_jax.morphology.types import Morphology

VELOCITY_CLIP = 10.0
KINEMATIC_FEATURES = 12
"""Position, linear velocity, angular velocity and orientation: the slots before the limb type."""
THREE_D_FEATURES = 36
"""The slots of a 3D limb's observation before its limb type (:func:`limb_observation_3d`)."""
DIRECTION_EPSILON = 1e-9
"""The direction to a target the torso stands on is 0, not NaN."""
ABSENT_JOINT = 0.5
"""What a 3D limb observes for the scaled angle and range ends of a hinge slot it does not have (the
torso's, in SGRL's observation)."""


def features_per_limb(num_limb_types: int) -> int:
    """F, the values of one limb's observation for a family of ``num_limb_types`` limb types: the kinematic
    slots, the limb type one-hot, and the scaled joint angle and range (3)."""
    return KINEMATIC_FEATURES + num_limb_types + 3


def body_features(morphology: Morphology) -> int:
    """F of ``morphology``'s observation: :func:`features_per_limb_3d` for a 3D family, else
    :func:`features_per_limb`."""
    types = morphology.family.num_limb_types
    return features_per_limb_3d(types) if morphology.family.three_d else features_per_limb(types)


def features_per_limb_3d(num_limb_types: int) -> int:
    """F of a 3D body (:func:`limb_observation_3d`): 36 slots, the limb type one-hot, and the height (41 for
    SGRL's four limb types)."""
    return THREE_D_FEATURES + num_limb_types + 1


class ObservationLayout(NamedTuple):
    """What a body's observation needs besides the simulator state (host-side constants).

    n = number of limbs, T = number of limb types of the family.
    """

    limb_type_one_hot: np.ndarray
    """[n, T] float32."""
    joint_qpos_address: np.ndarray
    """[n] int32 index into qpos of each limb's hinge ([n, M] in 3D, one per hinge slot); 0 where a limb
    has no hinge (masked)."""
    joint_range: np.ndarray
    """[n, 2] float32 joint range in degrees ([n, M, 2] in 3D); 0 where a limb has no hinge."""
    has_joint: np.ndarray
    """[n] bool, False for the torso ([n, M] in 3D: the limb has a hinge in this slot)."""
    joint_id: np.ndarray
    """[n] int32 MuJoCo joint index of each hinge ([n, M] in 3D); 0 where there is none (masked)."""

    @property
    def three_d(self) -> bool:
        return self.has_joint.ndim == 2

    @property
    def features(self) -> int:
        types = self.limb_type_one_hot.shape[1]
        return features_per_limb_3d(types) if self.three_d else features_per_limb(types)


def observation_layout(morphology: Morphology, model: mujoco.MjModel) -> ObservationLayout:
    """The layout of ``morphology``, compiled as ``model``: [n] per limb planar, [n, M] per hinge slot in 3D."""
    types = np.asarray(morphology.limb_types)
    one_hot = (types[:, None] == np.arange(morphology.family.num_limb_types)[None, :]).astype(np.float32)
    joints = np.zeros((morphology.num_limbs, morphology.motors_per_limb), np.int32)
    for limb, names in enumerate(morphology.joint_names):
        for slot, name in enumerate(names):
            joints[limb, slot] = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
    has_joint = morphology.motor_mask()
    if not morphology.family.three_d:
        joints, has_joint = joints[:, 0], has_joint[:, 0]
    return ObservationLayout(
        limb_type_one_hot=one_hot,
        joint_qpos_address=np.where(has_joint, model.jnt_qposadr[joints], 0).astype(np.int32),
        joint_range=layout_joint_range(morphology),
        has_joint=has_joint,
        joint_id=joints,
    )


def layout_joint_range(morphology: Morphology) -> np.ndarray:
    """The joint ranges an observation reads, float32 degrees: [n, 2] planar, [n, M, 2] in 3D."""
    ranges = morphology.joint_range_array()
    return ranges if morphology.family.three_d else ranges[:, 0]


def exponential_map(quaternion: Any, xp: ModuleType = np) -> Any:
    """Rotation vector (axis * angle, angle folded into [0, pi]) of unit quaternions [..., 4] (w, x, y, z)."""
    q = xp.where(quaternion[..., :1] < 0, -quaternion, quaternion)
    vector = q[..., 1:]
    sine = xp.linalg.norm(vector, axis=-1, keepdims=True)
    angle = 2.0 * xp.arctan2(sine, q[..., :1])
    safe = xp.where(sine > 1e-12, sine, 1.0)
    return xp.where(sine > 1e-12, vector / safe * angle, 0.0)


def frame_velocities(xpos: Any, cvel: Any, root_com: Any, xp: ModuleType = np) -> tuple[Any, Any]:
    """Linear and angular velocity [n, 3] of each frame origin, world axes, from MuJoCo's com-based cvel.

    cvel [n, 6] is (angular, linear) at the root subtree's centre of mass ``root_com`` [3]; moving the
    reference point to the frame origin p gives v_p = v + w x (p - root_com).
    """
    angular, linear = cvel[:, :3], cvel[:, 3:]
    return linear + xp.cross(angular, xpos - root_com), angular


def data_observation(
    layout: ObservationLayout,
    data: Any,
    *,
    torso_relative_x: bool = True,
    target: Any = None,
    gravity: Any = None,
    xp: ModuleType = np,
) -> Any:
    """[n, F] float32: the observation of a body from its simulator state (:func:`limb_observation`, or
    :func:`limb_observation_3d` for a 3D layout).

    Args:
        layout: the body's ObservationLayout.
        data: anything with MuJoCo's ``qpos``, ``xpos``, ``xquat``, ``cvel``, ``subtree_com`` and ``xaxis``
            fields: a ``mujoco.MjData`` after ``mujoco.mj_forward``, MJX data, C physics data.
        torso_relative_x: as :func:`limb_observation` (planar bodies).
        target: [2] the target point (3D bodies).
        gravity: [3] the model's gravity (3D bodies).
        xp: the array namespace (NumPy, or ``jax.numpy``).
    """
    limbs = slice(1, layout.has_joint.shape[0] + 1)
    if layout.three_d:
        arrays = (data.qpos, data.xpos[limbs], data.cvel[limbs], data.subtree_com[1], data.xaxis)
        observation = limb_observation_3d(layout, *arrays, target, gravity, xp=xp)
    else:
        arrays = (data.qpos, data.xpos[limbs], data.xquat[limbs], data.cvel[limbs], data.subtree_com[1])
        observation = limb_observation(layout, *arrays, torso_relative_x=torso_relative_x, xp=xp)
    return observation.astype(xp.float32)


def _updated(array: Any, index: Any, value: Any) -> Any:
    """``array`` with ``array[index] = value``, ``array`` left as it is: JAX's functional update for a jax
    array, a copy for a NumPy one."""
    if hasattr(array, "at"):
        return array.at[index].set(value)
    updated = np.array(array, copy=True)
    updated[index] = value
    return updated


def limb_observation(
    layout: ObservationLayout,
    qpos: Any,
    xpos: Any,
    xquat: Any,
    cvel: Any,
    root_com: Any,
    *,
    torso_relative_x: bool = True,
    xp: ModuleType = np,
) -> Any:
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
        xp: the array namespace (NumPy, or ``jax.numpy``).
    """
    qpos, xpos, xquat, cvel, root_com = (xp.asarray(array) for array in (qpos, xpos, xquat, cvel, root_com))
    torso_x = xpos[0, 0]
    position = (
        _updated(xpos, (slice(None), 0), xpos[:, 0] - torso_x)
        if torso_relative_x
        else _updated(xpos, (0, 0), 0.0)
    )
    linear, angular = frame_velocities(xpos if torso_relative_x else position, cvel, root_com, xp)
    angle = xp.degrees(qpos[layout.joint_qpos_address])
    low, high = layout.joint_range[:, 0], layout.joint_range[:, 1]
    scaled = xp.where(layout.has_joint, (angle - low) / xp.where(layout.has_joint, high - low, 1.0), 0.0)
    ends = xp.where(layout.has_joint[:, None], (180.0 + layout.joint_range) / 360.0, 0.0)
    return xp.concatenate(
        [
            position,
            xp.clip(linear, -VELOCITY_CLIP, VELOCITY_CLIP),
            angular,
            exponential_map(xquat, xp),
            layout.limb_type_one_hot,
            scaled[:, None],
            ends,
        ],
        axis=-1,
    )


def limb_observation_3d(
    layout: ObservationLayout,
    qpos: Any,
    xpos: Any,
    cvel: Any,
    root_com: Any,
    joint_axes: Any,
    target: Any,
    gravity: Any,
    xp: ModuleType = np,
) -> Any:
    """Per-limb observation [n, 37 + T] of one 3D body (SGRL's, 41 values for T = 4):

        0:3    world position of the limb's frame origin minus the torso's
        3:6    gravity (0, 0, -9.81)
        6:9    unit direction from the torso to the target, in the floor plane (x, y, 0)
        9:12   linear velocity of the frame origin, world axes, clipped to [-10, 10]
        12:15  angular velocity, world axes
        15:24  world axis of the limb's x, y and z hinges (0 where it has none)
        24:27  the three hinge angles, radians (0 where none)
        27:36  per hinge: the angle scaled to [0, 1] over its range, and the range ends as
               (180 + degrees) / 360 (0.5, 0.5, 0.5 where none)
        36:36+T  limb-type one-hot
        36+T   height of the frame origin

    Args:
        layout: the body's 3D ObservationLayout ([n, M] joint fields).
        qpos: [nq] joint positions.
        xpos, cvel: [n, 3], [n, 6] of the limbs (MuJoCo bodies 1..n).
        root_com: [3] centre of mass of the torso's subtree.
        joint_axes: [njnt, 3] world axes of every joint (MuJoCo's ``xaxis``).
        target: [2] the target point (x, y).
        gravity: [3] the model's gravity.
        xp: the array namespace (NumPy, or ``jax.numpy``).
    """
    qpos, xpos, cvel, root_com, joint_axes, target = (
        xp.asarray(array) for array in (qpos, xpos, cvel, root_com, joint_axes, target)
    )
    n = xpos.shape[0]
    linear, angular = frame_velocities(xpos, cvel, root_com, xp)
    direction = heading_to_target(xpos[0, :2], target, xp)
    axes, angle, joint = hinge_slots_3d(layout, qpos, joint_axes, xp)
    return xp.concatenate(
        [
            xpos - xpos[0],
            xp.broadcast_to(xp.asarray(gravity, xpos.dtype), (n, 3)),
            xp.broadcast_to(xp.concatenate([direction, xp.zeros(1, xpos.dtype)]), (n, 3)),
            xp.clip(linear, -VELOCITY_CLIP, VELOCITY_CLIP),
            angular,
            axes.reshape(n, -1),
            angle,
            joint.reshape(n, -1),
            layout.limb_type_one_hot,
            xpos[:, 2:],
        ],
        axis=-1,
    )


def heading_to_target(torso: Any, target: Any, xp: ModuleType = np) -> Any:
    """[2] the unit direction in the floor plane from the torso's (x, y) ``torso`` [2] to ``target`` [2]; 0
    where the torso stands on it."""
    direction = target - torso
    return direction / xp.maximum(xp.linalg.norm(direction), DIRECTION_EPSILON)


def hinge_slots_3d(
    layout: ObservationLayout, qpos: Any, joint_axes: Any, xp: ModuleType = np
) -> tuple[Any, Any, Any]:
    """What a 3D limb observes of its M hinge slots (:func:`limb_observation_3d`): the world axes [n, M, 3]
    (0 where a slot has no hinge), the angles [n, M] in radians (0 where none), and per slot the angle
    scaled to [0, 1] over its range and the range ends as (180 + degrees) / 360 [n, M, 3] (ABSENT_JOINT
    where none)."""
    has = layout.has_joint
    angle = xp.where(has, qpos[layout.joint_qpos_address], 0.0)
    low, high = layout.joint_range[..., 0], layout.joint_range[..., 1]
    scaled = (xp.degrees(angle) - low) / xp.where(has, high - low, 1.0)
    joint = xp.stack([scaled, (180.0 + low) / 360.0, (180.0 + high) / 360.0], axis=-1)
    joint = xp.where(has[..., None], joint, ABSENT_JOINT)
    axes = xp.where(has[..., None], joint_axes[layout.joint_id], 0.0)
    return axes, angle, joint
