"""What a :class:`TrainConfig` builds: the task set, environments, networks, learner, device mesh and the
jitted programs of a run (the trained policy read back from a run directory is :mod:`swat_jax.runs.trained`)."""

from __future__ import annotations

import dataclasses
import functools
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from swat_jax.compilation_cache import compile_cached, compiled_at_first_call
from swat_jax.envs.multi_task import MultiTaskEnv
from swat_jax.envs.physics import resolve_physics
from swat_jax.morphology import Morphology, limb_buckets
from swat_jax.morphology.variants import Variation, write_variants
from swat_jax.networks import (
    ArchitectureMismatch,
    Params,
    StructureMismatch,
    TaskSet,
    make_actor_critic,
    task_set,
)
from swat_jax.runs import programs
from swat_jax.runs.checkpoint import CheckpointError, CheckpointInfo, Checkpoints
from swat_jax.runs.config import ConfigError, TrainConfig
from swat_jax.runs.trained import check_transfer, network_items, restore_networks
from swat_jax.td3.evaluation import Episodes, make_evaluation
from swat_jax.td3.iteration import TrainState, init_train_state, make_train_iteration, seed_keys
from swat_jax.td3.learner import Learner, LearnerState
from swat_jax.td3.replay import resized
from swat_jax.td3.sharding import Placement, placement

RING_AXIS = 2
"""The ring axis of the replay arrays of a TrainState: [seeds, tasks, rows, ...]."""
REPLAY_ROWS_KEY = ".buffer.data.reward"
"""The checkpointed array whose shape gives the replay rings' rows."""
REPLAY_POSITION_KEY = ".buffer.position"
"""The checkpointed write position: [S], one per seed, or [] in checkpoints written before the seeds had
their own (December 2026)."""


@dataclasses.dataclass(frozen=True)
class Experiment:
    """The fixed parts of a run: the task set of its bodies, their multi-task environment and the TD3
    learner."""

    config: TrainConfig
    tasks: TaskSet
    env: MultiTaskEnv
    learner: Learner
    placement: Placement
    """The device mesh of the run's arrays (:mod:`swat_jax.td3.sharding`)."""

    @classmethod
    def build(cls, config: TrainConfig, devices: Sequence[jax.Device] | None = None) -> Experiment:
        """Load the bodies, build the networks and lay the run out over ``devices`` (default: every device);
        ConfigError if the network cannot take the bodies."""
        network = config.network_config()
        try:
            tasks = task_set(
                config.training_bodies(), network, reference_inorder=config.network.reference_inorder
            )
        except StructureMismatch as error:
            raise ConfigError(
                f"{config.algo} cannot take the bodies of {config.env}: {error}; {config.structure_fix(error)}"
            ) from error
        except ArchitectureMismatch as error:
            raise ConfigError(f"{config.algo} cannot take the bodies of {config.env}: {error}") from error
        devices = jax.devices() if devices is None else devices
        layout = placement(config.seeds, len(tasks.bodies), config.envs.copies, devices)
        env = make_env(
            config,
            tasks.bodies,
            config.envs.copies,
            config.seeds,
            lock_step=config.iteration.rounds,
            variants=config.envs.variants,
            variation=config.envs.variant_draw(),
            mesh=layout.mesh,
        )
        if config.init_from:
            check_transfer(config, env.observation_features)
        actor, critic = make_actor_critic(
            network, env.observation_features, config.td3.atoms, env.motors_per_limb
        )
        # A bucket gathers tasks across the task axis: only where that axis is not split over devices.
        buckets = (
            limb_buckets([body.num_limbs for body in tasks.bodies], config.limb_buckets)
            if config.limb_buckets > 1 and not layout.tasks_split
            else ()
        )
        return cls(config, tasks, env, Learner(actor, critic, config.td3, buckets), layout)

    @property
    def replay_rows(self) -> int:
        """Rows of each task's replay ring (:meth:`TrainConfig.replay_rows`)."""
        return self.config.replay_rows(self.env.num_bodies)

    def init_state(self) -> TrainState:
        """Fresh networks, empty replay buffers and reset environments for every seed of the run, stacked on
        a leading seed axis (:func:`swat_jax.axes.seed_axes`).

        With ``config.init_from``, every seed's actor, critic and target networks are those of the chosen
        seed of that run (optimizers and replay buffers stay fresh).

        Jitted: an eager MJX reset dispatches thousands of small operations (minutes for five bodies); each
        device computes its own shards. Traced once, for both its shapes (which place it) and its program.
        """

        def initial_state() -> Callable[[jax.Array], TrainState]:
            shardings = self.placement.state_shardings(self.state_shapes)
            return jax.jit(self._initial_state, out_shardings=shardings)

        keys = self._seed_keys()
        recipe = self._recipe(self.env, self.replay_rows)
        state = compile_cached("init_state", initial_state, (keys,), recipe)(keys)
        if self.config.init_from:
            state = state.replace(learner=self._transferred(state.learner))
        return self._placed(state)

    def _transferred(self, learner: LearnerState) -> LearnerState:
        """``learner`` with the networks of seed ``init_seed_index`` of run ``init_from`` in every seed."""
        one_seed = network_items(jax.eval_shape(self.learner.init, jax.random.PRNGKey(0)))
        # On the host: the copies are then placed on the mesh like every other array (several hosts too).
        networks = jax.device_get(restore_networks(Path(self.config.init_from), one_seed))
        index, seeds = self.config.init_seed_index, self.config.seeds
        chosen = jax.tree_util.tree_map(
            lambda leaf: np.broadcast_to(leaf[index], (seeds, *leaf.shape[1:])), networks
        )
        return learner.replace(
            actor_params=chosen["actor"],
            critic_params=chosen["critic"]["critic_params"],
            target_actor_params=chosen["critic"]["target_actor_params"],
            target_critic_params=chosen["critic"]["target_critic_params"],
        )

    def restore_state(self, checkpoints: Checkpoints) -> tuple[TrainState, CheckpointInfo]:
        """The newest checkpoint's training state, placed exactly as :meth:`init_state` places a fresh one
        (whatever mesh wrote it), and its info (CheckpointError if it is missing, unreadable or does not
        match).

        A checkpoint whose replay rings have another size (the run resumed with another ``--steps``, or
        written when rings were always ``iteration.capacity`` rows) is read at its size and resized to
        :attr:`replay_rows`, exactly, when what it stored fits; else CheckpointError.
        """
        shapes = self.state_shapes
        rows = checkpoints.saved_shape(REPLAY_ROWS_KEY, shapes)[RING_AXIS]
        if rows != self.replay_rows:
            shapes = shapes.replace(
                buffer=jax.eval_shape(lambda b: resized(b, rows, 0, RING_AXIS), shapes.buffer)
            )
        shardings = self.placement.state_shardings(shapes)
        shared = checkpoints.saved_shape(REPLAY_POSITION_KEY, shapes) == ()
        if shared:
            # Written when every seed wrote its replay at one position: read it as one, give each seed a copy.
            one, replicated = jax.ShapeDtypeStruct((), np.int32), self.placement.replicated()
            shapes = shapes.replace(buffer=shapes.buffer.replace(position=one, size=one))
            shardings = shardings.replace(
                buffer=shardings.buffer.replace(position=replicated, size=replicated)
            )
        state, info = checkpoints.restore(shapes, shardings)
        if shared:
            seeds = (self.config.seeds,)
            state = state.replace(
                buffer=state.buffer.replace(
                    position=jnp.broadcast_to(state.buffer.position, seeds),
                    size=jnp.broadcast_to(state.buffer.size, seeds),
                )
            )
        if rows != self.replay_rows:
            stored = int(state.steps_per_task)
            if stored > min(rows, self.replay_rows):
                raise CheckpointError(
                    f"{checkpoints.directory / str(info.env_steps)} holds {stored:,} transitions per task, more "
                    f"than the {self.replay_rows:,}-row replay rings of --steps {self.config.steps:,} take: "
                    f"resume with --steps {info.env_steps:,} or more"
                )
            state = state.replace(buffer=resized(state.buffer, self.replay_rows, stored, RING_AXIS))
        return self._placed(state), info

    @functools.cached_property
    def state_shapes(self) -> TrainState:
        """The shapes and dtypes of :meth:`init_state`, without allocating anything (traced once per
        Experiment: a second of tracing MJX's reset)."""
        return jax.eval_shape(self._initial_state, self._seed_keys())

    @functools.cached_property
    def _initial_state(self) -> Callable[[jax.Array], TrainState]:
        """The fresh state of every seed from their keys [S]; one function object, so that JAX's trace
        cache serves :attr:`state_shapes` and :meth:`init_state` with one trace."""
        iteration = dataclasses.replace(self.config.iteration, capacity=self.replay_rows)
        return functools.partial(init_train_state, self.env, self.learner, iteration)

    def _placed(self, state: TrainState) -> TrainState:
        """Every array of ``state`` committed to its place on the mesh.

        The compiled iteration, and so its persistent-cache key, differs between committed and uncommitted
        inputs (their buffers are donated differently). Restored checkpoints mix both (zero-size MJX arrays
        are rebuilt uncommitted), so fresh and resumed runs go through here to share one cache entry.
        """
        return jax.device_put(state, self.placement.state_shardings(state))

    def _seed_keys(self) -> jax.Array:
        return seed_keys(self.config.seed, self.config.seeds)

    def iteration(self) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
        """The jitted training iteration of every seed, partitioned over the mesh; it consumes (donates) its
        input state and returns the state placed as it came."""
        shardings = self.placement.state_shardings(self.state_shapes)
        return jax.jit(
            make_train_iteration(self.env, self.tasks.structure, self.learner, self.config.iteration),
            in_shardings=(shardings,),
            out_shardings=(shardings, self.placement.seeded()),
            donate_argnums=0,
        )

    def compiled_iteration(
        self, state: TrainState
    ) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
        """:meth:`iteration` compiled for ``state``, or loaded compiled from the program cache
        (:func:`swat_jax.compilation_cache.compile_cached`)."""
        return compile_cached("iteration", self.iteration, (state,), self._recipe(self.env))

    def evaluation(self) -> Callable[[Params, jax.Array], Episodes]:
        """The jitted deterministic evaluation of actor parameters [S, ...] on the train bodies,
        ``config.eval_episodes`` episodes each (:func:`swat_jax.td3.evaluation.make_evaluation`)."""
        return jax.jit(make_evaluation(self._evaluation_env, self.tasks.structure, self.learner.actor))

    def compiled_evaluation(self) -> Callable[[Params, jax.Array], Episodes]:
        """:meth:`evaluation`, compiled (or loaded from the program cache) at its first call."""
        return compiled_at_first_call("evaluation", self.evaluation, self._recipe(self._evaluation_env))

    @functools.cached_property
    def _evaluation_env(self) -> MultiTaskEnv:
        """The train bodies with ``config.eval_episodes`` copies each, for every seed."""
        return make_env(
            self.config,
            self.tasks.bodies,
            self.config.eval_episodes,
            self.config.seeds,
            mesh=self.placement.mesh,
        )

    def _recipe(self, env: MultiTaskEnv, *extra: Any) -> tuple[Any, ...] | None:
        """The program cache's recipe of a program of this run on ``env`` (:mod:`swat_jax.runs.programs`),
        with the mesh the programs place their outputs on, and ``extra``."""
        mesh = self.placement.mesh.device_ids.tolist()
        return programs.recipe(self.config, env, self.placement, mesh, *extra)

    def checkpoint_info(
        self, env_steps: int, iterations: int, seconds: float, **extra: Any
    ) -> CheckpointInfo:
        """The record a checkpoint of this run stores: progress, and what a policy needs besides its
        parameters (seeds, bodies, padded limbs, observation features); ``extra``: CheckpointInfo's optional
        fields."""
        return CheckpointInfo(
            env_steps=env_steps,
            iterations=iterations,
            seconds=seconds,
            seeds=tuple(self.config.seed_values()),
            bodies=tuple(self.env.body_names),
            max_limbs=self.env.max_limbs,
            observation_features=self.env.observation_features,
            motors_per_limb=self.env.motors_per_limb,
            **extra,
        )


def make_env(
    config: TrainConfig,
    bodies: Sequence[Morphology],
    copies: int,
    seeds: int,
    *,
    lock_step: bool = False,
    variants: int = 0,
    variation: Variation | None = None,
    mesh: Mesh | None = None,
) -> MultiTaskEnv:
    """The environments of ``bodies`` as a run with ``config`` simulates them (its observation switches and
    physics): ``copies`` per body, for ``seeds`` seeds stepped together (the one place a config becomes a
    :class:`~swat_jax.envs.multi_task.MultiTaskEnv`). With ``variants`` K, copy j of each body runs variant
    j mod K drawn by ``variation`` (default: spread 0.2, seed 0): the variants are written to a temporary folder, compiled, and the
    folder removed (the draw is a function of the body, K, the spread and the seed). ``mesh``: the devices
    the run's programs run on, over which MuJoCo C's calls split."""
    settings = dict(
        torso_relative_x=config.envs.torso_relative_x,
        stale_kinematics=config.envs.stale_kinematics,
        physics=resolve_physics(config.envs.physics),
        seeds=seeds,
        lock_step=lock_step,
        mesh=mesh,
        shared_reset_key=config.envs.shared_reset_key,
    )
    if not variants:
        return MultiTaskEnv(bodies, copies, **settings)
    with tempfile.TemporaryDirectory(prefix="swat_jax_variants_") as folder:
        variation = variation or Variation()
        drawn = [write_variants(body.path, variants, variation, Path(folder) / body.name) for body in bodies]
        return MultiTaskEnv(bodies, copies, variants=drawn, **settings)
