"""Physics on MuJoCo's C library, called from inside the jitted program: :class:`CSimulator`.

MJX compiles a body's physics into the XLA program, which on a CPU steps at a few percent of MuJoCo C's
rate and compiles for tens of seconds per body. ``physics="c"`` traces no physics at all: each call of
:meth:`CSimulator.advance` or :meth:`CSimulator.derive` is one call of the host function :data:`TARGET`
(:mod:`swat_jax.envs.named_callback`) that receives every copy of every seed at once (the vmapped axes
arrive as leading axes of its arguments) and computes them with ``mujoco.mj_step`` and MuJoCo's
kinematics on a thread pool (MuJoCo releases the GIL while it computes). Policy, replay and updates stay
one compiled program around it, and the simulator state stays arrays (:class:`CData`), so checkpoints,
exact resume, seeds, variants and sharding work as on MJX.

The program names its simulator by :attr:`CSimulator.key`, a digest of what the simulator computes (its
models, derived fields and device layout), not by a reference to this process's object: JAX's persistent
cache and the program cache keep C-physics programs, and a later process that builds the same simulator
loads them instead of compiling them again.

Precision: MuJoCo C computes in float64, which JAX holds only with ``jax_enable_x64``. :class:`CData`
keeps each float64 state value as its float32 rounding (``qpos``, ``qvel``, ``act``, ``qacc_warmstart``,
which the environment reads) plus two float32 remainders (``remainder``: 3 x 24 bits hold float64's 53),
and the callback adds them back, so the state passes between environment steps exactly and an
environment on C physics follows ``mujoco.mj_step`` alone bit for bit (for values above 1e-24 in
magnitude; below, the remainders underflow float32).

Stale kinematics (``BodyEnv(stale_kinematics=True)``, the original code's reads) are what ``mj_step``
leaves: :meth:`CSimulator.advance` returns the positions, orientations and sites of the step's last
integrator stage, with frame velocities (``mj_comVel``) of the new qvel at those positions.

Devices and hosts: given a device mesh (:class:`PhysicsShards`), each call runs under ``jax.shard_map``:
every device calls MuJoCo for its own block of the copies (the caller vmaps over the copies with the mesh's
axes as ``spmd_axis_name``, as :class:`~swat_jax.envs.multi_task.MultiTaskEnv` does), on its own share
of the threads, and every host for its own devices. The blocks run at the same time (MuJoCo releases the
GIL), and no simulator state travels to one device and back. Without a mesh, the call is one callback on
the first device.

Instability: a copy whose qvel leaves ``[-EXPLOSION_SPEED, EXPLOSION_SPEED]`` or stops being finite
stops stepping and is returned with NaN qpos and qvel, which the environment terminates as it does an
MJX state that exploded (MJX steps the remaining physics steps of that environment step first). The
check runs before MuJoCo's own (at 1e10), so MuJoCo neither resets the copy nor prints its warning.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import math
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from jax.sharding import Mesh, PartitionSpec

from swat_jax.envs import named_callback
from swat_jax.envs.controller import derive_kinematics, model_digest

EXPLOSION_SPEED = 1e3
"""A joint speed (m/s or rad/s) no benchmark body reaches; above it the simulation counts as unstable."""
STATE = (
    mujoco.mjtState.mjSTATE_QPOS
    | mujoco.mjtState.mjSTATE_QVEL
    | mujoco.mjtState.mjSTATE_ACT
    | mujoco.mjtState.mjSTATE_WARMSTART
)
"""The MuJoCo state (``mj_getState`` / ``mj_setState``) a :class:`CData` carries, in this order: what
``mj_step`` reads besides the controls (no body here has mocap bodies, user data or applied forces)."""
POSITION = mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL
"""The part of :data:`STATE` the kinematics read."""
DERIVED = ("xpos", "xquat", "cvel", "subtree_com", "site_xpos")
"""The derived fields of ``MjData`` a :class:`CData` holds: what the environment's observation and
termination read (3D bodies also ``xaxis``, :data:`JOINT_AXES`)."""
JOINT_AXES = "xaxis"
"""The derived field a 3D body's observation reads besides :data:`DERIVED`: the world axis of every joint."""
TARGET = "swat_jax_c_physics"
"""The name under which programs call C physics (:func:`_host_target`)."""


@struct.dataclass
class CData:
    """The simulator state of one copy on C physics (leading axes when vmapped or stacked): the MuJoCo
    state in float32 with its float64 remainder, the controls, and the derived fields the environment
    reads. The field names are ``mjx.Data``'s, so the environment reads either."""

    qpos: jax.Array
    """[nq] float32 joint positions (the float64 state's rounding)."""
    qvel: jax.Array
    """[nv] float32 joint velocities."""
    act: jax.Array
    """[na] float32 actuator activations."""
    qacc_warmstart: jax.Array
    """[nv] float32 accelerations that warm-start the constraint solver."""
    remainder: jax.Array
    """[2 S] float32, S = nq + nv + na + nv: the float64 state (in :data:`STATE` order) minus its float32
    rounding, as a float32 rounding and what that leaves (zero for a state set in float32, as a reset)."""
    ctrl: jax.Array
    """[nu] float32 controls of the last step."""
    xpos: jax.Array
    """[nbody, 3] float32 body positions."""
    xquat: jax.Array
    """[nbody, 4] float32 body orientations."""
    cvel: jax.Array
    """[nbody, 6] float32 frame velocities (rotation, translation) at the centre of mass of the tree."""
    subtree_com: jax.Array
    """[nbody, 3] float32 centres of mass of each body's subtree."""
    site_xpos: jax.Array
    """[nsite, 3] float32 site positions."""
    xaxis: jax.Array | None = None
    """[njnt, 3] float32 world joint axes (3D bodies; None for a planar body, which does not read them)."""

    def where(self, done: jax.Array, other: CData) -> CData:
        """``other`` where ``done`` (a scalar inside ``vmap``), else this state (``mjx.Data.where``'s
        contract)."""
        return jax.tree_util.tree_map(lambda new, old: jnp.where(done, new, old), other, self)


@dataclasses.dataclass(frozen=True)
class PhysicsShards:
    """The device mesh a run's C physics calls split over: shard i (``jax.lax.axis_index`` over every axis
    of the mesh, row-major) is device ``mesh.devices.flat[i]``, and steps the i-th block of the copies."""

    mesh: Mesh

    @property
    def axes(self) -> tuple[str, ...]:
        """Every axis of the mesh: the copies split over all of them (``vmap``'s ``spmd_axis_name``)."""
        return tuple(self.mesh.axis_names)

    @property
    def size(self) -> int:
        """Shards: the mesh's devices."""
        return int(self.mesh.devices.size)

    def local(self) -> dict[int, int]:
        """{shard: its place among this process's devices of the mesh}: the shards whose calls this
        process (host) makes."""
        mine = [i for i, d in enumerate(self.mesh.devices.flat) if d.process_index == jax.process_index()]
        return {shard: place for place, shard in enumerate(mine)}

    def call(
        self, function: Callable[..., tuple[jax.Array, ...]], *inputs: jax.Array
    ) -> tuple[jax.Array, ...]:
        """``function(shard [] int32, *inputs)`` on every device, each with its own block of the inputs'
        vmapped axis (inside ``vmap(..., spmd_axis_name=self.axes)``; outside one, every device the
        whole inputs)."""
        spec = PartitionSpec()

        def per_device(*block: jax.Array) -> tuple[jax.Array, ...]:
            return function(jax.lax.axis_index(self.axes), *block)

        mapped = jax.shard_map(per_device, mesh=self.mesh, in_specs=spec, out_specs=spec, check_vma=False)
        return mapped(*inputs)


@dataclasses.dataclass
class _Slot:
    """What one device's calls compute with: a lock, its share of the threads, each thread's ``MjData``
    per model."""

    pool: ThreadPoolExecutor
    threads: int
    datas: list[dict[int, mujoco.MjData]]
    lock: threading.Lock = dataclasses.field(default_factory=threading.Lock)

    @classmethod
    def make(cls, threads: int, place: int) -> _Slot:
        pool = ThreadPoolExecutor(threads, thread_name_prefix=f"swat_jax_c_physics_{place}")
        return cls(pool, threads, [{} for _ in range(threads)])


class CSimulator:
    """One body on MuJoCo C: the initial state and the advance / derive functions, as
    :class:`~swat_jax.envs.physics.Simulator` on MJX.

    Args:
        mj_models: the body's compiled model, or its variants' (one per row of the body's variant table;
            a state's ``index`` picks one). All share one topology (the same sizes).
        name: the body's name, for errors.
        threads: threads that step the copies; default: the CPUs this process may use. With ``shards``,
            each of this process's devices calls with its own share (at least one thread).
        joint_axes: also compute the joints' world axes (``xaxis``), which a 3D body's observation reads.
        shards: the device mesh the calls split over (module docstring); None: one call on the first device.

    Raises:
        ValueError: no model, models of different sizes, or ``threads`` < 1.
    """

    implementation = "c"

    def __init__(
        self,
        mj_models: Sequence[mujoco.MjModel],
        name: str = "body",
        threads: int | None = None,
        joint_axes: bool = False,
        shards: PhysicsShards | None = None,
    ):
        if not mj_models:
            raise ValueError("CSimulator needs at least one model")
        sizes = {(m.nq, m.nv, m.na, m.nu, m.nbody, m.nsite) for m in mj_models}
        if len(sizes) > 1:
            raise ValueError(f"the models differ in size (nq, nv, na, nu, nbody, nsite): {sorted(sizes)}")
        self.threads = threads or len(os.sched_getaffinity(0))
        if self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {threads}")
        self.models = tuple(mj_models)
        model = self.models[0]
        self.name = name
        self.state_size = mujoco.mj_stateSize(model, STATE)
        self.shards = shards if shards is not None and shards.size > 1 else None
        places = self.shards.local() if self.shards else {0: 0}
        self._slots = {
            shard: _Slot.make(max(1, self.threads // len(places)), place) for shard, place in places.items()
        }
        self.derived = DERIVED + ((JOINT_AXES,) if joint_axes else ())
        """The derived fields this simulator's states hold."""
        self.key = hashlib.sha256(
            repr(([model_digest(m) for m in self.models], self.derived, sorted(places.items()))).encode()
        ).hexdigest()
        """What programs name this simulator by: the SHA-256 of its models, derived fields and the shards
        this process calls for. Simulators of one key compute the same; the one that traced a program
        last (or was built first) computes its calls."""
        _simulators.setdefault(self.key, self)
        named_callback.register(TARGET, _host_target)
        self.calls: collections.Counter[int] = collections.Counter()
        """Host calls made by this process so far, by shard (device of the mesh; 0 without shards)."""
        self.timeline: list[tuple[int, float, float]] | None = None
        """Set it to a list to record every later call as (shard, start, end), ``time.perf_counter`` seconds:
        whether the devices' calls overlap in time."""
        example = mujoco.MjData(model)
        self._derived_shapes = {name: np.shape(getattr(example, name)) for name in self.derived}
        zeros = {name: np.zeros(shape, np.float32) for name, shape in self._derived_shapes.items()}
        self.initial = CData(
            qpos=jnp.asarray(model.qpos0, jnp.float32),
            qvel=jnp.zeros(model.nv, jnp.float32),
            act=jnp.zeros(model.na, jnp.float32),
            qacc_warmstart=jnp.zeros(model.nv, jnp.float32),
            remainder=jnp.zeros(2 * self.state_size, jnp.float32),
            ctrl=jnp.zeros(model.nu, jnp.float32),
            **{name: jnp.asarray(value) for name, value in zeros.items()},
        )
        self._qpos0 = jnp.asarray(np.stack([m.qpos0 for m in self.models]), jnp.float32)

    def qpos0(self, index: jax.Array | None) -> jax.Array:
        """[nq] float32 reference pose of model ``index`` (None: the first)."""
        return self._qpos0[0 if index is None else index]

    def advance(self, data: CData, steps: int, index: jax.Array | None = None) -> CData:
        """``steps`` calls of ``mj_step`` from ``data`` (its ctrl applied) on model ``index``; the derived
        fields as the last one leaves them, with ``cvel`` of the new qvel (module docstring)."""
        return self._with_outputs(data, self._call("advance", data, index, steps))

    def derive(self, data: CData, index: jax.Array | None = None) -> CData:
        """Positions, orientations, sites and frame velocities computed from qpos and qvel
        (``mj_kinematics``, ``mj_comPos``, ``mj_comVel``)."""
        return self._with_outputs(data, self._call("derive", data, index, 0))

    def velocities(self, data: CData, index: jax.Array | None = None) -> CData:
        """``data`` itself: :meth:`advance` has computed the frame velocities of its new qvel."""
        return data

    def _call(self, compute: str, data: CData, index: jax.Array | None, steps: int) -> tuple[jax.Array, ...]:
        """:data:`COMPUTE` ``[compute]`` on every copy of ``data``: one host call, or one per device with
        shards."""
        shapes = _result_shapes(data, self.state_size, self.derived)
        _simulators[self.key] = self

        def callback(shard: jax.Array, *inputs: jax.Array) -> tuple[jax.Array, ...]:
            return named_callback.call(
                TARGET, shapes, shard, *inputs, simulator=self.key, compute=compute, steps=steps
            )

        inputs = self._inputs(data, index)
        if self.shards is None:
            return callback(jnp.zeros((), jnp.int32), *inputs)
        return self.shards.call(callback, *inputs)

    def _inputs(self, data: CData, index: jax.Array | None) -> tuple[jax.Array, ...]:
        state = jnp.concatenate([data.qpos, data.qvel, data.act, data.qacc_warmstart], axis=-1)
        variant = jnp.zeros((), jnp.int32) if index is None else index.astype(jnp.int32)
        return state, data.remainder, data.ctrl, variant

    def _with_outputs(self, data: CData, outputs: tuple[jax.Array, ...]) -> CData:
        state, remainder, *derived = outputs
        ends = np.cumsum([data.qpos.shape[-1], data.qvel.shape[-1], data.act.shape[-1]])
        qpos, qvel, act, warmstart = jnp.split(state, ends, axis=-1)
        return data.replace(
            qpos=qpos,
            qvel=qvel,
            act=act,
            qacc_warmstart=warmstart,
            remainder=remainder,
            **dict(zip(self.derived, derived, strict=True)),
        )

    def _host_call(
        self, compute: CopyFunction, steps: int, shard: np.ndarray, *args: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        """Every copy of a call on device ``shard`` (broadcast to the copies' axes): the arguments' leading
        axes flattened to one batch [B], split into contiguous blocks, one per thread of the device's
        share, each thread with its own ``MjData`` per model."""
        state, remainder, ctrl, index = (np.asarray(arg) for arg in args)
        device = int(np.asarray(shard).flat[0])
        slot = self._slots[device]
        self.calls[device] += 1
        lead = index.shape
        batch = math.prod(lead)
        full = _joined(state.reshape(batch, -1), remainder.reshape(batch, 2, -1))
        ctrl = ctrl.reshape(batch, -1).astype(np.float64)
        index = index.reshape(batch)
        if batch and (index.min() < 0 or index.max() >= len(self.models)):
            raise ValueError(
                f"{self.name}: variant index outside 0..{len(self.models) - 1}: {np.unique(index)}"
            )
        derived = {
            name: np.empty((batch, *shape), np.float64) for name, shape in self._derived_shapes.items()
        }
        blocks = [rows for rows in np.array_split(np.arange(batch), min(slot.threads, batch)) if len(rows)]
        start = time.perf_counter()
        with slot.lock:
            if len(blocks) == 1:
                self._run_block(compute, slot.datas[0], blocks[0], full, ctrl, index, derived, steps)
            else:
                jobs = [
                    slot.pool.submit(
                        self._run_block, compute, slot.datas[t], rows, full, ctrl, index, derived, steps
                    )
                    for t, rows in enumerate(blocks)
                ]
                for job in jobs:
                    job.result()
        if self.timeline is not None:
            self.timeline.append((device, start, time.perf_counter()))
        rounded, left = _split(full)
        return (
            rounded.reshape(*lead, -1),
            left.reshape(*lead, -1),
            *(
                derived[name].astype(np.float32).reshape(*lead, *derived[name].shape[1:])
                for name in self.derived
            ),
        )

    def _run_block(
        self,
        compute: CopyFunction,
        datas: dict[int, mujoco.MjData],
        rows: np.ndarray,
        full: np.ndarray,
        ctrl: np.ndarray,
        index: np.ndarray,
        derived: dict[str, np.ndarray],
        steps: int,
    ) -> None:
        """``compute`` on the copies ``rows`` with one thread's ``datas`` (its ``MjData`` per model); ``full``
        [B, S] and ``derived`` written in place."""
        for row in rows:
            variant = int(index[row])
            model = self.models[variant]
            data = datas.get(variant)
            if data is None:
                data = datas[variant] = mujoco.MjData(model)
            try:
                compute(model, data, full[row], ctrl[row], steps)
            except mujoco.FatalError as error:
                raise RuntimeError(
                    f"{self.name}: MuJoCo rejected a physics step on physics 'c': {error}; its MJCF may need "
                    "more memory (<size memory=...>), or the body may run on physics 'jax'"
                ) from error
            for name in self.derived:
                derived[name][row] = getattr(data, name)


CopyFunction = Callable[[mujoco.MjModel, mujoco.MjData, np.ndarray, np.ndarray, int], None]
"""What a call computes for one copy: (model, data, state [S] float64 updated in place, ctrl [nu], steps)."""


def _advance_copy(
    model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray, ctrl: np.ndarray, steps: int
) -> None:
    """``steps`` physics steps of one copy from ``state`` (then NaN qpos and qvel if it exploded)."""
    mujoco.mj_setState(model, data, state, STATE)
    data.ctrl[:] = ctrl
    for _ in range(steps):
        mujoco.mj_step(model, data)
        if not np.all(np.abs(data.qvel) <= EXPLOSION_SPEED):
            mujoco.mj_getState(model, data, state, STATE)
            state[: model.nq + model.nv] = np.nan
            return
    mujoco.mj_comVel(model, data)
    mujoco.mj_getState(model, data, state, STATE)


def _derive_copy(
    model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray, ctrl: np.ndarray, steps: int
) -> None:
    """The kinematics of one copy at ``state`` (left unchanged; ``ctrl`` and ``steps`` unused)."""
    mujoco.mj_setState(model, data, state[: model.nq + model.nv], POSITION)
    derive_kinematics(model, data)


COMPUTE: dict[str, CopyFunction] = {"advance": _advance_copy, "derive": _derive_copy}
"""What a call of :data:`TARGET` computes for each copy, by its ``compute`` attribute."""
_simulators: dict[str, CSimulator] = {}
"""This process's simulators by :attr:`CSimulator.key`: the one that computes a program's calls."""


def _host_target(
    args: Sequence[np.ndarray], results: Sequence[np.ndarray], attributes: Mapping[str, str | int]
) -> None:
    """A call of :data:`TARGET`: the named simulator's :meth:`CSimulator._host_call`, written into the
    ``results`` buffers."""
    simulator = _simulators.get(str(attributes["simulator"]))
    if simulator is None:
        raise RuntimeError(
            f"a program calls C physics simulator {attributes['simulator']} that this process has not built; "
            "build its environment (swat_jax.envs.BodyEnv with physics 'c') before running the program"
        )
    compute = COMPUTE[str(attributes["compute"])]
    outputs = simulator._host_call(compute, int(attributes["steps"]), *args)
    for result, output in zip(results, outputs, strict=True):
        result[...] = output


def _joined(rounded: np.ndarray, remainder: np.ndarray) -> np.ndarray:
    """[B, S] float64 from its float32 parts: ``rounded`` [B, S] and ``remainder`` [B, 2, S]."""
    return (
        rounded.astype(np.float64) + remainder[:, 0].astype(np.float64) + remainder[:, 1].astype(np.float64)
    )


def _split(full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``full`` [B, S] float64 as its float32 rounding [B, S] and the remainders [B, 2 S] (inverse of
    :func:`_joined`, exact: each part holds 24 of the 53 bits)."""
    rounded = full.astype(np.float32)
    left = full - rounded
    middle = left.astype(np.float32)
    low = (left - middle).astype(np.float32)
    return rounded, np.concatenate([middle, low], axis=-1)


def _result_shapes(data: CData, state_size: int, derived: Sequence[str]) -> tuple[jax.ShapeDtypeStruct, ...]:
    """The shapes of a call's results for one copy (``vmap`` adds the leading axes): state, remainder,
    then the ``derived`` fields."""
    state = jax.ShapeDtypeStruct((state_size,), jnp.float32)
    remainder = jax.ShapeDtypeStruct((2 * state_size,), jnp.float32)
    return (
        state,
        remainder,
        *(jax.ShapeDtypeStruct(getattr(data, name).shape, jnp.float32) for name in derived),
    )
