"""Frozen configuration of the per-limb policy networks and the named variants of the paper.

``network_config("swat")`` is the paper's model (Table 1, sections 4.1-4.3); the ablations of
section 5.4 (Figure 6) each change one structural-embedding field, and AMORPHEUS (Kurin et al.
2021) is the same transformer with neither embedding. SMP (Huang et al. 2020) is the
message-passing baseline. SET (Chen et al. 2023, SGRL) is the subequivariant transformer for 3D bodies
(:mod:`swat_jax.networks.subequivariant`); SGRL's 3D configuration has SWAT's sizes (width 128, 2 heads,
3 layers, feed-forward 256, the same traversals and relations), so it shares these defaults.
:class:`NetworkSizes` is what a training run sets of them (the ``--network.*`` flags), which
:meth:`swat_jax.runs.config.TrainConfig.network_config` turns into a NetworkConfig.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from swat_jax.errors import ConfigError, is_positive_whole, require_positive
from swat_jax.morphology import RELATION_NAMES, TRAVERSAL_NAMES
from swat_jax.networks.initialisation import INITIALISATIONS, Initialisation

ARCHITECTURES = ("swat", "amorpheus", "smp", "set")


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Sizes and switches of one network; every field is checked in ``__post_init__``."""

    architecture: str = "swat"
    """"swat" (transformer with structural embeddings), "amorpheus" (the same transformer with
    none), "smp" (shared modular policies, two-pass message passing) or "set" (SGRL's subequivariant
    transformer, 3D bodies only)."""
    width: int = 128
    """Transformer model width d_v: the encoded limb token (Table 1, embedding size)."""
    heads: int = 2
    """Attention heads (Table 1)."""
    layers: int = 3
    """Transformer layers (Table 1)."""
    feedforward: int = 256
    """Hidden width of each layer's feed-forward block (Table 1, attention hidden size)."""
    traversals: tuple[str, ...] = TRAVERSAL_NAMES
    """Traversals whose learned position tables make the positional embedding (section 4.1);
    empty for no positional embedding."""
    relations: tuple[str, ...] = RELATION_NAMES
    """Pairwise relation features fed to g for the relational embedding (section 4.2, eq. 4);
    empty for no relational embedding."""
    relation_bias_in_every_layer: bool = False
    """Add the relational bias to the logits of every layer; the reference adds it to the first only."""
    max_traversal_positions: int = 15
    """Rows of each traversal table: traversal positions of every body must be below this (the original
    code's 15 by default, so its trained tables read in one to one)."""
    final_norm: bool = True
    """A LayerNorm after the last transformer layer, before the decoder (the original code's
    ``transformer_norm=1``, its default)."""
    layer_norm_epsilon: float = 1e-5
    """Epsilon of every LayerNorm (PyTorch's 1e-5, the original code's; Flax's own default is 1e-6)."""
    decoder_hidden: tuple[int, ...] = ()
    """Hidden widths of the per-limb decoder MLP (ReLU); empty is one linear map, as in AMORPHEUS."""
    message_width: int = 32
    """SMP: width of every message, up and down (SMP's msg_dim)."""
    up_hidden: tuple[int, ...] = (64, 64)
    """SMP: hidden widths of the bottom-up module (tanh)."""
    down_hidden: tuple[int, ...] = (400, 300)
    """SMP: hidden widths of the top-down modules, one for the output, one for the messages (ReLU)."""
    max_children: int = 4
    """SMP: child message slots per limb (4 is the most children of any benchmark limb)."""
    initialisation: Initialisation = "flax"
    """Initial weights: "flax" (Flax's defaults) or "original" (the original PyTorch code's, every
    transformer layer starting as a copy of the first; :mod:`swat_jax.networks.initialisation`; for SET,
    SGRL's: PyTorch's default for every linear map, its two input encoders U(+-0.1))."""
    observation_normalisation: bool = False
    """Standardise every limb feature by running statistics of the observations seen in training, one set
    over all real limbs (FastTD3's normaliser), in the actor and the critic; the statistics are variables
    of both networks, so policies carry them (:mod:`swat_jax.networks.observation_stats`)."""

    @property
    def sums_limb_values(self) -> bool:
        """Whether the critic's Q of a body is the sum of its limbs' outputs (SMP, as in the original
        code) rather than one Q per limb, each with its own TD target (the transformers)."""
        return self.architecture == "smp"

    def __post_init__(self) -> None:
        if self.architecture not in ARCHITECTURES:
            raise ValueError(f"architecture must be one of {ARCHITECTURES}, got {self.architecture!r}")
        for name in ("width", "heads", "layers", "feedforward", "max_traversal_positions"):
            _require_positive_int(name, getattr(self, name))
        for name in ("message_width", "max_children"):
            _require_positive_int(name, getattr(self, name))
        if isinstance(self.layer_norm_epsilon, bool) or not (
            isinstance(self.layer_norm_epsilon, int | float) and self.layer_norm_epsilon > 0
        ):
            raise ValueError(f"layer_norm_epsilon must be a positive number, got {self.layer_norm_epsilon!r}")
        if self.initialisation not in INITIALISATIONS:
            raise ValueError(f"initialisation must be one of {INITIALISATIONS}, got {self.initialisation!r}")
        if self.width % self.heads != 0:
            raise ValueError(f"width ({self.width}) must be divisible by heads ({self.heads})")
        if self.architecture == "set" and self.observation_normalisation:
            raise ValueError(
                "SET reads the observation's 3-vectors as they are: observation normalisation, which standardises "
                "each value on its own, would break its symmetry about gravity; turn it off for SET"
            )
        if self.architecture == "set" and self.width < 2 * self.heads:
            raise ValueError(
                f"SET needs a width of at least 2 per head (each head's vector values hold 2 * width / heads - 2 "
                f"channels and the 2 directions); got width {self.width} with {self.heads} heads"
            )
        for name in ("decoder_hidden", "up_hidden", "down_hidden"):
            sizes = _as_tuple(name, getattr(self, name))
            for size in sizes:
                _require_positive_int(f"every entry of {name}", size)
            object.__setattr__(self, name, sizes)
        if not self.up_hidden:
            raise ValueError("up_hidden needs at least one layer: the limb input is encoded by the first")
        object.__setattr__(
            self, "traversals", _checked_subset("traversals", self.traversals, TRAVERSAL_NAMES)
        )
        object.__setattr__(self, "relations", _checked_subset("relations", self.relations, RELATION_NAMES))
        if len(self.traversals) > self.width:
            raise ValueError(
                f"width ({self.width}) is too small to split among {len(self.traversals)} traversals"
            )
        if self.architecture == "amorpheus" and (self.traversals or self.relations):
            raise ValueError(
                "AMORPHEUS has no structural embeddings: set traversals=() and relations=() "
                "(or use architecture='swat' to keep them)"
            )


def _require_positive_int(name: str, value: Any) -> None:
    if not is_positive_whole(value):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")


def _as_tuple(name: str, value: Any) -> tuple:
    if isinstance(value, str) or not isinstance(value, tuple | list):
        raise ValueError(f"{name} must be a tuple, got {value!r}")
    return tuple(value)


def _checked_subset(name: str, value: Any, allowed: tuple[str, ...]) -> tuple[str, ...]:
    chosen = _as_tuple(name, value)
    unknown = [item for item in chosen if item not in allowed]
    if unknown:
        raise ValueError(f"{name} must be drawn from {allowed}, got unknown {unknown}")
    if len(set(chosen)) != len(chosen):
        raise ValueError(f"{name} lists an entry twice: {chosen}")
    return chosen


NAMED_VARIANTS: dict[str, dict[str, Any]] = {
    "swat": {},
    "amorpheus": {"architecture": "amorpheus", "traversals": (), "relations": ()},
    "smp": {"architecture": "smp"},
    "swat_no_pe": {"traversals": ()},
    "swat_no_re": {"relations": ()},
    "swat_no_pe_re": {"traversals": (), "relations": ()},
    "set": {"architecture": "set"},
}
"""The fields each named variant changes from the defaults (the paper's SWAT)."""


def network_config(name: str, **overrides: Any) -> NetworkConfig:
    """The configuration of a named variant, with any field overridden.

    Args:
        name: one of :data:`NAMED_VARIANTS` ("swat", "amorpheus", "smp", "swat_no_pe",
            "swat_no_re", "swat_no_pe_re", "set").
        **overrides: :class:`NetworkConfig` fields, e.g. ``width=16``.

    Raises:
        ValueError: unknown name or field, or an invalid value.
    """
    if name not in NAMED_VARIANTS:
        raise ValueError(f"unknown network {name!r}; valid names: {', '.join(NAMED_VARIANTS)}")
    fields = {field.name for field in dataclasses.fields(NetworkConfig)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"unknown NetworkConfig fields {unknown}; valid fields: {', '.join(sorted(fields))}")
    return NetworkConfig(**{**NAMED_VARIANTS[name], **overrides})


NETWORK_SIZES = ("width", "heads", "layers", "feedforward", "max_traversal_positions", "max_children")


@dataclasses.dataclass(frozen=True)
class NetworkSizes:
    """The actor's and critic's sizes (``--network.*``); None keeps the algorithm's."""

    width: int | None = None
    """Transformer model width; None keeps the algorithm's (128)."""
    heads: int | None = None
    """Attention heads; None keeps the algorithm's (2)."""
    layers: int | None = None
    """Transformer layers; None keeps the algorithm's (3)."""
    feedforward: int | None = None
    """Feed-forward width of each layer; None keeps the algorithm's (256)."""
    max_traversal_positions: int | None = None
    """Rows of each traversal table of SWAT's positional embedding, at least the limbs of the largest body; None keeps the original code's 15."""
    max_children: int | None = None
    """SMP: child slots per limb, at least the most children of any limb; None takes that most over the training bodies, as the original code does (Hopper++ 1, Walker++ and Cheetah++ 2, the others 4)."""
    smp_hidden: int | None = None
    """SMP: width of both hidden layers of its bottom-up and top-down modules; None keeps the paper's (64, 64) up and (400, 300) down."""
    reference_inorder: bool = True
    """Use the original code's in-order traversal for the positional embedding (the paper preset; docs/fidelity.md); off: a true binary in-order (the fast preset)."""
    initialisation: Initialisation = "original"
    """Initial weights: original (the original PyTorch code's, the paper preset: uniform kernels and biases, traversal tables N(0, 1), every transformer layer a copy of the first; docs/fidelity.md, rows 6-11 and 20) or flax (Flax's defaults, the fast preset)."""
    observation_normalisation: bool = False
    """Standardise every limb feature by running statistics of the observations collected so far, one set over all real limbs (FastTD3's normaliser), in actor and critic; policy files and exported policies carry the statistics. Off in both presets (docs/training.md)."""

    def __post_init__(self) -> None:
        for name in (*NETWORK_SIZES, "smp_hidden"):
            if getattr(self, name) is not None:
                require_positive(f"--network.{name.replace('_', '-')}", getattr(self, name))
        if self.initialisation not in INITIALISATIONS:
            raise ConfigError(
                f"--network.initialisation must be one of {', '.join(INITIALISATIONS)}, got {self.initialisation!r}"
            )
