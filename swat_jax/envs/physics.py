"""Physics on MJX: :class:`Simulator` holds one body's model and steps it on MJX's JAX or Warp implementation
(MuJoCo's C library is :mod:`swat_jax.envs.c_physics`, with the same interface).

JAX (the default) compiles the whole physics into the XLA program. Its step, with ``integrator="RK4"``,
is :func:`rk4_step`, which compiles a third as long as ``mjx.step``'s:

``mjx.step`` with ``integrator="RK4"`` traces ``mjx.forward`` four times (once before the integrator
and once per unrolled stage), and XLA compile time grows with each copy: 13 s per body on a 2-core CPU.
:func:`rk4_step` computes the same classic RK4 step (MuJoCo's tableau: stages at 0, dt/2, dt/2, dt with
weights 1/6, 1/3, 1/3, 1/6) as a ``lax.scan`` over the four stages, so ``forward`` is traced once.
It relies on every joint being a hinge or a slide (qpos integrates linearly), which holds for every
planar body :func:`swat_jax.morphology.load` accepts; a 3D body's free torso (a quaternion) steps with
``mjx.step`` (:func:`physics_step`).

Warp (``physics="warp"``, needs ``pip install -e '.[warp]'``) runs MuJoCo Warp's kernels as foreign
function calls: XLA compiles a few calls per body instead of the physics, and Warp compiles its kernels
once per machine, for every body (its kernel cache, ``~/.cache/warp``). Its integrator is Warp's own
RK4. A Warp state keeps its contacts in buffers that all the simulations of one call share (sized for
``worlds`` of them), which MJX leaves out of ``vmap``'s batch axes; carried in a state, they would break
its per-copy array operations (concatenation, selection) and repeat across states. The states this
class returns hold empty placeholders there instead, and :meth:`Simulator.advance` and
:meth:`Simulator.derive` put the buffers back for the duration of their call.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from swat_jax.envs.quiet_mjx import mjx

Implementation = Literal["jax", "warp", "c"]
"""Where a body's physics runs: MJX's JAX implementation (compiled into the XLA program), MJX's Warp
implementation (MuJoCo Warp kernels called from it), or MuJoCo's C library through a host callback
(:mod:`swat_jax.envs.c_physics`)."""
IMPLEMENTATIONS: tuple[Implementation, ...] = ("jax", "warp", "c")
Physics = Literal["auto", "jax", "warp", "c"]
"""An implementation, or ``auto``: :func:`resolve_physics` picks one for the machine."""
PHYSICS: tuple[Physics, ...] = ("auto", *IMPLEMENTATIONS)


def resolve_physics(physics: Physics) -> Implementation:
    """``physics`` itself, or for ``auto``: ``c`` where JAX's default backend is the CPU (MuJoCo C steps
    there many times faster than MJX and compiles nothing), ``jax`` where it is an accelerator (MJX steps
    thousands of copies in parallel there).

    Raises:
        ValueError: not one of :data:`PHYSICS`; or ``c`` where JAX's default backend is not the CPU (C
            physics is a host function of CPU programs, :mod:`swat_jax.envs.named_callback`).
    """
    if physics not in PHYSICS:
        raise ValueError(f"physics must be one of {', '.join(PHYSICS)}, got {physics!r}")
    if physics in ("jax", "warp"):
        return physics
    backend = jax.default_backend()
    if physics == "c" and backend != "cpu":
        raise ValueError(
            f"physics 'c' runs MuJoCo C from programs on the CPU, and JAX's default backend here is "
            f"{backend!r}: use physics 'jax' or 'auto' (MJX on the {backend}), or JAX_PLATFORMS=cpu"
        )
    return "c" if backend == "cpu" else "jax"


RK4_NEXT_OFFSETS = np.array([0.5, 0.5, 1.0, 0.0])
"""Fraction of dt at which the next stage evaluates the derivative, from this stage's derivative (the first
stage evaluates it at the step's start; the last entry is unused)."""
RK4_WEIGHTS = (1 / 6, 1 / 3, 1 / 3, 1 / 6)
"""Weight of each stage's derivative in the step."""


def rk4_step(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """Advance ``data`` by one timestep with RK4; only hinge and slide joints (nq == nv).

    The stage scan carries nothing but ``data``, and each stage's derivative is a scan output: a carry
    that starts as a constant (zeros) is batched only after a first pass, so ``vmap`` would batch
    ``mjx.forward`` twice per batch axis (a quarter of the training iteration's tracing).
    """
    dt = model.opt.timestep
    qpos0, qvel0, time0 = data.qpos, data.qvel, data.time

    def stage(data, next_offset):
        data = mjx.forward(model, data)
        velocity, acceleration = data.qvel, data.qacc
        data = data.replace(
            qpos=qpos0 + next_offset * dt * velocity,
            qvel=qvel0 + next_offset * dt * acceleration,
            time=time0 + next_offset * dt,
        )
        return data, (velocity, acceleration)

    data, (velocities, accelerations) = jax.lax.scan(stage, data, jnp.asarray(RK4_NEXT_OFFSETS, qvel0.dtype))
    return data.replace(
        qpos=qpos0 + dt * _weighted_sum(velocities),
        qvel=qvel0 + dt * _weighted_sum(accelerations),
        time=time0 + dt,
        qacc_warmstart=data.qacc,
    )


def _weighted_sum(derivatives: jax.Array) -> jax.Array:
    """sum_k RK4_WEIGHTS[k] * derivatives[k] over the stage axis [4, nv], added in stage order."""
    total = RK4_WEIGHTS[0] * derivatives[0]
    for weight, derivative in zip(RK4_WEIGHTS[1:], derivatives[1:], strict=True):
        total = total + weight * derivative
    return total


def physics_step(mj_model: mujoco.MjModel) -> Callable[[mjx.Model, mjx.Data], mjx.Data]:
    """The single-timestep function for ``mj_model``: :func:`rk4_step` for RK4 models of hinges and slides
    only, else ``mjx.step`` (other integrators, and free or ball joints, whose quaternions it integrates)."""
    linear = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    if mj_model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4 or not np.all(
        np.isin(mj_model.jnt_type, linear)
    ):
        return mjx.step
    return rk4_step


ModelFields = Mapping[str, jax.Array]
"""Some leaves of an ``mjx.Model``, by their key path (``jax.tree_util.keystr``): one variant's values of
the fields in which variants of a body differ (:func:`differing_fields`)."""


def differing_fields(mj_models: Sequence[mujoco.MjModel]) -> dict[str, np.ndarray]:
    """The ``mjx.Model`` leaves in which models of one topology differ, each stacked over the models:
    ``{key path: [k, ...]}``. Leaves equal in every model are left out (they stay constants of a program).

    Raises:
        ValueError: the models differ in structure (another tree of bodies, joints or geoms), which only
            separate programs can step.
    """
    models = [mjx.put_model(model) for model in mj_models]
    if all(model.nhfield == 0 for model in mj_models):
        # A static (trace-time NumPy) copy of geom_rbound that only height-field collisions read.
        nominal = models[0]._impl.geom_rbound_hfield
        models = [model.replace(_impl=model._impl.replace(geom_rbound_hfield=nominal)) for model in models]
    flat = [jax.tree_util.tree_flatten_with_path(model) for model in models]
    treedef = flat[0][1]
    for index, (_, other) in enumerate(flat[1:], start=1):
        if other != treedef:
            raise ValueError(
                f"model {index} has another structure than model 0 (its sizes, static options or the numbers "
                "MJX reads while tracing differ); variants of one body share a topology, so stack only those"
            )
    stacked = {}
    for position, (path, _) in enumerate(flat[0][0]):
        values = [np.asarray(leaves[position][1]) for leaves, _ in flat]
        if any(
            value.shape != values[0].shape or not np.array_equal(value, values[0]) for value in values[1:]
        ):
            stacked[jax.tree_util.keystr(path)] = np.stack(values)
    return stacked


def with_fields(model: mjx.Model, fields: ModelFields) -> mjx.Model:
    """``model`` with the leaves named in ``fields`` replaced (one variant's values)."""
    if not fields:
        return model
    return jax.tree_util.tree_map_with_path(
        lambda path, leaf: fields.get(jax.tree_util.keystr(path), leaf), model
    )


class Simulator:
    """One MuJoCo model on MJX: device model, initial state and the advance / derive functions.

    Args:
        mj_model: the compiled MuJoCo model.
        implementation: "jax" (XLA) or "warp" (MuJoCo Warp kernels).
        worlds: Warp only: the most simulations one call of :meth:`advance` or :meth:`derive` runs, all
            ``vmap`` axes together (copies x seeds); the shared contact buffer holds, for each of them,
            as many contacts as MJX's JAX implementation allocates per simulation.

    Raises:
        ValueError: an unknown implementation, or ``worlds`` < 1.
        ImportError: "warp" without warp-lang installed.
    """

    def __init__(self, mj_model: mujoco.MjModel, implementation: Implementation = "jax", worlds: int = 1):
        if implementation not in ("jax", "warp"):
            raise ValueError(f"MJX runs physics 'jax' or 'warp', got {implementation!r}")
        if worlds < 1:
            raise ValueError(f"worlds must be at least 1, got {worlds}")
        self.implementation = implementation
        if implementation == "jax":
            self.model: mjx.Model = mjx.put_model(mj_model)
            self.initial: mjx.Data = mjx.make_data(self.model)
            self._step = physics_step(mj_model)
            self._buffers: dict[str, jax.Array] = {}
            return
        _quiet_warp()
        per_world = mjx.make_data(mj_model)
        data = mjx.make_data(
            mj_model,
            impl="warp",
            naconmax=max(1, per_world._impl.contact.dist.shape[0] * worlds),
            njmax=max(1, per_world._impl.efc_J.shape[0]),
        )
        self.model = mjx.put_model(mj_model, impl="warp")
        self._step = mjx.step
        self._buffers = {name: getattr(data._impl, name) for name in _shared_warp_buffers(data)}
        self.initial = self._detach(data)

    def advance(self, data: mjx.Data, steps: int, fields: ModelFields | None = None) -> mjx.Data:
        """``steps`` physics steps from ``data`` (its ctrl applied); derived quantities not recomputed.
        ``fields``: a variant's model fields (:func:`with_fields`), inputs of the program, not constants."""
        model = self.model_with(fields)
        data = jax.lax.fori_loop(0, steps, lambda _, d: self._step(model, d), self._attach(data))
        return self._detach(data)

    def derive(self, data: mjx.Data, fields: ModelFields | None = None) -> mjx.Data:
        """Positions, orientations, sites and frame velocities (``cvel``) computed from qpos and qvel.

        Warp has no ``com_vel`` of its own in mujoco-mjx 3.17: there a whole ``forward`` computes them.
        """
        model = self.model_with(fields)
        if self.implementation == "jax":
            return mjx.com_vel(model, mjx.com_pos(model, mjx.kinematics(model, data)))
        return self._detach(mjx.forward(model, self._attach(data)))

    def velocities(self, data: mjx.Data, fields: ModelFields | None = None) -> mjx.Data:
        """Frame velocities (``cvel``) of ``data``'s qvel at the positions its derived fields hold (JAX only):
        after :meth:`advance`, those the last physics step left, i.e. the Jacobians of that step's last
        ``forward`` (the previous state for Euler, :func:`rk4_step`'s last stage) times the new qvel."""
        return mjx.com_vel(self.model_with(fields), data)

    def qpos0(self, fields: ModelFields | None = None) -> jax.Array:
        """[nq] reference pose of the body (of a variant with ``fields``)."""
        return self.model_with(fields).qpos0

    def model_with(self, fields: ModelFields | None) -> mjx.Model:
        """The device model, with a variant's ``fields`` in place of the nominal values (JAX only)."""
        if fields and self.implementation != "jax":
            raise ValueError(
                "variants of a body run on physics='jax'; MuJoCo Warp's model is not an input here"
            )
        return with_fields(self.model, fields or {})

    def _attach(self, data: mjx.Data) -> mjx.Data:
        """``data`` with the shared Warp buffers in place of its placeholders (unbatched under vmap)."""
        if not self._buffers:
            return data
        return data.replace(_impl=data._impl.replace(**self._buffers))

    def _detach(self, data: mjx.Data) -> mjx.Data:
        """``data`` with empty placeholders [0, ...] for the shared Warp buffers."""
        if not self._buffers:
            return data
        empty = {name: jnp.zeros((0, *value.shape[1:]), value.dtype) for name, value in self._buffers.items()}
        return data.replace(_impl=data._impl.replace(**empty))


def _shared_warp_buffers(data: mjx.Data) -> list[str]:
    """Names of the Warp state's arrays shared by every simulation of a call (no per-world axis)."""
    from mujoco.mjx.warp import types as warp_types

    batched = warp_types._BATCH_DIM["Data"]
    return [
        name
        for name, value in vars(data._impl).items()
        if not batched.get(name, True) and isinstance(value, jax.Array | np.ndarray) and np.ndim(value) > 0
    ]


def _quiet_warp() -> None:
    """Import warp-lang (ImportError naming the fix); keep its greeting and kernel builds off stdout."""
    try:
        import warp
    except ImportError as error:
        raise ImportError(
            "physics='warp' needs warp-lang: pip install -e '.[warp]' (or pip install warp-lang==1.18.0)"
        ) from error
    warp.config.log_level = warp.LOG_WARNING
