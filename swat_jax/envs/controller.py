"""A body's environment step outside JAX: what a controller on MuJoCo C needs to act as the environment does.

:class:`BodyInterface` holds, for one body, the constants that turn a ``mujoco.MjData`` into the
observation a policy reads and a policy's actions into the body's controls: the ObservationLayout, the
action that drives each actuator, the gravity a 3D observation reads, the frame skip, and the two
observation switches the run trained with. The functions act as :class:`~swat_jax.envs.body.BodyEnv`
does on C physics (``physics="c"``), with NumPy and MuJoCo alone; this module imports no jax, and
exported policy files carry each body's interface (:mod:`swat_jax.policy_files`), so a control loop runs
with onnxruntime, NumPy and MuJoCo (docs/evaluation-and-export.md, "A control loop without JAX").
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Any, NamedTuple

import mujoco
import numpy as np

from swat_jax.envs.observation import ObservationLayout, data_observation, observation_layout

if TYPE_CHECKING:  # the package of morphology/types.py imports jax, which this module does not need
    from swat_jax.morphology.types import Morphology


class BodyInterface(NamedTuple):
    """One body's constants for a controller (n limbs, nu actuators)."""

    layout: ObservationLayout
    motor_actions: np.ndarray
    """[nu] int32: the entry of the flattened action ([n] or [n, M]) that drives each actuator."""
    gravity: np.ndarray
    """[3] float32, the model's gravity (a 3D observation reads it)."""
    frame_skip: int
    """Physics steps per environment step."""
    torso_relative_x: bool
    """The observation switch of :func:`~swat_jax.envs.observation.limb_observation` the run trained with."""
    stale_kinematics: bool
    """Whether a step's observation reads the kinematics ``mj_step`` leaves (the original code's reads,
    :meth:`~swat_jax.envs.body.BodyEnv.step_kinematics`) or those of the new state."""


def body_interface(
    morphology: Morphology, model: mujoco.MjModel, *, torso_relative_x: bool, stale_kinematics: bool
) -> BodyInterface:
    """The interface of ``morphology`` compiled as ``model``, for a run with the given observation switches."""
    return BodyInterface(
        layout=observation_layout(morphology, model),
        motor_actions=motor_actions(morphology, model.nu),
        gravity=np.asarray(model.opt.gravity, np.float32),
        frame_skip=morphology.frame_skip,
        torso_relative_x=torso_relative_x,
        stale_kinematics=stale_kinematics,
    )


def motor_actions(morphology: Morphology, num_motors: int) -> np.ndarray:
    """[nu] int32: the entry of the flattened action ([n] or [n, M]) that drives each actuator (inverse of
    ``limb_motors``; load() has checked that every actuator drives exactly one limb's hinge)."""
    actions = np.full(num_motors, -1, np.int32)
    for limb, motors in enumerate(morphology.limb_motors):
        for slot, motor in enumerate(motors):
            actions[motor] = limb * morphology.motors_per_limb + slot
    return actions


def controls(motor_actions: np.ndarray, action: Any, xp: Any = np) -> Any:
    """[nu] the actuators' controls for one body's ``action`` ([n] or [n, M], or padded to more limbs): each
    actuator's entry of the flattened action, clipped to [-1, 1]."""
    return xp.clip(xp.ravel(action)[motor_actions], -1.0, 1.0)


def model_digest(mj_model: mujoco.MjModel) -> str:
    """SHA-256 of ``mj_model`` saved as MuJoCo's binary MJB: every size, parameter and asset."""
    buffer = np.zeros(mujoco.mj_sizeModel(mj_model), np.uint8)
    mujoco.mj_saveModel(mj_model, None, buffer)
    return hashlib.sha256(buffer).hexdigest()


def derive_kinematics(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Positions, orientations, sites and frame velocities of ``data``'s qpos and qvel, in place."""
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_comVel(model, data)


def simulate(interface: BodyInterface, model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """One environment step of ``data`` under its ``ctrl``, in place: ``frame_skip`` calls of ``mj_step``,
    then the kinematics the step's observation reads (the frame velocities of the new qvel at the positions
    ``mj_step`` left, with stale kinematics; those of the new state otherwise)."""
    mujoco.mj_step(model, data, nstep=interface.frame_skip)
    if interface.stale_kinematics:
        mujoco.mj_comVel(model, data)
    else:
        derive_kinematics(model, data)


def observe(interface: BodyInterface, data: mujoco.MjData, target: Any = None) -> np.ndarray:
    """[n, F] float32, the body's observation of ``data`` (after :func:`simulate`, or after
    ``mujoco.mj_forward`` at an episode's start); ``target`` [2] is the point a 3D body walks to."""
    if interface.layout.three_d and target is None:
        raise ValueError("a 3D body observes the direction to its target: pass target=[x, y]")
    return data_observation(
        interface.layout,
        data,
        torso_relative_x=interface.torso_relative_x,
        target=None if target is None else np.asarray(target, np.float64),
        gravity=interface.gravity,
    )


ARRAY_FIELDS = (*ObservationLayout._fields, "motor_actions", "gravity")
"""The array fields of :func:`interface_arrays`."""


def interface_arrays(interface: BodyInterface) -> dict[str, Any]:
    """``interface`` as flat fields: the arrays of :data:`ARRAY_FIELDS`, then ``frame_skip`` and the switches
    (what :func:`interface_from_arrays` reads)."""
    return {
        **interface.layout._asdict(),
        "motor_actions": interface.motor_actions,
        "gravity": interface.gravity,
        "frame_skip": interface.frame_skip,
        "torso_relative_x": interface.torso_relative_x,
        "stale_kinematics": interface.stale_kinematics,
    }


def interface_from_arrays(fields: dict[str, Any]) -> BodyInterface:
    """The interface :func:`interface_arrays` flattened; KeyError names a missing field."""
    layout = ObservationLayout(*(np.asarray(fields[name]) for name in ObservationLayout._fields))
    return BodyInterface(
        layout=layout,
        motor_actions=np.asarray(fields["motor_actions"]),
        gravity=np.asarray(fields["gravity"]),
        frame_skip=int(fields["frame_skip"]),
        torso_relative_x=bool(fields["torso_relative_x"]),
        stale_kinematics=bool(fields["stale_kinematics"]),
    )
