"""Initial weights: Flax's defaults, or the original PyTorch code's (docs/fidelity.md, rows 6-11 and 20).

``NetworkConfig.initialisation`` picks one. "flax" keeps every layer's Flax default (LeCun-normal
kernels, zero biases, embeddings of std 1/sqrt(width)). "original" draws what the original code's
PyTorch modules draw:

- every ``nn.Linear`` by default: kernel and bias U(±1/sqrt(fan_in)) (SWAT's feed-forward blocks, SMP);
- the limb encoder: kernel U(±0.1), bias PyTorch's default; the decoder: kernel U(±0.1), bias 0
  (the original's ``init_weights``);
- attention: query, key and value kernels Xavier-uniform over their stacked [3 width, width] matrix,
  U(±sqrt(6 / (4 width))), biases 0; the output projection U(±1/sqrt(width)), bias 0;
- the relation map g: U(±1/sqrt(relation features));
- traversal tables: N(0, 1) (``nn.Embedding``);
- every transformer layer starts as a copy of the first (the original deep-copies one layer).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Literal, get_args

import flax.linen as nn
import jax
import jax.numpy as jnp

Initialisation = Literal["flax", "original"]
INITIALISATIONS: tuple[str, ...] = get_args(Initialisation)
"""The values of ``NetworkConfig.initialisation``."""

Initializer = Callable[..., jax.Array]

LINEAR_ROLES = ("default", "limb_encoder", "decoder", "attention_projection", "attention_output")
"""The kinds of linear layer whose original initialisation differs (see the module docstring)."""


def uniform(bound: float) -> Initializer:
    """U(-bound, bound), PyTorch's ``uniform_``."""

    def init(key: jax.Array, shape: tuple[int, ...], dtype: Any = jnp.float32) -> jax.Array:
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


def linear_init(initialisation: str, role: str, fan_in: int) -> dict[str, Initializer]:
    """``nn.Dense`` keyword arguments (``kernel_init``, ``bias_init``) for a linear layer of ``role``
    (one of :data:`LINEAR_ROLES`) reading ``fan_in`` values; empty for Flax's defaults."""
    if initialisation == "flax":
        return {}
    pytorch_default = uniform(1 / math.sqrt(fan_in))
    kernel, bias = {
        "default": (pytorch_default, pytorch_default),
        "limb_encoder": (uniform(0.1), pytorch_default),
        "decoder": (uniform(0.1), nn.initializers.zeros),
        "attention_projection": (uniform(math.sqrt(6 / (4 * fan_in))), nn.initializers.zeros),
        "attention_output": (pytorch_default, nn.initializers.zeros),
    }[role]
    return {"kernel_init": kernel, "bias_init": bias}


def linear(
    inputs: jax.Array, features: int, initialisation: str, role: str = "default", **dense: Any
) -> jax.Array:
    """``nn.Dense(features, **dense)`` made in the calling module and applied to ``inputs`` [..., fan_in] ->
    [..., features], its weights drawn as ``initialisation`` draws a layer of ``role``
    (:func:`linear_init`, fan-in ``inputs.shape[-1]``)."""
    init = linear_init(initialisation, role, inputs.shape[-1])
    return nn.Dense(features, **init, **dense)(inputs)


def embedding_init(initialisation: str) -> dict[str, Initializer]:
    """``nn.Embed`` keyword arguments: empty for Flax's default, N(0, 1) for the original's."""
    return {} if initialisation == "flax" else {"embedding_init": nn.initializers.normal(1.0)}


def copy_first_layer(params: Any) -> Any:
    """Every ``layer_i`` subtree replaced by ``layer_0`` of the same network, at any depth: the original's
    transformer layers all start as deep copies of one."""
    if not isinstance(params, dict):
        return params
    copied = {name: copy_first_layer(subtree) for name, subtree in params.items()}
    if "layer_0" in copied:
        copied.update({name: copied["layer_0"] for name in copied if name.removeprefix("layer_").isdigit()})
    return copied
