"""TD3 actor and twin critic over limbs, for any architecture of the config (paper section 4.3).

The structure is an input, not state: ``network.apply(params, limb_obs, structure)`` takes one
body's slice of a :class:`~swat_jax.morphology.StructureBatch`, so one compiled function serves every
body and ``jax.vmap`` over the task axis runs a whole environment set::

    actor, critic = make_actor_critic(network_config("swat"), obs_features=19)
    actor_params = actor.init(jax.random.key(0))
    actions = jax.vmap(actor.apply, in_axes=(None, 0, 0))(actor_params, obs, batch)  # obs [K, B, L, F]

Outputs on padded limbs are zero. A limb acts with M values, one per hinge slot: M = 1 for planar bodies
(actions [batch, limbs]) and 3 for 3D bodies (actions [batch, limbs, 3], zero where a limb has no hinge:
the torso, and the slots of :attr:`~swat_jax.morphology.StructureBatch.motor_mask` that are False).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from swat_jax.morphology import StructureBatch
from swat_jax.networks.config import NetworkConfig
from swat_jax.networks.initialisation import copy_first_layer
from swat_jax.networks.observation_stats import NORMALISER, STATS, ObservationNormaliser
from swat_jax.networks.smp import SharedModularCritic, SharedModularPolicy, most_children
from swat_jax.networks.subequivariant import MOTORS, SubequivariantTransformer
from swat_jax.networks.transformer import StructureAwareTransformer

Params = Any
"""A Flax variables pytree: ``{"params": {...}}``, and ``"observation_stats"`` with observation
normalisation."""


def limb_network(config: NetworkConfig, name: str, outputs: int = 1) -> nn.Module:
    """The per-limb network of the configured architecture: (limb_inputs, structure) -> [batch, limbs]
    (``outputs`` > 1: [batch, limbs, outputs])."""
    if config.architecture == "smp":
        return SharedModularPolicy(config, outputs, name=name)
    if config.architecture == "set":
        return SubequivariantTransformer(config, outputs, name=name)
    return StructureAwareTransformer(config, outputs, name=name)


def motors_per_limb(structure: StructureBatch) -> int:
    """M of a structure slice (static: the last axis of its motor mask)."""
    return structure.motor_mask.shape[-1]


def action_mask(structure: StructureBatch) -> jax.Array:
    """Where a body's actions may be nonzero: limb_mask [limbs] for planar bodies (the torso's action is
    computed and ignored by the environment, as in the paper's code), motor_mask [limbs, M] in 3D."""
    return structure.limb_mask if motors_per_limb(structure) == 1 else structure.motor_mask


def motor_slots(structure: StructureBatch) -> jax.Array:
    """The action slots that drive a motor, in the actions' shape: [limbs] planar (M = 1), [limbs, M] in 3D
    (:attr:`~swat_jax.morphology.StructureBatch.motor_mask`: not the torso, not padding)."""
    return structure.motor_mask if motors_per_limb(structure) > 1 else structure.motor_mask[..., 0]


def limb_action_features(actions: jax.Array) -> jax.Array:
    """Each limb's actions as input features: [batch, limbs] -> [batch, limbs, 1]; [batch, limbs, M] as is."""
    return actions[..., None] if actions.ndim == 2 else actions


def normalised(config: NetworkConfig, limb_obs: jax.Array, structure: StructureBatch) -> jax.Array:
    """``limb_obs`` [batch, limbs, F] standardised by the network's observation statistics when the config
    normalises observations, else as given (called inside an actor's or critic's compact method)."""
    if not config.observation_normalisation:
        return limb_obs
    return ObservationNormaliser(name=NORMALISER)(limb_obs, structure.limb_mask)


class Actor(nn.Module):
    """Deterministic policy: M actions in [-1, 1] per limb (tanh of the per-limb output)."""

    config: NetworkConfig

    @nn.compact
    def __call__(self, limb_obs: jax.Array, structure: StructureBatch, squash: bool = True) -> jax.Array:
        """limb_obs [batch, limbs, features], structure: one body's slice -> actions [batch, limbs]
        (M = 1) or [batch, limbs, M]; with ``squash`` False the outputs before the tanh (the actions are
        their tanh). 0 at padded limbs and motors."""
        if self.config.architecture == "set" and motors_per_limb(structure) != MOTORS:
            raise ValueError(
                f"SET acts on 3D bodies ({MOTORS} motors a limb), not {motors_per_limb(structure)}"
            )
        limb_obs = normalised(self.config, limb_obs, structure)
        outputs = limb_network(self.config, "policy", motors_per_limb(structure))(limb_obs, structure)
        return jnp.where(action_mask(structure), jnp.tanh(outputs) if squash else outputs, 0.0)


class Critic(nn.Module):
    """Twin Q networks; each limb's input is its observation concatenated with its action.

    Transformers: two independent networks, one Q value per limb, each limb with its own TD target
    (:mod:`swat_jax.td3.learner`), or with ``atoms`` (SWAT and AMORPHEUS) the logits of a distribution of
    each limb's return over that many atoms (C51, Bellemare et al. 2017, as FastTD3's critic). SET: the same
    with one invariant Q value per limb (:mod:`swat_jax.networks.subequivariant`). SMP: one message passing
    with two heads, whose per-limb outputs sum to the body's Q
    (:class:`~swat_jax.networks.smp.SharedModularCritic`).
    """

    config: NetworkConfig
    atoms: int = 0
    """0: one Q value per limb; N >= 2: N logits per limb (SWAT and AMORPHEUS only)."""

    def __post_init__(self) -> None:
        if self.atoms and (self.atoms < 2 or self.config.architecture in ("smp", "set")):
            raise ValueError(
                f"a distributional critic needs 2 or more atoms and a transformer (swat or amorpheus); got "
                f"{self.atoms} atoms with {self.config.architecture}"
            )
        super().__post_init__()

    @nn.compact
    def __call__(
        self, limb_obs: jax.Array, actions: jax.Array, structure: StructureBatch
    ) -> tuple[jax.Array, jax.Array]:
        """limb_obs [batch, limbs, features], actions [batch, limbs] or [batch, limbs, M] -> (q1, q2), each
        [batch, limbs], or [batch, limbs, atoms] logits with atoms (zero on padded limbs)."""
        limb_obs = normalised(self.config, limb_obs, structure)
        actions = limb_action_features(actions)
        if self.config.architecture == "smp":
            q_values = SharedModularCritic(self.config, name="q")(limb_obs, actions, structure)
        else:
            limb_inputs = jnp.concatenate([limb_obs, actions], axis=-1)
            q_values = (
                limb_network(self.config, name, max(1, self.atoms))(limb_inputs, structure)
                for name in ("q1", "q2")
            )
        mask = structure.limb_mask[:, None] if self.atoms else structure.limb_mask
        q1, q2 = (jnp.where(mask, q, 0.0) for q in q_values)
        return q1, q2


def torso_only_structure(motors: int = 1) -> StructureBatch:
    """One body's slice for a body of a single limb with ``motors`` action slots: enough to initialise any
    network's parameters.

    No parameter shape depends on the number of limbs, so these parameters serve every body (of M =
    ``motors``).
    """
    return StructureBatch(
        limb_mask=np.ones(1, bool),
        parents=np.full(1, -1, np.int32),
        traversal_positions=np.zeros((1, 3), np.int32),
        relations=np.zeros((1, 1, 3), np.float32),
        limb_types=np.zeros(1, np.int32),
        motor_mask=np.zeros((1, motors), bool),
        num_limbs=np.int32(1),
    )


@dataclasses.dataclass(frozen=True)
class LimbNetwork:
    """A Flax module with its input size: ``init(rng)`` and ``apply(params, *inputs, structure)``."""

    module: nn.Module
    obs_features: int
    motors: int = 1
    """M, actions per limb (1 planar, 3 in 3D)."""

    def init(self, rng: jax.Array) -> Params:
        """Fresh parameters ({"params": ...}, and the observation statistics of a network that normalises)
        for observations of ``obs_features`` values a limb."""
        structure = torso_only_structure(self.motors)
        limb_obs = jnp.zeros((1, 1, self.obs_features), jnp.float32)
        actions = jnp.zeros((1, 1) if self.motors == 1 else (1, 1, self.motors))
        inputs = (limb_obs, structure) if isinstance(self.module, Actor) else (limb_obs, actions, structure)
        variables = self.module.init(rng, *inputs)
        params = variables["params"]
        if self.module.config.initialisation == "original":
            params = copy_first_layer(params)
        return {"params": params, **({STATS: variables[STATS]} if STATS in variables else {})}

    def apply(self, params: Params, *inputs: Any, **kwargs: Any) -> Any:
        """``module.apply``: actor (params, limb_obs, structure), critic (params, limb_obs, actions, structure)."""
        return self.module.apply(params, *inputs, **kwargs)


def make_actor_critic(
    config: NetworkConfig, obs_features: int, atoms: int = 0, motors: int = 1
) -> tuple[LimbNetwork, LimbNetwork]:
    """The actor and the twin critic of ``config`` for ``obs_features`` observation values and ``motors``
    actions per limb; a distributional critic of ``atoms`` atoms per limb if not 0 (:class:`Critic`)."""
    return (
        LimbNetwork(Actor(config), obs_features, motors),
        LimbNetwork(Critic(config, atoms), obs_features, motors),
    )


def param_count(params: Params) -> int:
    """Number of scalars in a parameter pytree."""
    return sum(int(np.prod(leaf.shape)) for leaf in jax.tree.leaves(params))


class ArchitectureMismatch(ValueError):
    """Bodies a network's architecture cannot take at any size (SET and a planar body); the message says
    what to use instead."""


class StructureMismatch(ValueError):
    """Bodies a network cannot take; ``setting`` (a NetworkConfig field) would need to be at least ``needed``."""

    def __init__(self, problem: str, setting: str, needed: int):
        super().__init__(problem)
        self.setting = setting
        self.needed = needed


def check_structures(
    config: NetworkConfig, structures: StructureBatch, names: Sequence[str] | None = None
) -> None:
    """Host-side check (not jittable) that ``config`` can take these bodies; raises StructureMismatch if not.

    Inside jit an out-of-range traversal position or an extra child cannot raise: traversal
    positions must be below ``max_traversal_positions`` (transformers: one position per limb, so
    a body needs as many as it has limbs) and no limb may have more than ``max_children``
    children (SMP). ``names`` (one per body of the batch) name the body in the message. SET takes 3D bodies
    only (its geometric stream reads the 3-vectors of their observation): ArchitectureMismatch otherwise.
    """
    names = names or [f"body {index}" for index in range(structures.limb_mask.shape[0])]
    if config.architecture == "set" and motors_per_limb(structures) != MOTORS:
        raise ArchitectureMismatch(
            f"SET (--algo set) is 3D-only and {names[0]} is a planar body (one motor a limb, no 3-vectors in "
            "its observation); train SET on a 3D-SGRL set (3d_hopper, 3d_walker, 3d_humanoid, 3d_cheetah, "
            "3d_whh, 3d_cwhh) or use --algo swat, amorpheus or smp for planar bodies"
        )
    if config.architecture == "smp":
        children = [most_children(parents) for parents in np.asarray(structures.parents)]
        worst = int(np.argmax(children))
        if children[worst] > config.max_children:
            raise StructureMismatch(
                f"{names[worst]} has a limb with {children[worst]} children, more than SMP's "
                f"{config.max_children} child slots (max_children)",
                "max_children",
                children[worst],
            )
    elif config.traversals:
        limbs = np.asarray(structures.limb_mask).sum(axis=-1)
        worst = int(np.argmax(limbs))
        if limbs[worst] > config.max_traversal_positions:
            raise StructureMismatch(
                f"{names[worst]} has {limbs[worst]} limbs, more than the {config.max_traversal_positions} "
                "positions of each traversal table (max_traversal_positions)",
                "max_traversal_positions",
                int(limbs[worst]),
            )
