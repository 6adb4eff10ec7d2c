"""What a :class:`TrainConfig` builds (environments, networks, learner, the jitted iteration), and the
trained policy read back from a run directory (for ``swat_jax.eval`` and ``swat_jax.export``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from swat_jax.envs.multi_task import MultiTaskEnv
from swat_jax.morphology import StructureBatch
from swat_jax.networks import LimbNetwork, Params, check_structures, make_actor_critic
from swat_jax.runs.checkpoint import Checkpoints
from swat_jax.runs.config import ConfigError, TrainConfig, load_config
from swat_jax.td3.iteration import TrainState, init_train_state, make_train_iteration
from swat_jax.td3.learner import Learner

CONFIG_FILE = "config.json"


@dataclasses.dataclass(frozen=True)
class Experiment:
    """The fixed parts of a run: the multi-task environment of the train bodies and the TD3 learner."""

    config: TrainConfig
    env: MultiTaskEnv
    learner: Learner

    @classmethod
    def build(cls, config: TrainConfig) -> Experiment:
        """Load the bodies and build the networks; ConfigError if the network cannot take the bodies."""
        env = MultiTaskEnv(
            config.bodies(),
            config.copies,
            torso_relative_x=config.torso_relative_x,
            reference_inorder=config.reference_inorder,
        )
        network = config.network()
        try:
            check_structures(network, env.structure)
        except ValueError as error:
            raise ConfigError(f"{config.algo} cannot take the bodies of {config.env}: {error}") from error
        actor, critic = make_actor_critic(network, env.observation_features)
        return cls(config, env, Learner(actor, critic, config.td3))

    def init_state(self) -> TrainState:
        """Fresh networks, empty replay buffers and reset environments, from ``config.seed``.

        Jitted: an eager MJX reset dispatches thousands of small operations (minutes for five bodies).
        """
        return _committed(jax.jit(self._initial_state)(jax.random.PRNGKey(self.config.seed)))

    def restore_state(self, checkpoints: Checkpoints) -> tuple[TrainState, dict[str, Any]]:
        """The newest checkpoint's training state, placed exactly as :meth:`init_state` places a fresh one,
        and its info (CheckpointError if it is missing, unreadable or does not match)."""
        state, info = checkpoints.restore(self.state_shapes())
        return _committed(state), info

    def state_shapes(self) -> TrainState:
        """The shapes and dtypes of :meth:`init_state`, without allocating anything."""
        return jax.eval_shape(self._initial_state, jax.random.PRNGKey(self.config.seed))

    def _initial_state(self, rng: jax.Array) -> TrainState:
        return init_train_state(self.env, self.learner, self.config.iteration, rng)

    def iteration(self) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
        """The jitted training iteration; it consumes (donates) its input state."""
        return jax.jit(make_train_iteration(self.env, self.learner, self.config.iteration), donate_argnums=0)

    def info(self) -> dict[str, Any]:
        """What a policy needs besides its parameters, stored in every checkpoint."""
        return {
            "bodies": list(self.env.body_names),
            "max_limbs": self.env.max_limbs,
            "observation_features": self.env.observation_features,
        }


def _committed(state: TrainState) -> TrainState:
    """Every array of ``state`` committed to the default device.

    The compiled iteration, and so its persistent-cache key, differs between committed and uncommitted
    inputs (their buffers are donated differently). Restored checkpoints mix both (zero-size MJX arrays
    are rebuilt uncommitted), so fresh and resumed runs go through here to share one cache entry.
    """
    return jax.device_put(state, jax.devices()[0])


@dataclasses.dataclass(frozen=True)
class TrainedPolicy:
    """A run's actor and its newest parameters; ``act`` is deterministic (no exploration noise)."""

    config: TrainConfig
    actor: LimbNetwork
    params: Params
    info: dict[str, Any]
    """env_steps, iterations, seconds, bodies, max_limbs, observation_features of the checkpoint."""

    def act(self, observation: jax.Array, structure: StructureBatch) -> jax.Array:
        """observation [batch, limbs, F] and one body's structure slice -> actions [batch, limbs] in [-1, 1]."""
        return self.actor.apply(self.params, observation, structure)


def load_policy(run_dir: str | Path) -> TrainedPolicy:
    """The actor of the newest checkpoint of ``run_dir`` (ConfigError / CheckpointError if unusable)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"{run_dir}: no such run directory")
    config = load_config(run_dir / CONFIG_FILE)
    checkpoints = Checkpoints(run_dir, config.keep_checkpoints)
    try:
        info = checkpoints.info()
        actor, _ = make_actor_critic(config.network(), int(info["observation_features"]))
        params = checkpoints.restore_actor(jax.eval_shape(actor.init, jax.random.PRNGKey(0)))
    finally:
        checkpoints.close()
    return TrainedPolicy(config, actor, params, info)
