"""SET, the subequivariant transformer of SGRL (Chen, Han, Sun and Huang, ICML 2023), for 3D bodies.

A 3D limb's observation starts with eight 3-vectors (:func:`swat_jax.envs.observation.limb_observation_3d`,
SGRL's order): position relative to the torso, gravity, the direction to the target, linear and angular
velocity, and the world axes of the limb's x, y and z hinges. SET keeps them as a geometric stream
``Z`` [3, C] per limb beside the usual stream of scalars ``h`` [C] (the other 17 values of the
observation, and a critic's 3 actions), and builds every layer so that rotating or reflecting all input
vectors by Q in O(3) multiplies ``Z`` by Q and leaves ``h`` unchanged (the paper's O(3)-equivariance,
with gravity an input vector). With gravity held fixed, that leaves the rotations about the gravity
axis (the paper's subequivariance): the actions and Q values, scalars, do not change when the body,
its velocities and its target turn about the vertical.

The pieces, arranged as in SGRL's code:

- invariants: project the vectors to 30 channels, append the two direction vectors (gravity and the
  target direction) to make a frame ``F`` [3, 32], and read its Gram matrix ``F^T F``
  [32, 32] (1,024 invariant scalars) and ``s = |F^T F|_F + 1``, by which SGRL divides what it
  computes from them (:func:`gram_invariants`);
- attention: one set of weights per head from scalars (``h`` and an MLP of the Gram matrix), divided
  by ``s``, applied to both streams; a head's vector values are a projection of ``Z`` with the two
  direction vectors appended (:class:`SubequivariantAttention`);
- each layer: the attention's residuals, then the vectors are mixed by a [32, 32] matrix computed from
  scalars (``F M``, equivariant), and the scalars by an MLP, both divided by ``s``; post-LayerNorm on the
  scalars only (:class:`SubequivariantLayer`);
- the head: the input vectors and scalars are appended to the final streams; a critic's Q is linear in
  invariant scalars (divided by ``s``); an actor's output is one vector ``v`` per limb, and its three
  actions are ``v``'s projections on the limb's three hinge axes (:class:`SubequivariantHead`).

The scalars get SWAT's traversal embedding (SGRL's is the same: three tables of 15 rows, concatenated and
added to ``h``) and SWAT's relational bias on the first layer's logits (SGRL's relation map also has a
bias, which the softmax cancels: it is left out, as for SWAT). Padded limbs are removed as keys (SGRL runs one body at a
time and needs no mask), so they never influence a real limb.

The 32 frame channels are SGRL's constant, not a config field. SGRL's attention appends the two
direction vectors to the vector values of exactly two heads (its code runs with 2 heads only); here they
are appended to every head, which is the same at 2 heads.
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp

from swat_jax.morphology import StructureBatch
from swat_jax.networks.config import NetworkConfig
from swat_jax.networks.initialisation import Initialisation, linear
from swat_jax.networks.transformer import RelationalEmbedding, TraversalEmbedding, masked_attention_weights

GEOMETRIC_VECTORS = 8
"""3-vectors at the start of a 3D limb's observation (24 values)."""
DIRECTIONS = slice(1, 3)
"""Gravity and the unit direction to the target: the vectors appended to every frame."""
JOINT_AXES = slice(5, 8)
"""The world axes of the limb's x, y and z hinges: an actor's output vector is projected on them."""
FRAME_CHANNELS = 32
"""Channels of every frame F: 30 projected vectors and the 2 directions (SGRL's constant)."""
MOTORS = 3
"""Actions per limb of a 3D body: one per hinge axis."""


def geometric_inputs(limb_inputs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Split [batch, limbs, F] into the vectors [batch, limbs, 3, 8] (vector k is values 3k..3k+2, the
    columns SGRL's reshape makes) and the scalars [batch, limbs, F - 24]."""
    if limb_inputs.shape[-1] <= 3 * GEOMETRIC_VECTORS:
        raise ValueError(
            f"SET needs a 3D body's observation (8 vectors, then scalars); got {limb_inputs.shape[-1]} values "
            "a limb: use a 3D-SGRL body set, or another architecture for planar bodies"
        )
    vectors = limb_inputs[..., : 3 * GEOMETRIC_VECTORS]
    vectors = vectors.reshape(*limb_inputs.shape[:-1], GEOMETRIC_VECTORS, 3)
    return jnp.swapaxes(vectors, -1, -2), limb_inputs[..., 3 * GEOMETRIC_VECTORS :]


def frame(vectors: jax.Array, directions: jax.Array, initialisation: Initialisation, name: str) -> jax.Array:
    """F = [Z W, directions]: vectors [..., 3, C] projected to 30 channels (a linear map without bias,
    equivariant) with directions [..., 3, 2] appended -> [..., 3, 32]. Called inside a compact method."""
    channels = FRAME_CHANNELS - directions.shape[-1]
    projected = linear(vectors, channels, initialisation, use_bias=False, name=name)
    return jnp.concatenate([projected, directions], axis=-1)


def gram_invariants(frame_vectors: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A frame [..., 3, 32] -> its Gram matrix F^T F flattened [..., 1024] (row-major) and the divisor
    s = |F^T F|_F + 1 [..., 1]: both invariant under any Q in O(3) acting on the frame's 3 rows."""
    gram = jnp.einsum("...ci,...cj->...ij", frame_vectors, frame_vectors)
    scale = jnp.sqrt(jnp.sum(gram**2, axis=(-2, -1)))[..., None] + 1.0
    return gram.reshape(*gram.shape[:-2], -1), scale


class InvariantMLP(nn.Module):
    """Linear, ReLU, linear on scalars: [..., in] -> [..., outputs]."""

    hidden: int
    outputs: int
    initialisation: Initialisation = "flax"

    @nn.compact
    def __call__(self, scalars: jax.Array) -> jax.Array:
        hidden = nn.relu(linear(scalars, self.hidden, self.initialisation, name="hidden"))
        return linear(hidden, self.outputs, self.initialisation, name="output")


class FrameMixing(nn.Module):
    """The equivariant update F M: a frame [..., 3, 32] times a [32, 32] matrix computed from scalars
    [..., S] by an MLP and divided by ``scale`` [..., 1] -> [..., 3, 32]."""

    hidden: int
    initialisation: Initialisation = "flax"

    @nn.compact
    def __call__(self, frame_vectors: jax.Array, scalars: jax.Array, scale: jax.Array) -> jax.Array:
        mixing = InvariantMLP(self.hidden, FRAME_CHANNELS**2, self.initialisation, name="mixing")(scalars)
        mixing = (mixing / scale).reshape(*scalars.shape[:-1], FRAME_CHANNELS, FRAME_CHANNELS)
        return jnp.einsum("...ci,...ij->...cj", frame_vectors, mixing)


class SubequivariantAttention(nn.Module):
    """Multi-head attention over limbs whose weights, from invariant scalars, move both streams.

    Queries, keys and values are linear maps of [MLP(Gram of the vectors' frame), h] divided by s;
    logits q.k / sqrt(2 width / heads) plus the relational bias, padded limbs removed as keys. A head's
    vector values are (2 width / heads - 2) channels of Z with the two directions appended.
    """

    config: NetworkConfig

    @nn.compact
    def __call__(
        self,
        vectors: jax.Array,
        tokens: jax.Array,
        directions: jax.Array,
        limb_mask: jax.Array,
        relation_bias: jax.Array | None,
    ) -> tuple[jax.Array, jax.Array]:
        """vectors [batch, limbs, 3, width], tokens [batch, limbs, width], directions [batch, limbs, 3, 2],
        limb_mask [limbs], relation_bias [heads, limbs, limbs] or None -> (vectors, tokens) updates."""
        config, init = self.config, self.config.initialisation
        heads, width = config.heads, config.width
        head_width = 2 * width // heads
        gram, scale = gram_invariants(frame(vectors, directions, init, "gram_frame"))
        geometric = InvariantMLP(2 * width, width, init, name="gram_mlp")(gram)
        scalars = jnp.concatenate([geometric, tokens], axis=-1)

        def project(name: str) -> jax.Array:
            projected = linear(scalars, 2 * width, init, name=name) / scale
            return projected.reshape(*tokens.shape[:-1], heads, head_width)

        queries = project("query") / math.sqrt(head_width)
        logits = jnp.einsum("bqhe,bkhe->bhqk", queries, project("key"))
        weights = masked_attention_weights(logits, limb_mask, relation_bias)
        attended = jnp.einsum("bhqk,bkhe->bqhe", weights, project("value")).reshape(*tokens.shape[:-1], -1)
        vector_values = linear(vectors, 2 * width - 2 * heads, init, use_bias=False, name="vector_value")
        vector_values = vector_values.reshape(*vectors.shape[:-1], heads, head_width - 2)
        repeated = jnp.broadcast_to(directions[..., None, :], (*directions.shape[:-1], heads, 2))
        vector_values = jnp.concatenate([vector_values, repeated], axis=-1)
        attended_vectors = jnp.einsum("bhqk,bkche->bqche", weights, vector_values)
        attended_vectors = attended_vectors.reshape(*vectors.shape[:-1], -1)
        return (
            linear(attended_vectors, width, init, use_bias=False, name="vector_output"),
            linear(attended, width, init, name="output"),
        )


class SubequivariantLayer(nn.Module):
    """One SET layer: attention residuals on both streams (LayerNorm on h), then, from the attention's vector
    output A: Z += (F_A M) W with M from [MLP(Gram of F'_A), h] / s, and h = LN(h + MLP([...]) / s)."""

    config: NetworkConfig

    @nn.compact
    def __call__(
        self,
        vectors: jax.Array,
        tokens: jax.Array,
        directions: jax.Array,
        limb_mask: jax.Array,
        relation_bias: jax.Array | None,
    ) -> tuple[jax.Array, jax.Array]:
        """vectors [batch, limbs, 3, width], tokens [batch, limbs, width] -> both updated."""
        config, init = self.config, self.config.initialisation
        epsilon = config.layer_norm_epsilon
        attended_vectors, attended = SubequivariantAttention(config, name="attention")(
            vectors, tokens, directions, limb_mask, relation_bias
        )
        vectors = vectors + attended_vectors
        tokens = nn.LayerNorm(epsilon, name="attention_norm")(tokens + attended)
        gram, scale = gram_invariants(frame(attended_vectors, directions, init, "gram_frame"))
        geometric = InvariantMLP(config.feedforward, config.width, init, name="gram_mlp")(gram)
        scalars = jnp.concatenate([geometric, tokens], axis=-1)
        mixing_frame = frame(attended_vectors, directions, init, "mixing_frame")
        mixed = FrameMixing(config.feedforward, init, name="frame_mixing")(mixing_frame, scalars, scale)
        vectors = vectors + linear(mixed, config.width, init, use_bias=False, name="vector_feedforward")
        transformed = InvariantMLP(config.feedforward, config.width, init, name="feedforward")(scalars)
        tokens = nn.LayerNorm(epsilon, name="feedforward_norm")(tokens + transformed / scale)
        return vectors, tokens


class SubequivariantTransformer(nn.Module):
    """SET over one body's limbs: an actor's 3 actions per limb (``outputs`` 3) or a critic's Q (1)."""

    config: NetworkConfig
    outputs: int = 1
    """1: one invariant value per limb (a critic); 3: projections on the limb's hinge axes (an actor)."""

    @nn.compact
    def __call__(self, limb_inputs: jax.Array, structure: StructureBatch) -> jax.Array:
        """limb_inputs [batch, limbs, F] (a 3D observation, a critic's with its 3 actions appended) and one
        body's structure slice -> [batch, limbs] (``outputs`` 1) or [batch, limbs, 3]; padded limbs hold
        unspecified values. The final vector stream is sown as ``intermediates/vector_features``."""
        if self.outputs not in (1, MOTORS):
            raise ValueError(
                f"SET computes 1 value (a critic) or {MOTORS} actions a limb, not {self.outputs}"
            )
        config, init = self.config, self.config.initialisation
        input_vectors, input_scalars = geometric_inputs(limb_inputs)
        directions = input_vectors[..., DIRECTIONS]
        scaling = math.sqrt(config.width)
        vectors = linear(
            input_vectors, config.width, init, "limb_encoder", use_bias=False, name="vector_encoder"
        )
        vectors = vectors * scaling
        tokens = linear(input_scalars, config.width, init, "limb_encoder", name="limb_encoder") * scaling
        if config.traversals:
            embedding = TraversalEmbedding(config, name="traversal_embedding")
            tokens = tokens + embedding(structure.traversal_positions)
        relation_bias = (
            RelationalEmbedding(config, name="relational_embedding")(structure.relations)
            if config.relations
            else None
        )
        for layer in range(config.layers):
            layer_bias = relation_bias if layer == 0 or config.relation_bias_in_every_layer else None
            vectors, tokens = SubequivariantLayer(config, name=f"layer_{layer}")(
                vectors, tokens, directions, structure.limb_mask, layer_bias
            )
        if config.final_norm:
            tokens = nn.LayerNorm(config.layer_norm_epsilon, name="final_norm")(tokens)
        self.sow("intermediates", "vector_features", vectors)
        vectors = jnp.concatenate([input_vectors, vectors], axis=-1)
        tokens = jnp.concatenate([input_scalars, tokens], axis=-1)
        return SubequivariantHead(config, self.outputs, name="head")(
            vectors, tokens, directions, input_vectors
        )


class SubequivariantHead(nn.Module):
    """The decoder: [MLP(Gram of the vectors' frame), MLP(h)] -> a critic's value / s, or an actor's vector
    v = (F M) w with M from them / s, projected on the three hinge axes."""

    config: NetworkConfig
    outputs: int = 1

    @nn.compact
    def __call__(
        self, vectors: jax.Array, tokens: jax.Array, directions: jax.Array, input_vectors: jax.Array
    ) -> jax.Array:
        """vectors [batch, limbs, 3, 8 + width], tokens [batch, limbs, F - 24 + width], directions
        [batch, limbs, 3, 2], input_vectors [batch, limbs, 3, 8] -> [batch, limbs] or [batch, limbs, 3]."""
        config, init = self.config, self.config.initialisation
        gram, scale = gram_invariants(frame(vectors, directions, init, "gram_frame"))
        geometric = InvariantMLP(config.width, config.width, init, name="gram_mlp")(gram)
        scalars = InvariantMLP(config.width, config.width, init, name="scalar_mlp")(tokens)
        decoded = jnp.concatenate([geometric, scalars], axis=-1)
        if self.outputs == 1:
            return (linear(decoded, 1, init, name="value") / scale)[..., 0]
        mixing_frame = frame(vectors, directions, init, "mixing_frame")
        mixed = FrameMixing(2 * config.width, init, name="frame_mixing")(mixing_frame, decoded, scale)
        output_vector = linear(mixed, 1, init, use_bias=False, name="output_vector")[..., 0]
        return jnp.einsum("...ck,...c->...k", input_vectors[..., JOINT_AXES], output_vector)
