"""What a :class:`TrainConfig` builds (environments, networks, learner, the jitted iteration), and the
trained policy read back from a run directory (for ``swat_jax.eval`` and ``swat_jax.export``)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from swat_jax.compilation_cache import compile_cached, compiled_at_first_call
from swat_jax.envs.multi_task import MultiTaskEnv
from swat_jax.morphology import StructureBatch, limb_buckets
from swat_jax.networks import (
    LimbNetwork,
    Params,
    StructureMismatch,
    TaskSet,
    make_actor_critic,
    task_set,
)
from swat_jax.runs.checkpoint import CheckpointError, Checkpoints
from swat_jax.runs.config import ConfigError, TrainConfig, load_config
from swat_jax.td3.evaluation import Episodes, make_evaluation
from swat_jax.td3.iteration import (
    TrainState,
    init_seeded_train_state,
    make_seeded_train_iteration,
    seed_keys,
)
from swat_jax.td3.learner import Learner, LearnerState
from swat_jax.td3.sharding import Placement, placement

CONFIG_FILE = "config.json"


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
        network = config.network()
        try:
            tasks = task_set(config.training_bodies(), network, reference_inorder=config.reference_inorder)
        except StructureMismatch as error:
            raise ConfigError(
                f"{config.algo} cannot take the bodies of {config.env}: {error}; {config.structure_fix(error)}"
            ) from error
        env = MultiTaskEnv(
            tasks.bodies,
            config.copies,
            torso_relative_x=config.torso_relative_x,
            stale_kinematics=config.stale_kinematics,
            physics=config.physics,
            runs=config.seeds,
            lock_step=config.iteration.rounds,
        )
        if config.init_from:
            _check_transfer(config, env.observation_features)
        actor, critic = make_actor_critic(network, env.observation_features)
        devices = jax.devices() if devices is None else devices
        layout = placement(config.seeds, env.num_bodies, config.copies, devices)
        # A bucket gathers tasks across the task axis: only where that axis is not split over devices.
        buckets = (
            limb_buckets([body.num_limbs for body in tasks.bodies], config.limb_buckets)
            if config.limb_buckets > 1 and not layout.tasks_split
            else ()
        )
        return cls(config, tasks, env, Learner(actor, critic, config.td3, buckets), layout)

    def init_state(self) -> TrainState:
        """Fresh networks, empty replay buffers and reset environments for every seed of the run, stacked on
        a leading seed axis (:data:`~swat_jax.td3.iteration.SEED_AXES`).

        With ``config.init_from``, every seed's actor, critic and target networks are those of the chosen
        seed of that run (optimizers and replay buffers stay fresh).

        Jitted: an eager MJX reset dispatches thousands of small operations (minutes for five bodies); each
        device computes its own shards. Traced once, for both its shapes (which place it) and its program.
        """

        def initial_state() -> Callable[[jax.Array], TrainState]:
            shardings = self.placement.state_shardings(self.state_shapes)
            return jax.jit(self._initial_state, out_shardings=shardings)

        keys = self._seed_keys()
        state = compile_cached("init_state", initial_state, (keys,), self._recipe(self.env))(keys)
        if self.config.init_from:
            state = state.replace(learner=self._transferred(state.learner))
        return self._placed(state)

    def _transferred(self, learner: LearnerState) -> LearnerState:
        """``learner`` with the networks of seed ``init_seed_index`` of run ``init_from`` in every seed."""
        one_seed = network_items(jax.eval_shape(self.learner.init, jax.random.PRNGKey(0)))
        # On the host: the copies are then placed on the mesh like every other array (several hosts too).
        networks = jax.device_get(_restore_networks(Path(self.config.init_from), one_seed))
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

    def restore_state(self, checkpoints: Checkpoints) -> tuple[TrainState, dict[str, Any]]:
        """The newest checkpoint's training state, placed exactly as :meth:`init_state` places a fresh one
        (whatever mesh wrote it), and its info (CheckpointError if it is missing, unreadable or does not
        match)."""
        shapes = self.state_shapes
        state, info = checkpoints.restore(shapes, self.placement.state_shardings(shapes))
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
        return functools.partial(init_seeded_train_state, self.env, self.learner, self.config.iteration)

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
            make_seeded_train_iteration(self.env, self.tasks.structure, self.learner, self.config.iteration),
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
        """The train bodies with ``config.eval_episodes`` copies each, one run per seed."""
        return MultiTaskEnv(
            self.tasks.bodies,
            self.config.eval_episodes,
            torso_relative_x=self.config.torso_relative_x,
            stale_kinematics=self.config.stale_kinematics,
            physics=self.config.physics,
            runs=self.config.seeds,
        )

    def _recipe(self, env: MultiTaskEnv) -> tuple[Any, ...] | None:
        """:func:`program_recipe` with the mesh the programs place their outputs on."""
        return program_recipe(self.config, env, self.placement, self.placement.mesh.device_ids.tolist())

    def info(self) -> dict[str, Any]:
        """What a policy needs besides its parameters, stored in every checkpoint."""
        return {
            "seeds": list(self.config.seed_values()),
            "bodies": list(self.env.body_names),
            "max_limbs": self.env.max_limbs,
            "observation_features": self.env.observation_features,
        }


def program_recipe(config: TrainConfig, env: MultiTaskEnv, *extra: Any) -> tuple[Any, ...] | None:
    """What a program of a run with ``config`` on ``env`` is traced from besides its arguments, for
    :func:`swat_jax.compilation_cache.compile_cached`: the config's program fields, the environments'
    definition and ``extra``; None where the environments' programs cannot be cached (Warp physics)."""
    definition = env.definition()
    return None if definition is None else (config.program_config(), definition, *extra)


def network_items(learner: LearnerState) -> dict[str, Any]:
    """The networks of a learner state as the checkpoint items ``actor`` (the actor's parameters) and
    ``critic`` (the critic's and both targets'), every seed."""
    return {
        "actor": learner.actor_params,
        "critic": {
            "critic_params": learner.critic_params,
            "target_actor_params": learner.target_actor_params,
            "target_critic_params": learner.target_critic_params,
        },
    }


def _restore_networks(run_dir: Path, one_seed: dict[str, Any]) -> dict[str, Any]:
    """The items of ``one_seed`` (single-seed shapes, see :func:`network_items`) from the newest checkpoint
    of ``run_dir``, with the run's seed axis in front (CheckpointError if there is none)."""
    checkpoints = Checkpoints(run_dir)
    try:
        seeds = len(_newest_info(run_dir, checkpoints)["seeds"])
        return {
            name: checkpoints.restore_item(
                name,
                jax.tree_util.tree_map(
                    lambda leaf: jax.ShapeDtypeStruct((seeds, *leaf.shape), leaf.dtype), template
                ),
            )
            for name, template in one_seed.items()
        }
    finally:
        checkpoints.close()


def _newest_info(run_dir: Path, checkpoints: Checkpoints) -> dict[str, Any]:
    """The info of the newest checkpoint (CheckpointError if there is none or it predates the seed axis)."""
    if checkpoints.latest_step() is None:
        raise CheckpointError(
            f"{run_dir} has no checkpoint yet, so there is no trained policy to load: training writes "
            "one every --checkpoint-interval steps, at its end and when it is stopped"
        )
    info = checkpoints.info()
    if "seeds" not in info:
        raise CheckpointError(
            f"{checkpoints.directory} was written before runs had a seed axis (swat_jax 0.1.0 before "
            "multi-seed training); train the run again"
        )
    return info


def _check_transfer(config: TrainConfig, observation_features: int) -> None:
    """ConfigError, naming both runs, if run ``config.init_from``'s networks cannot start this run."""
    source_dir = Path(config.init_from)
    if not source_dir.is_dir():
        raise ConfigError(f"--init-from {source_dir}: no such run directory")
    source = load_config(source_dir / CONFIG_FILE)
    checkpoints = Checkpoints(source_dir)
    try:
        info = _newest_info(source_dir, checkpoints)
    finally:
        checkpoints.close()
    theirs, ours = source.network(), config.network()
    problems = [
        f"{field.name} {getattr(theirs, field.name)!r} there, {getattr(ours, field.name)!r} here"
        for field in dataclasses.fields(theirs)
        if getattr(theirs, field.name) != getattr(ours, field.name)
    ]
    if int(info["observation_features"]) != observation_features:
        problems.append(
            f"{info['observation_features']} observation features per limb there, {observation_features} "
            "here (another family vocabulary)"
        )
    if config.init_seed_index >= len(info["seeds"]):
        problems.append(
            f"--init-seed-index {config.init_seed_index}, but it has {len(info['seeds'])} seeds "
            f"({', '.join(map(str, info['seeds']))})"
        )
    if problems:
        raise ConfigError(
            f"--init-from {source_dir} ({source.algo} on {Path(source.env).name}) cannot start "
            f"{config.directory()} ({config.algo} on {Path(config.env).name}): "
            + "; ".join(problems)
            + ". Give this run the same --algo and network sizes as that one"
        )


@dataclasses.dataclass(frozen=True)
class TrainedPolicy:
    """A run's actor and its newest parameters, for every seed of the run; ``act`` is deterministic."""

    config: TrainConfig
    actor: LimbNetwork
    params: Params
    """[S, ...] actor parameters stacked on a leading seed axis, in the order of ``seeds``."""
    info: dict[str, Any]
    """env_steps, iterations, seconds, seeds, bodies, max_limbs, observation_features of the checkpoint."""

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seed of each slice of ``params``."""
        return tuple(self.info["seeds"])

    def seed_params(self, seed_index: int) -> Params:
        """The parameters of the ``seed_index``-th seed (ConfigError naming the valid range if out of it)."""
        if not 0 <= seed_index < len(self.seeds):
            raise ConfigError(
                f"--seed-index {seed_index}: {self.config.directory()} holds {len(self.seeds)} seeds "
                f"({', '.join(map(str, self.seeds))}); use an index from 0 to {len(self.seeds) - 1}"
            )
        return jax.tree_util.tree_map(lambda leaf: leaf[seed_index], self.params)

    def act(self, observation: jax.Array, structure: StructureBatch, seed_index: int = 0) -> jax.Array:
        """observation [batch, limbs, F] and one body's structure slice -> actions [batch, limbs] in [-1, 1]."""
        return self.actor.apply(self.seed_params(seed_index), observation, structure)


def load_policy(run_dir: str | Path) -> TrainedPolicy:
    """The actor of the newest checkpoint of ``run_dir``, every seed (ConfigError / CheckpointError if unusable)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"{run_dir}: no such run directory")
    config = load_config(run_dir / CONFIG_FILE)
    checkpoints = Checkpoints(run_dir, config.keep_checkpoints)
    try:
        info = _newest_info(run_dir, checkpoints)
    finally:
        checkpoints.close()
    actor, _ = make_actor_critic(config.network(), int(info["observation_features"]))
    one_seed = {"actor": jax.eval_shape(actor.init, jax.random.PRNGKey(0))}
    return TrainedPolicy(config, actor, _restore_networks(run_dir, one_seed)["actor"], info)
