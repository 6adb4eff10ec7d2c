"""Read the original SWAT code's PyTorch weights into our Flax parameters, one to one.

The original repository (Hong et al. 2022, MIT) saves each network as a PyTorch ``state_dict``. Given
one as a mapping from its keys to NumPy arrays (no PyTorch needed here), :func:`actor_params` and
:func:`critic_params` build the ``{"params": ...}`` pytree of our actor and critic of the same sizes:

- SWAT and AMORPHEUS (its ``StructurePolicy`` / ``TransformerPolicy`` and their critics): encoder,
  traversal tables (the original's 42/42/44 split and 15 rows, our defaults), relation map ``g`` (its
  columns reordered from the original's (PPR, Laplacian, distance) to our :data:`RELATION_NAMES`),
  every post-LayerNorm layer, the final LayerNorm and the decoder. The key projection's bias and ``g``'s
  bias are dropped: each adds the same number to every logit of a query, which the softmax cancels.
- SMP with both message passes (its ``ActorGraphPolicy`` / ``CriticGraphPolicy`` with ``td`` and
  ``bu``): the bottom-up module, the top-down message module, and the output head (actor) or the two
  Q heads (critic), shared by every limb, from the first limb's entries (``sNet.0``, ``actor.0``,
  ``critic.0``).

PyTorch's ``Linear`` stores [out, in] and computes x W^T + b; Flax's ``Dense`` kernel is [in, out].
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from swat_jax.morphology import TRAVERSAL_NAMES
from swat_jax.networks.config import NetworkConfig
from swat_jax.networks.policies import Params

ORIGINAL_RELATION_ORDER = ("ppr", "laplacian", "spd")
"""Channel order of the original's relation tensor (its ``getGraphDict``)."""

StateDict = Mapping[str, np.ndarray]
"""A PyTorch ``state_dict`` as NumPy arrays."""


class OriginalWeightsError(ValueError):
    """A state dict that does not fit the network config; the message names the key."""


def actor_params(state_dict: StateDict, config: NetworkConfig) -> Params:
    """Our actor's parameters from the original actor's ``state_dict``."""
    if config.architecture == "smp":
        return {"params": {"policy": _smp_actor(state_dict)}}
    return {"params": {"policy": _transformer(state_dict, "actor.", config)}}


def critic_params(state_dict: StateDict, config: NetworkConfig) -> Params:
    """Our twin critic's parameters from the original critic's ``state_dict``."""
    if config.architecture == "smp":
        return {"params": {"q": _smp_critic(state_dict)}}
    return {
        "params": {
            "q1": _transformer(state_dict, "critic1.", config),
            "q2": _transformer(state_dict, "critic2.", config),
        }
    }


def _get(state_dict: StateDict, key: str) -> np.ndarray:
    if key not in state_dict:
        sample = ", ".join(sorted(state_dict)[:6])
        raise OriginalWeightsError(
            f"the original state dict has no {key!r} (its keys start: {sample}, ...): "
            "is it the network the config names (architecture, layers, final_norm)?"
        )
    return np.asarray(state_dict[key], np.float32)


def _dense(state_dict: StateDict, prefix: str, *, bias: bool = True) -> dict[str, np.ndarray]:
    """A Flax Dense from PyTorch Linear ``prefix.weight`` [out, in] and ``prefix.bias`` [out]."""
    dense = {"kernel": _get(state_dict, prefix + "weight").T.copy()}
    if bias:
        dense["bias"] = _get(state_dict, prefix + "bias")
    return dense


def _norm(state_dict: StateDict, prefix: str) -> dict[str, np.ndarray]:
    return {"scale": _get(state_dict, prefix + "weight"), "bias": _get(state_dict, prefix + "bias")}


def _transformer(state_dict: StateDict, prefix: str, config: NetworkConfig) -> dict:
    """One SWAT / AMORPHEUS ``TransformerModel`` under ``prefix`` (``actor.``, ``critic1.``, ...)."""
    encoder = prefix + "transformer_encoder."
    params: dict = {
        "limb_encoder": _dense(state_dict, prefix + "encoder."),
        "decoder": {"Dense_0": _dense(state_dict, prefix + "decoder.")},
    }
    if config.decoder_hidden:
        raise OriginalWeightsError("the original decoder is one linear map: decoder_hidden must be ()")
    if config.traversals:
        params["traversal_embedding"] = {
            f"{name}_order": {"embedding": _get(state_dict, f"{prefix}pos_encoder.embeddings.{index}.weight")}
            for index, name in enumerate(TRAVERSAL_NAMES)
        }
    if config.relations:
        weight = _get(state_dict, encoder + "rel_encoder.weight")  # [heads, 3], original channel order
        columns = [ORIGINAL_RELATION_ORDER.index(name) for name in config.relations]
        params["relational_embedding"] = {"g": {"kernel": weight[:, columns].T.copy()}}
    width = config.width
    for layer in range(config.layers):
        at = f"{encoder}layers.{layer}."
        in_weight = _get(state_dict, at + "self_attn.in_proj_weight")
        in_bias = _get(state_dict, at + "self_attn.in_proj_bias")
        query, key, value = (
            {
                "kernel": in_weight[part * width : (part + 1) * width].T.copy(),
                "bias": in_bias[part * width : (part + 1) * width],
            }
            for part in range(3)
        )
        del key["bias"]
        params[f"layer_{layer}"] = {
            "attention": {
                "query": query,
                "key": key,
                "value": value,
                "output": _dense(state_dict, at + "self_attn.out_proj."),
            },
            "attention_norm": _norm(state_dict, at + "norm1."),
            "feedforward_hidden": _dense(state_dict, at + "linear1."),
            "feedforward_output": _dense(state_dict, at + "linear2."),
            "feedforward_norm": _norm(state_dict, at + "norm2."),
        }
    if config.final_norm:
        params["final_norm"] = _norm(state_dict, encoder + "norm.")
    _check_no_extra_layers(state_dict, encoder, config.layers)
    return params


def _check_no_extra_layers(state_dict: StateDict, encoder: str, layers: int) -> None:
    if any(key.startswith(f"{encoder}layers.{layers}.") for key in state_dict):
        raise OriginalWeightsError(
            f"the original network has more than {layers} layers: set layers to its count"
        )


def _mlp(state_dict: StateDict, prefixes: tuple[str, ...]) -> dict:
    """Our MLP (Dense_0, Dense_1, ...) from PyTorch Linears."""
    return {f"Dense_{index}": _dense(state_dict, prefix) for index, prefix in enumerate(prefixes)}


def _messages(state_dict: StateDict, up: str, down: str) -> dict:
    """SMP's bottom-up module (``fc1``-``fc3``) and top-down message module (``msg_base``)."""
    return {
        "bottom_up": {
            "input_encoder": _dense(state_dict, up + "fc1."),
            "message": _mlp(state_dict, (up + "fc2.", up + "fc3.")),
        },
        "top_down": {"messages": _mlp(state_dict, _base(down + "msg_base."))},
    }


def _base(prefix: str) -> tuple[str, ...]:
    """The three Linears of the original's 400-300 ``MLPBase``."""
    return (prefix + "l1.", prefix + "l2.", prefix + "l3.")


def _smp_actor(state_dict: StateDict) -> dict:
    return {
        "messages": _messages(state_dict, "sNet.0.", "actor.0."),
        "output": _mlp(state_dict, _base("actor.0.action_base.")),
    }


def _smp_critic(state_dict: StateDict) -> dict:
    return {
        "messages": _messages(state_dict, "sNet.0.", "critic.0."),
        "q1": _mlp(state_dict, _base("critic.0.baseQ1.")),
        "q2": _mlp(state_dict, _base("critic.0.baseQ2.")),
    }
