"""Shared Modular Policies (SMP, Huang et al. 2020), the message-passing baseline of the paper.

Modules shared by all limbs pass messages both ways along the tree (paper section 2.2):

1. Bottom-up: each limb's up message is computed from its own input and its children's up
   messages, concatenated in child order and zero-padded to ``max_children`` slots.
2. Top-down: each limb reads the slot of its parent's down message that belongs to it (the torso
   reads zeros) and, from that and its own up message, computes one down message per child slot
   and its output value.

The actor reads tanh(concat(up message, parent message)) with its output module; the critic runs one
message passing over concat(observation, action) for both Q heads, and each head reads
concat(up message, action, parent message), as in the original SWAT repository's SMP.

Child-slot convention: the children of a limb fill slots 0, 1, ... in increasing limb index, which
is MJCF pre-order; unused slots are zero. A limb with more than ``max_children`` children would lose
the extra ones, so :func:`most_children` lets the caller check bodies on the host first.

Vectorised over the padded tree: limbs are in pre-order, so a parent's index is below its
children's. The bottom-up pass is a ``scan`` over limbs from the last to the first, the top-down
pass a ``scan`` from the first to the last; each step updates one limb for the whole batch, so
every limb is computed once per pass, as in the reference recursion. Children and parents are
found through a one-hot child-slot matrix built from ``parents``, not by Python recursion.
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from swat_jax.morphology import StructureBatch
from swat_jax.networks.config import NetworkConfig
from swat_jax.networks.initialisation import Initialisation, linear

NORMALIZE_EPSILON = 1e-12


def child_slot_matrix(parents: jax.Array, limb_mask: jax.Array, max_children: int) -> jax.Array:
    """One-hot child slots: ``slots[p, s, i] = 1`` when limb i is the s-th child of limb p.

    Args:
        parents: [limbs] int parent index, -1 for the torso and for padding.
        limb_mask: [limbs] bool, True for real limbs.
        max_children: number of slots s.

    Returns:
        [limbs, max_children, limbs] float32; children beyond ``max_children`` have no slot.
    """
    limbs = parents.shape[0]
    is_child = (parents[None, :] == jnp.arange(limbs)[:, None]) & limb_mask[None, :]
    slot = jnp.cumsum(is_child, axis=1) - 1
    slots = jax.nn.one_hot(slot, max_children) * is_child[..., None]
    return jnp.transpose(slots, (0, 2, 1))


def most_children(parents: np.ndarray) -> int:
    """Host-side check: the largest number of children of any limb in ``parents`` ([..., limbs])."""
    parents = np.asarray(parents).reshape(-1, np.shape(parents)[-1])
    counts = [np.bincount(row[row >= 0], minlength=1).max(initial=0) for row in parents]
    return int(max(counts))


def normalize(vectors: jax.Array) -> jax.Array:
    """L2-normalise the last axis (SMP normalises every message); the gradient is finite at zero."""
    squared_norm = jnp.sum(vectors**2, axis=-1, keepdims=True)
    return vectors * jax.lax.rsqrt(jnp.maximum(squared_norm, NORMALIZE_EPSILON**2))


class MLP(nn.Module):
    """Dense layers with an activation between them; the last layer is linear."""

    hidden: tuple[int, ...]
    outputs: int
    activation: str = "relu"
    initialisation: Initialisation = "flax"

    @nn.compact
    def __call__(self, inputs: jax.Array) -> jax.Array:
        """[..., in] -> [..., outputs]."""
        activation = getattr(jax.nn, self.activation)
        hidden = inputs
        for size in self.hidden:
            hidden = activation(linear(hidden, size, self.initialisation))
        return linear(hidden, self.outputs, self.initialisation)


class BottomUpStep(nn.Module):
    """One step of the bottom-up pass: the up message of one limb, for the whole batch."""

    config: NetworkConfig

    @nn.compact
    def __call__(
        self, up_messages: jax.Array, limb: jax.Array, limb_inputs: jax.Array, slots: jax.Array
    ) -> tuple[jax.Array, None]:
        """up_messages [batch, limbs, message] (carry), limb: scalar index, limb_inputs [batch, limbs,
        features], slots [limbs, max_children, limbs] -> (updated up_messages, None)."""
        config = self.config
        children_messages = jnp.einsum("sj,bjm->bsm", slots[limb], up_messages)
        children_messages = children_messages.reshape(up_messages.shape[0], -1)
        own_input = jnp.take(limb_inputs, limb, axis=1)
        encoded = normalize(
            linear(own_input, config.up_hidden[0], config.initialisation, name="input_encoder")
        )
        hidden = jnp.tanh(jnp.concatenate([encoded, children_messages], axis=-1))
        message = normalize(
            MLP(config.up_hidden[1:], config.message_width, "tanh", config.initialisation, name="message")(
                hidden
            )
        )
        return up_messages.at[:, limb].set(message), None


class TopDownStep(nn.Module):
    """One step of the top-down pass: the down messages of one limb to its child slots."""

    config: NetworkConfig

    @nn.compact
    def __call__(
        self, down_messages: jax.Array, limb: jax.Array, up_messages: jax.Array, slots: jax.Array
    ) -> tuple[jax.Array, None]:
        """down_messages [batch, limbs, max_children * message] (carry), limb: scalar index,
        up_messages [batch, limbs, message], slots [limbs, max_children, limbs]."""
        config = self.config
        parent_message = jnp.take(parent_messages(down_messages, slots, config), limb, axis=1)
        own_message = jnp.take(up_messages, limb, axis=1)
        hidden = jnp.tanh(jnp.concatenate([own_message, parent_message], axis=-1))
        outgoing = MLP(
            config.down_hidden,
            config.max_children * config.message_width,
            initialisation=config.initialisation,
            name="messages",
        )(hidden)
        return down_messages.at[:, limb].set(normalize(outgoing)), None


def parent_messages(down_messages: jax.Array, slots: jax.Array, config: NetworkConfig) -> jax.Array:
    """For every limb, the slot of its parent's down message addressed to it (zeros for the torso and padding).

    Args:
        down_messages: [batch, limbs, max_children * message].
        slots: [limbs, max_children, limbs] child-slot matrix (:func:`child_slot_matrix`).

    Returns:
        [batch, limbs, message].
    """
    by_slot = down_messages.reshape(*down_messages.shape[:2], config.max_children, config.message_width)
    return jnp.einsum("psi,bpsm->bim", slots, by_slot)


def _limb_scan(step: type[nn.Module]) -> type[nn.Module]:
    """``step`` scanned over limb indices, with its parameters shared by every limb."""
    return nn.scan(
        step,
        variable_broadcast="params",
        split_rngs={"params": False},
        in_axes=(0, nn.broadcast, nn.broadcast),
    )


class MessagePassing(nn.Module):
    """SMP's two passes over one body's padded tree: every limb's up message and the slot of its
    parent's down message addressed to it."""

    config: NetworkConfig

    @nn.compact
    def __call__(self, limb_inputs: jax.Array, structure: StructureBatch) -> tuple[jax.Array, jax.Array]:
        """limb_inputs [batch, limbs, features]; structure: one body's slice of a StructureBatch
        (parents [limbs] in pre-order, limb_mask [limbs]) -> (up messages [batch, limbs, message],
        parent messages [batch, limbs, message])."""
        config = self.config
        batch, limbs = limb_inputs.shape[:2]
        slots = child_slot_matrix(structure.parents, structure.limb_mask, config.max_children)
        up_messages, _ = _limb_scan(BottomUpStep)(config, name="bottom_up")(
            jnp.zeros((batch, limbs, config.message_width), limb_inputs.dtype),
            jnp.arange(limbs - 1, -1, -1),
            limb_inputs,
            slots,
        )
        down_messages, _ = _limb_scan(TopDownStep)(config, name="top_down")(
            jnp.zeros((batch, limbs, config.max_children * config.message_width), limb_inputs.dtype),
            jnp.arange(limbs),
            up_messages,
            slots,
        )
        return up_messages, parent_messages(down_messages, slots, config)


class SharedModularPolicy(nn.Module):
    """SMP's actor network: message passing over the limbs' observations, then a shared output module
    on tanh(concat(up message, parent message)); one value per limb (``outputs`` > 1: that many, one per
    hinge of a 3D limb)."""

    config: NetworkConfig
    outputs: int = 1

    @nn.compact
    def __call__(self, limb_inputs: jax.Array, structure: StructureBatch) -> jax.Array:
        """limb_inputs [batch, limbs, features], structure: one body's slice -> [batch, limbs], or [batch,
        limbs, outputs] with ``outputs`` > 1 (padded limbs unspecified)."""
        up_messages, from_parent = MessagePassing(self.config, name="messages")(limb_inputs, structure)
        hidden = jnp.tanh(jnp.concatenate([up_messages, from_parent], axis=-1))
        values = MLP(
            self.config.down_hidden, self.outputs, initialisation=self.config.initialisation, name="output"
        )(hidden)
        return values[..., 0] if self.outputs == 1 else values


class SharedModularCritic(nn.Module):
    """SMP's twin critic as in the original code: ONE message passing over concat(observation, action)
    serves both Q heads, and each head reads concat(up message, action, parent message) (no tanh).
    The body's Q is the sum of its limbs' head outputs (the learner sums them,
    :attr:`NetworkConfig.sums_limb_values`)."""

    config: NetworkConfig

    @nn.compact
    def __call__(
        self, limb_obs: jax.Array, actions: jax.Array, structure: StructureBatch
    ) -> tuple[jax.Array, jax.Array]:
        """limb_obs [batch, limbs, features], actions [batch, limbs, M] (M = 1 for planar bodies) -> per-limb
        (q1, q2), each [batch, limbs] (padded limbs unspecified)."""
        limb_inputs = jnp.concatenate([limb_obs, actions], axis=-1)
        up_messages, from_parent = MessagePassing(self.config, name="messages")(limb_inputs, structure)
        head_inputs = jnp.concatenate([up_messages, actions, from_parent], axis=-1)
        q1, q2 = (
            MLP(self.config.down_hidden, 1, initialisation=self.config.initialisation, name=name)(
                head_inputs
            )[..., 0]
            for name in ("q1", "q2")
        )
        return q1, q2
