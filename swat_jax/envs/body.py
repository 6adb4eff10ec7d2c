"""One body as a functional MuJoCo MJX environment: ``reset(rng) -> state``, ``step(state, action) -> state``.

Exactly the modular-locomotion benchmark (docs/bodies-and-environments.md, "Environments"): frame skip 4, the per-limb observation of observation.py, the
family's reward, termination and reset noise (swat_jax/morphology/families.py), and the 1000-step time
limit reported as truncation, not termination. One action per limb and hinge slot ([n] planar, [n, 3]
in 3D); the torso's are ignored and the others reach their motors through the limb-to-motor map,
clipped to [-1, 1]. The body's task (:mod:`swat_jax.envs.tasks`) gives its reward and termination: a
planar body runs forward, a body of a 3D family (SGRL's benchmark) walks toward a target point, which its
state carries.

Two decisions beyond the benchmark text, both documented in docs/bodies-and-environments.md and docs/fidelity.md:
- Observations are computed from the kinematics of the state after the step, or, with
  ``stale_kinematics``, as the original code reads them: MuJoCo's ``mj_step`` leaves in its derived
  fields the positions of the last integrator stage (before the last integration: the previous state for
  Euler, the last stage's point for RK4), and the original read those with the new joint velocities
  (its Jacobians times the new qvel) and the new joint angles.
- A simulation that produces a non-finite state or a joint speed above :data:`EXPLOSION_SPEED` is
  terminated, earns reward 0 on that step, and reports an all-zero observation; no NaN leaves ``step``.

All methods are pure functions of their arguments (the class only holds constants), so they jit and vmap.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Union

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from swat_jax.envs.c_physics import EXPLOSION_SPEED, CData, CSimulator, PhysicsShards
from swat_jax.envs.controller import BodyInterface, body_interface, controls
from swat_jax.envs.observation import (
    ObservationLayout,
    data_observation,
    layout_joint_range,
)
from swat_jax.envs.physics import ModelFields, Physics, Simulator, differing_fields, resolve_physics
from swat_jax.envs.quiet_mjx import mjx
from swat_jax.envs.tasks import BOUNDED_STATE_LIMIT, TargetState, Task, body_task
from swat_jax.morphology.mjcf import compile_model, load
from swat_jax.morphology.types import Morphology

__all__ = ["BOUNDED_STATE_LIMIT", "EXPLOSION_SPEED", "BodyEnv", "EnvState", "PhysicsData", "Variant"]

PhysicsData = Union["mjx.Data", CData]
"""A simulator state: MJX's on physics "jax" and "warp", :class:`~swat_jax.envs.c_physics.CData` on "c"
(the same field names for what the environment reads)."""


@struct.dataclass
class Variant:
    """What one variant of a body (:mod:`swat_jax.morphology.variants`) changes: inputs of the step, never
    constants of its program, so one program steps any number of variants. With leading axes when stacked
    or vmapped (:meth:`BodyEnv.variant_table` has [k])."""

    model: ModelFields
    """The ``mjx.Model`` leaves in which the variants differ, by key path (``physics.differing_fields``);
    empty on physics "c", where ``index`` picks the variant's compiled model."""
    joint_range: jax.Array
    """[n, 2] float32 joint ranges in degrees (the observation scales joint angles by them); 0 for the torso."""
    index: jax.Array
    """[] int32: the variant's row in the body's table (on physics "c", its MuJoCo model)."""


@struct.dataclass
class EnvState:
    """State of one body's episode; every field gains leading axes when vmapped.

    n = limbs, F = features per limb (19, 21 for Animal-Walkers, 41 in 3D).
    """

    data: PhysicsData
    """The simulator state after the last step (positions and velocities computed)."""
    observation: jax.Array
    """[n, F] float32 per-limb observation of ``data``."""
    reward: jax.Array
    """[] float32 reward of the last step (0 after reset)."""
    terminated: jax.Array
    """[] bool: the last step ended the episode by a termination condition (or an unstable simulation)."""
    truncated: jax.Array
    """[] bool: the last step reached the time limit without terminating; the learner bootstraps here."""
    episode_return: jax.Array
    """[] float32 sum of rewards since reset."""
    episode_length: jax.Array
    """[] int32 steps since reset."""
    variant: Variant | None = None
    """The body's variant this episode runs (kept across resets); None: the nominal body."""
    target: jax.Array | None = None
    """3D: [2] float32, the point (x, y) the body walks toward; None for a planar body."""
    target_key: jax.Array | None = None
    """3D: [2] uint32, the key that draws the next target once this one is reached."""

    @property
    def done(self) -> jax.Array:
        """[] bool: the episode is over (terminated or truncated)."""
        return self.terminated | self.truncated


class BodyEnv:
    """The benchmark environment of one body on MJX.

    Args:
        morphology: a loaded body, a benchmark body name, or the path of an MJCF file.
        torso_relative_x: subtract the torso's x from every limb's x (the paper's intent, default).
            False reproduces the reference code (docs/fidelity.md, rows 31-32): the torso reads x = 0, every
            other limb its absolute world x, and the torso's velocity is that of the point (0, y, z).
        stale_kinematics: observe the positions the last physics step left, as the original code does
            (docs/fidelity.md, row 33; physics "jax" or "c").
        physics: "jax" or "warp" (MJX, :class:`~swat_jax.envs.physics.Simulator`), "c" (MuJoCo's C
            library, :class:`~swat_jax.envs.c_physics.CSimulator`), or "auto"
            (:func:`~swat_jax.envs.physics.resolve_physics`: "c" on a CPU, "jax" on a GPU).
        worlds: "warp" only: the most copies one vmapped call steps, all vmap axes together.
        variants: variants of the body (:mod:`swat_jax.morphology.variants`; loaded bodies or MJCF paths),
            the same tree of limbs with other numbers. :meth:`variant_table` stacks what they change; a
            state started with one of its rows (``reset(rng, variant)``) steps that variant, through the
            same program for every variant (physics "jax" or "c"); a state started without one runs the
            first variant.
        shards: physics "c" only: the device mesh its calls split over
            (:class:`~swat_jax.envs.c_physics.PhysicsShards`; vmap the copies with its axes as
            ``spmd_axis_name``); None: one call on the first device.

    Raises:
        ValueError: a variant is not the same tree of limbs, or variants or stale kinematics with
            physics="warp", or shards with physics other than "c".
    """

    def __init__(
        self,
        morphology: Morphology | str,
        *,
        torso_relative_x: bool = True,
        stale_kinematics: bool = False,
        physics: Physics = "jax",
        worlds: int = 1,
        variants: Sequence[Morphology | str | Path] = (),
        shards: PhysicsShards | None = None,
    ):
        physics = resolve_physics(physics)
        if shards is not None and physics != "c":
            raise ValueError(f"shards split MuJoCo C's calls (physics 'c'); physics {physics!r} takes none")
        if stale_kinematics and physics == "warp":
            raise ValueError(
                "stale_kinematics reads the positions MuJoCo's step leaves, which Warp does not keep; use "
                "physics='jax' or 'c', or turn it off"
            )
        self.morphology = morphology if isinstance(morphology, Morphology) else load(morphology)
        self.torso_relative_x = torso_relative_x
        self.stale_kinematics = stale_kinematics
        self.variants = tuple(v if isinstance(v, Morphology) else load(v) for v in variants)
        self._check_variants(physics)
        models = [compile_model(variant) for variant in self.variants] or [compile_model(self.morphology)]
        self.mj_model: mujoco.MjModel = models[0]
        """The compiled model whose numbers are the program's constants: the body's, or its first variant's."""
        self.task: Task = body_task(self.morphology, self.mj_model)
        """What the body is asked to do: its reward, termination and targets (:mod:`swat_jax.envs.tasks`)."""
        self.simulator: Simulator | CSimulator = (
            CSimulator(models, self.morphology.name, joint_axes=self.task.reads_joint_axes, shards=shards)
            if physics == "c"
            else Simulator(self.mj_model, physics, worlds)
        )
        self.interface: BodyInterface = body_interface(
            self.morphology,
            self.mj_model,
            torso_relative_x=torso_relative_x,
            stale_kinematics=stale_kinematics,
        )
        """The body's constants as a controller outside JAX reads them (:mod:`swat_jax.envs.controller`)."""
        self._variant_table = self._stack_variants(models) if self.variants else None

    @property
    def layout(self) -> ObservationLayout:
        """What the observation reads besides the state (:attr:`interface`'s)."""
        return self.interface.layout

    @property
    def motor_actions(self) -> np.ndarray:
        """[nu] int32: the entry of the flattened action that drives each actuator (:attr:`interface`'s)."""
        return self.interface.motor_actions

    @property
    def gravity(self) -> np.ndarray:
        """[3] float32, the model's gravity (:attr:`interface`'s)."""
        return self.interface.gravity

    @property
    def num_limbs(self) -> int:
        return self.morphology.num_limbs

    @property
    def observation_features(self) -> int:
        """F, the number of values per limb."""
        return self.layout.features

    @property
    def action_shape(self) -> tuple[int, ...]:
        """The shape of one action: (n,) planar, (n, M) in 3D."""
        motors = self.morphology.motors_per_limb
        return (self.num_limbs,) if motors == 1 else (self.num_limbs, motors)

    def variant_table(self) -> Variant:
        """Every variant's row, stacked: ``model`` leaves and ``joint_range`` with a leading [k] axis.

        Raises:
            ValueError: the environment was built without variants.
        """
        if self._variant_table is None:
            raise ValueError(f"{self.morphology.name}: this environment has no variants; pass variants=...")
        return self._variant_table

    def _check_variants(self, physics: str) -> None:
        if self.variants and physics == "warp":
            raise ValueError(
                "variants of a body run on physics='jax' or 'c' (their model is an input of the step)"
            )
        nominal = self.morphology
        for variant in self.variants:
            tree = (variant.limb_names, variant.parents, variant.limb_motors, variant.joint_names)
            if tree != (nominal.limb_names, nominal.parents, nominal.limb_motors, nominal.joint_names):
                raise ValueError(
                    f"{variant.path}: not a variant of {nominal.name}: its limbs, parents, joints or motors "
                    "differ (a variant changes numbers only; another tree is another body)"
                )

    def _stack_variants(self, models: list[mujoco.MjModel]) -> Variant:
        """The variants' rows: the model leaves in which they differ (the first variant's model holds the
        rest as constants; none on physics "c", which steps each variant's own model), their joint ranges
        and indices."""
        fields = {} if isinstance(self.simulator, CSimulator) else differing_fields(models)
        return Variant(
            model={path: jnp.asarray(values) for path, values in fields.items()},
            joint_range=jnp.asarray(np.stack([layout_joint_range(variant) for variant in self.variants])),
            index=jnp.arange(len(models), dtype=jnp.int32),
        )

    def reset(self, rng: jax.Array, variant: Variant | None = None) -> EnvState:
        """Start an episode at the initial pose plus the family's reset noise (of ``variant``: one row of
        :meth:`variant_table`; None: the body, or with variants its first one); in 3D facing a random
        heading, with a target at a random direction."""
        data, target = self.new_episode(rng, variant)
        return self.start(self.kinematics(data, variant), variant, target)

    def new_episode(
        self, rng: jax.Array, variant: Variant | None = None
    ) -> tuple[PhysicsData, TargetState | None]:
        """What an episode starts from: :meth:`initial_data` (kinematics not computed) and what the task
        carries besides it (in 3D the first target and the key of the next; None for a planar body)."""
        pose_key, target = self.task.episode(rng)
        return self.initial_data(pose_key, variant), target

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """Apply ``action`` (:attr:`action_shape`: one value per limb and hinge slot, the torso's ignored) for
        ``frame_skip`` physics steps."""
        data = self.simulate(state.data, action, state.variant)
        return self.finish_step(state, self.step_kinematics(data, state.variant))

    def initial_data(self, rng: jax.Array, variant: Variant | None = None) -> PhysicsData:
        """The initial pose plus reset noise; derived quantities not yet computed (see :meth:`kinematics`)."""
        noise = self.morphology.family.reset_noise
        qpos0, rng = self.task.orient(self.simulator.qpos0(self._row(variant)), rng)
        position_key, velocity_key = jax.random.split(rng)
        qpos = qpos0 + jax.random.uniform(
            position_key, (self.mj_model.nq,), minval=-noise.qpos_uniform, maxval=noise.qpos_uniform
        )
        if noise.qvel_gaussian:
            qvel = noise.qvel_scale * jax.random.normal(velocity_key, (self.mj_model.nv,))
        else:
            qvel = jax.random.uniform(
                velocity_key, (self.mj_model.nv,), minval=-noise.qvel_scale, maxval=noise.qvel_scale
            )
        initial = self.simulator.initial
        dtype = initial.qpos.dtype
        return initial.replace(qpos=qpos.astype(dtype), qvel=qvel.astype(dtype))

    def simulate(self, data: PhysicsData, action: jax.Array, variant: Variant | None = None) -> PhysicsData:
        """``frame_skip`` physics steps under ``action`` (:attr:`action_shape`); derived quantities not yet
        computed."""
        data = data.replace(ctrl=controls(self.motor_actions, action, jnp))
        return self.simulator.advance(data, self.morphology.frame_skip, self._row(variant))

    def kinematics(self, data: PhysicsData, variant: Variant | None = None) -> PhysicsData:
        """Positions, orientations, sites and frame velocities computed from ``data``'s qpos and qvel."""
        return self.simulator.derive(data, self._row(variant))

    def step_kinematics(self, data: PhysicsData, variant: Variant | None = None) -> PhysicsData:
        """The kinematics a step's observation and termination read, for ``data`` just simulated:
        :meth:`kinematics`, or with ``stale_kinematics`` the positions, orientations and sites the last
        physics step left, with frame velocities from them and the new qvel (the original code's reads)."""
        if self.stale_kinematics:
            return self.simulator.velocities(data, self._row(variant))
        return self.kinematics(data, variant)

    def start(
        self,
        data: PhysicsData,
        variant: Variant | None = None,
        target: TargetState | None = None,
    ) -> EnvState:
        """The state of a new episode at ``data`` (kinematics computed) of ``variant``; in 3D with ``target``
        (:meth:`new_episode`'s)."""
        zero = jnp.zeros((), jnp.float32)
        point, key = target if target is not None else (None, None)
        return EnvState(
            data=data,
            observation=self._observe(data, variant, point),
            reward=zero,
            terminated=jnp.zeros((), bool),
            truncated=jnp.zeros((), bool),
            episode_return=zero,
            episode_length=jnp.zeros((), jnp.int32),
            variant=variant,
            target=point,
            target_key=key,
        )

    def finish_step(self, state: EnvState, data: PhysicsData) -> EnvState:
        """The state after ``state`` was simulated to ``data`` (kinematics computed): reward, termination,
        truncation and observation of the step."""
        unstable = _unstable(data)
        earned = self.task.reward(state.data, data, state.target)
        terminated = unstable | ~self.task.alive(state.data, data)
        target, target_key = self.task.advance(state.target, state.target_key, data)
        reward = jnp.where(unstable, 0.0, earned).astype(jnp.float32)
        length = state.episode_length + 1
        return EnvState(
            data=data,
            observation=jnp.where(unstable, 0.0, self._observe(data, state.variant, state.target)),
            reward=reward,
            terminated=terminated,
            truncated=~terminated & (length >= self.morphology.family.max_episode_steps),
            episode_return=state.episode_return + reward,
            episode_length=length,
            variant=state.variant,
            target=target,
            target_key=target_key,
        )

    def _row(self, variant: Variant | None) -> ModelFields | jax.Array | None:
        """What the simulator needs of ``variant``: its model fields on MJX, its index on C physics."""
        if variant is None:
            return None
        return variant.index if isinstance(self.simulator, CSimulator) else variant.model

    def _observe(
        self, data: PhysicsData, variant: Variant | None = None, target: jax.Array | None = None
    ) -> jax.Array:
        """[n, F] float32 (whatever precision the simulation runs in); ``target`` [2] in 3D."""
        layout = self.layout if variant is None else self.layout._replace(joint_range=variant.joint_range)
        return data_observation(
            layout,
            data,
            torso_relative_x=self.torso_relative_x,
            target=target,
            gravity=self.gravity,
            xp=jnp,
        )


def _unstable(data: PhysicsData) -> jax.Array:
    """[] bool: the state is not finite or some joint moves faster than EXPLOSION_SPEED."""
    finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
    return ~finite | jnp.any(jnp.abs(data.qvel) > EXPLOSION_SPEED)
