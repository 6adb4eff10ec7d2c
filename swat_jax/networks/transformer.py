"""The structure-aware transformer (SWAT, paper section 4.3) and, without embeddings, AMORPHEUS.

Every limb is one token. A linear layer shared by all limbs encodes each limb's input, scaled by
sqrt(width); the traversal-based positional embedding (section 4.1, eq. 3) is added to it; post-
LayerNorm transformer layers let the limbs attend to each other with a per-head relational bias
on the logits (section 4.2, eqs. 4-5), followed by one more LayerNorm (the original code's
``transformer_norm``, :attr:`NetworkConfig.final_norm`); a decoder shared by all limbs maps each final token,
concatenated with the limb's raw input, to one value per limb.

Padded limbs are masked out as keys, so they never influence a real limb.
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp

from swat_jax.morphology import RELATION_NAMES, TRAVERSAL_NAMES, StructureBatch
from swat_jax.networks.config import NetworkConfig
from swat_jax.networks.initialisation import Initialisation, embedding_init, linear


def traversal_embedding_widths(width: int, count: int) -> tuple[int, ...]:
    """Split the model width among ``count`` traversal tables as the original code does: each table
    gets ``width // count`` and the last one also the remainder (128 over three: 42, 42, 44), so the
    original's trained tables read in one to one."""
    base, remainder = divmod(width, count)
    return (base,) * (count - 1) + (base + remainder,)


class TraversalEmbedding(nn.Module):
    """Positional embedding of section 4.1 (eq. 3): one learned table per selected traversal.

    The vectors of a limb's pre-, in- and post-order positions are concatenated to the model width.
    """

    config: NetworkConfig

    @nn.compact
    def __call__(self, traversal_positions: jax.Array) -> jax.Array:
        """[limbs, 3] int positions (columns in TRAVERSAL_NAMES order) -> [limbs, width]."""
        widths = traversal_embedding_widths(self.config.width, len(self.config.traversals))
        vectors = [
            nn.Embed(
                self.config.max_traversal_positions,
                table_width,
                name=f"{traversal}_order",
                **embedding_init(self.config.initialisation),
            )(traversal_positions[:, TRAVERSAL_NAMES.index(traversal)])
            for traversal, table_width in zip(self.config.traversals, widths, strict=True)
        ]
        return jnp.concatenate(vectors, axis=-1)


class RelationalEmbedding(nn.Module):
    """Relational embedding of section 4.2 (eq. 4): R^{ij} = g([R_lap, R_spd, R_ppr]^{ij}), one bias per head.

    g is linear and has no bias term: a constant added to all logits of a head cancels in the
    softmax, so it could never learn.
    """

    config: NetworkConfig

    @nn.compact
    def __call__(self, relations: jax.Array) -> jax.Array:
        """[limbs, limbs, 3] relation features (RELATION_NAMES order) -> [heads, limbs, limbs] bias."""
        columns = [RELATION_NAMES.index(name) for name in self.config.relations]
        features = jnp.take(relations, jnp.array(columns), axis=-1)
        relation_bias = linear(
            features, self.config.heads, self.config.initialisation, use_bias=False, name="g"
        )
        return jnp.moveaxis(relation_bias, -1, 0)


def masked_attention_weights(
    logits: jax.Array, limb_mask: jax.Array, relation_bias: jax.Array | None
) -> jax.Array:
    """Softmax over keys of ``logits`` [batch, heads, limbs, limbs] plus the relational bias [heads, limbs,
    limbs] (eq. 5) when given, padded limbs (``limb_mask`` [limbs] False) removed as keys: weight 0."""
    if relation_bias is not None:
        logits = logits + relation_bias
    logits = jnp.where(limb_mask, logits, jnp.finfo(logits.dtype).min)
    return jax.nn.softmax(logits, axis=-1)


class MaskedMultiHeadAttention(nn.Module):
    """Multi-head self-attention over limbs with an additive per-head bias (eq. 5) and a key mask.

    alpha_h^{ij} = q_h^i . k_h^j / sqrt(width / heads) + R_h^{ij}; padded limbs are removed as keys.
    The attention weights are sown as ``intermediates/attention_weights`` ([batch, heads, limbs, limbs]).
    Keys have no bias: like g's bias, it would cancel in the softmax.
    """

    width: int
    heads: int
    initialisation: Initialisation = "flax"

    @nn.compact
    def __call__(self, tokens: jax.Array, limb_mask: jax.Array, relation_bias: jax.Array | None) -> jax.Array:
        """tokens [batch, limbs, width], limb_mask [limbs] bool, relation_bias [heads, limbs, limbs] or None."""
        head_width = self.width // self.heads

        def project(name: str, use_bias: bool = True) -> jax.Array:
            projected = linear(
                tokens, self.width, self.initialisation, "attention_projection", use_bias=use_bias, name=name
            )
            return projected.reshape(*tokens.shape[:-1], self.heads, head_width)

        queries, keys, values = project("query"), project("key", use_bias=False), project("value")
        logits = jnp.einsum("bqhd,bkhd->bhqk", queries, keys) / math.sqrt(head_width)
        attention_weights = masked_attention_weights(logits, limb_mask, relation_bias)
        self.sow("intermediates", "attention_weights", attention_weights)
        attended = jnp.einsum("bhqk,bkhd->bqhd", attention_weights, values)
        attended = attended.reshape(tokens.shape)
        return linear(attended, self.width, self.initialisation, "attention_output", name="output")


class TransformerLayer(nn.Module):
    """Post-LayerNorm encoder layer: x = LN(x + attention(x)); x = LN(x + FF(x)), FF with ReLU."""

    config: NetworkConfig

    @nn.compact
    def __call__(self, tokens: jax.Array, limb_mask: jax.Array, relation_bias: jax.Array | None) -> jax.Array:
        """tokens [batch, limbs, width] -> [batch, limbs, width]."""
        config = self.config
        attended = MaskedMultiHeadAttention(
            config.width, config.heads, config.initialisation, name="attention"
        )(tokens, limb_mask, relation_bias)
        epsilon = config.layer_norm_epsilon
        tokens = nn.LayerNorm(epsilon, name="attention_norm")(tokens + attended)
        hidden = nn.relu(linear(tokens, config.feedforward, config.initialisation, name="feedforward_hidden"))
        transformed = linear(hidden, config.width, config.initialisation, name="feedforward_output")
        return nn.LayerNorm(epsilon, name="feedforward_norm")(tokens + transformed)


class LimbDecoder(nn.Module):
    """Per-limb decoder shared by all limbs: MLP(concat(final token, raw limb input)) -> one value, or
    ``outputs`` values (a distributional critic's logits)."""

    hidden: tuple[int, ...]
    outputs: int = 1
    initialisation: Initialisation = "flax"

    @nn.compact
    def __call__(self, tokens: jax.Array, limb_inputs: jax.Array) -> jax.Array:
        """tokens [batch, limbs, width], limb_inputs [batch, limbs, features] -> [batch, limbs], or
        [batch, limbs, outputs] when ``outputs`` > 1."""
        hidden = jnp.concatenate([tokens, limb_inputs], axis=-1)
        for size in self.hidden:
            hidden = nn.relu(linear(hidden, size, self.initialisation))
        values = linear(hidden, self.outputs, self.initialisation, "decoder")
        return values[..., 0] if self.outputs == 1 else values


class StructureAwareTransformer(nn.Module):
    """SWAT (section 4.3), or AMORPHEUS when the config selects no traversals and no relations."""

    config: NetworkConfig
    outputs: int = 1
    """Values per limb: 1, or a distributional critic's atoms."""

    @nn.compact
    def __call__(self, limb_inputs: jax.Array, structure: StructureBatch) -> jax.Array:
        """One value per limb (``outputs`` > 1: that many).

        Args:
            limb_inputs: [batch, limbs, features] raw per-limb input.
            structure: one body's slice of a StructureBatch: limb_mask [limbs], traversal_positions
                [limbs, 3], relations [limbs, limbs, 3] (parents is not used).

        Returns:
            [batch, limbs] decoder output, [batch, limbs, outputs] with ``outputs`` > 1 (padded limbs hold
            unspecified values).
        """
        config = self.config
        encoded = linear(
            limb_inputs, config.width, config.initialisation, "limb_encoder", name="limb_encoder"
        )
        tokens = encoded * math.sqrt(config.width)
        if config.traversals:
            tokens = tokens + TraversalEmbedding(config, name="traversal_embedding")(
                structure.traversal_positions
            )
        relation_bias = (
            RelationalEmbedding(config, name="relational_embedding")(structure.relations)
            if config.relations
            else None
        )
        for layer in range(config.layers):
            layer_bias = relation_bias if layer == 0 or config.relation_bias_in_every_layer else None
            tokens = TransformerLayer(config, name=f"layer_{layer}")(tokens, structure.limb_mask, layer_bias)
        if config.final_norm:
            tokens = nn.LayerNorm(config.layer_norm_epsilon, name="final_norm")(tokens)
        decoder = LimbDecoder(config.decoder_hidden, self.outputs, config.initialisation, name="decoder")
        return decoder(tokens, limb_inputs)
