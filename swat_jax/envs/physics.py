"""One physics step on MJX, with a Runge-Kutta 4 integrator that compiles a third as long as ``mjx.step``'s.

``mjx.step`` with ``integrator="RK4"`` traces ``mjx.forward`` four times (once before the integrator
and once per unrolled stage), and XLA compile time grows with each copy: 13 s per body on a 2-core CPU.
:func:`rk4_step` computes the same classic RK4 step (MuJoCo's tableau: stages at 0, dt/2, dt/2, dt with
weights 1/6, 1/3, 1/3, 1/6) as a ``lax.scan`` over the four stages, so ``forward`` is traced once.
It relies on every joint being a hinge or a slide (qpos integrates linearly), which holds for every
body :func:`swat_jax.morphology.load` accepts; :func:`physics_step` checks it.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from swat_jax.envs.quiet_mjx import mjx

RK4_STAGE_OFFSETS = np.array([0.0, 0.5, 0.5, 1.0])
"""Fraction of dt at which stage i evaluates the derivative, from the previous stage's derivative."""
RK4_WEIGHTS = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
"""Weight of each stage's derivative in the step."""


def rk4_step(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """Advance ``data`` by one timestep with RK4; only hinge and slide joints (nq == nv)."""
    dt = model.opt.timestep
    qpos0, qvel0, time0 = data.qpos, data.qvel, data.time

    def stage(carry, coefficients):
        data, velocity, acceleration, velocity_sum, acceleration_sum = carry
        offset, weight = coefficients
        data = data.replace(
            qpos=qpos0 + offset * dt * velocity,
            qvel=qvel0 + offset * dt * acceleration,
            time=time0 + offset * dt,
        )
        data = mjx.forward(model, data)
        velocity, acceleration = data.qvel, data.qacc
        return (
            data,
            velocity,
            acceleration,
            velocity_sum + weight * velocity,
            acceleration_sum + weight * acceleration,
        ), None

    zeros = jnp.zeros_like(qvel0)
    (data, _, _, velocity_sum, acceleration_sum), _ = jax.lax.scan(
        stage,
        (data, zeros, zeros, zeros, zeros),
        (jnp.asarray(RK4_STAGE_OFFSETS, qvel0.dtype), jnp.asarray(RK4_WEIGHTS, qvel0.dtype)),
    )
    return data.replace(
        qpos=qpos0 + dt * velocity_sum,
        qvel=qvel0 + dt * acceleration_sum,
        time=time0 + dt,
        qacc_warmstart=data.qacc,
    )


def physics_step(mj_model: mujoco.MjModel) -> Callable[[mjx.Model, mjx.Data], mjx.Data]:
    """The single-timestep function for ``mj_model``'s integrator: :func:`rk4_step` or ``mjx.step``.

    Raises:
        ValueError: an RK4 model has a free or ball joint (its qpos would not integrate linearly).
    """
    if mj_model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4:
        return mjx.step
    linear = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    if not np.all(np.isin(mj_model.jnt_type, linear)):
        raise ValueError("rk4_step supports hinge and slide joints only; this model has a free or ball joint")
    return rk4_step
