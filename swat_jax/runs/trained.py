"""A run's networks read back from its checkpoints: the trained policy (for eval, export and the figures),
the networks another run starts from (``--init-from``), and the checks that they fit."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax

from swat_jax.envs.observation import body_features
from swat_jax.morphology import Morphology, StructureBatch, load
from swat_jax.networks import LimbNetwork, Params, StructureMismatch, TaskSet, make_actor_critic, task_set
from swat_jax.runs.checkpoint import CheckpointError, CheckpointInfo, Checkpoints
from swat_jax.runs.config import CONFIG_FILE, ConfigError, TrainConfig, load_config
from swat_jax.td3.learner import LearnerState


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


def restore_networks(run_dir: Path, one_seed: dict[str, Any]) -> dict[str, Any]:
    """The items of ``one_seed`` (single-seed shapes, see :func:`network_items`) from the newest checkpoint
    of ``run_dir``, with the run's seed axis in front (CheckpointError if there is none)."""
    checkpoints = Checkpoints(run_dir)
    try:
        seeds = len(newest_info(run_dir, checkpoints).seeds)
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


def newest_info(run_dir: Path, checkpoints: Checkpoints) -> CheckpointInfo:
    """The info of the newest checkpoint (CheckpointError if there is none or it predates the seed axis)."""
    if checkpoints.latest_step() is None:
        raise CheckpointError(
            f"{run_dir} has no checkpoint yet, so there is no trained policy to load: training writes "
            "one every --checkpoint-interval steps, at its end and when it is stopped"
        )
    return checkpoints.info()


INITIAL_ONLY = ("initialisation",)
"""NetworkConfig fields that only say how fresh weights are drawn: a transfer replaces the weights, so the
two runs may differ in them."""


def check_transfer(config: TrainConfig, observation_features: int) -> None:
    """ConfigError, naming both runs, if run ``config.init_from``'s networks cannot start this run."""
    source_dir = Path(config.init_from)
    if not source_dir.is_dir():
        raise ConfigError(f"--init-from {source_dir}: no such run directory")
    source = load_config(source_dir / CONFIG_FILE)
    checkpoints = Checkpoints(source_dir)
    try:
        info = newest_info(source_dir, checkpoints)
    finally:
        checkpoints.close()
    theirs, ours = source.network_config(), config.network_config()
    problems = [
        f"{field.name} {getattr(theirs, field.name)!r} there, {getattr(ours, field.name)!r} here"
        for field in dataclasses.fields(theirs)
        if field.name not in INITIAL_ONLY and getattr(theirs, field.name) != getattr(ours, field.name)
    ]
    if info.observation_features != observation_features:
        problems.append(
            f"{info.observation_features} observation features per limb there, {observation_features} "
            "here (another family vocabulary)"
        )
    if config.init_seed_index >= len(info.seeds):
        problems.append(
            f"--init-seed-index {config.init_seed_index}, but it has {len(info.seeds)} seeds "
            f"({', '.join(map(str, info.seeds))})"
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
    info: CheckpointInfo
    """What the checkpoint says about itself (steps trained, seeds, bodies, observation features)."""

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seed of each slice of ``params``."""
        return self.info.seeds

    def seed_params(self, seed_index: int) -> Params:
        """The parameters of the ``seed_index``-th seed (ConfigError naming the valid range if out of it)."""
        if not 0 <= seed_index < len(self.seeds):
            raise ConfigError(
                f"--seed-index {seed_index}: {self.config.directory()} holds {len(self.seeds)} seeds "
                f"({', '.join(map(str, self.seeds))}); use an index from 0 to {len(self.seeds) - 1}"
            )
        return jax.tree_util.tree_map(lambda leaf: leaf[seed_index], self.params)

    def task_set(self, bodies: Sequence[Morphology | str | Path], max_limbs: int | None = None) -> TaskSet:
        """The bodies (names, MJCF paths or loaded) padded and checked for this policy: ValueError naming the
        body and the fix if a body's observation has another width than the policy was trained on (another
        family vocabulary), or if the policy's network cannot take it (traversal positions, child slots)."""
        loaded = [body if isinstance(body, Morphology) else load(body) for body in bodies]
        for body in loaded:
            features = body_features(body)
            if features != self.info.observation_features:
                raise ValueError(
                    f"{body.name}: {features} observation features per limb, the policy was trained on "
                    f"{self.info.observation_features} (another family vocabulary); use bodies of the families "
                    f"of {self.config.directory()}"
                )
        try:
            return task_set(
                loaded,
                self.config.network_config(),
                max_limbs=max_limbs,
                reference_inorder=self.config.network.reference_inorder,
            )
        except StructureMismatch as error:
            raise ValueError(
                f"{error}: the policy of {self.config.directory()} cannot take it "
                f"({self.config.structure_fix(error)})"
            ) from error

    def act(self, observation: jax.Array, structure: StructureBatch, seed_index: int = 0) -> jax.Array:
        """observation [batch, limbs, F] and one body's structure slice -> actions [batch, limbs] ([batch,
        limbs, M] in 3D) in [-1, 1]."""
        return self.actor.apply(self.seed_params(seed_index), observation, structure)


def load_policy(run_dir: str | Path) -> TrainedPolicy:
    """The actor of the newest checkpoint of ``run_dir``, every seed (ConfigError / CheckpointError if unusable)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"{run_dir}: no such run directory")
    config = load_config(run_dir / CONFIG_FILE)
    checkpoints = Checkpoints(run_dir, config.keep_checkpoints)
    try:
        info = newest_info(run_dir, checkpoints)
    finally:
        checkpoints.close()
    actor, _ = make_actor_critic(
        config.network_config(), info.observation_features, motors=info.motors_per_limb
    )
    one_seed = {"actor": jax.eval_shape(actor.init, jax.random.PRNGKey(0))}
    return TrainedPolicy(config, actor, restore_networks(run_dir, one_seed)["actor"], info)
