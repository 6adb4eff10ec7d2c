"""A batch of bodies padded to a common limb count, as plain arrays for jitted code.

The structural encodings of each body (paper sections 4.1-4.2, see encodings.py) are
computed once on the host and padded; ``limb_mask`` tells real limbs from padding.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from swat_jax.morphology.encodings import (
    RELATION_NAMES,
    TRAVERSAL_NAMES,
    relation_features,
    traversal_positions,
)
from swat_jax.morphology.types import Morphology


class StructureBatch(NamedTuple):
    """Per-limb structure of K bodies padded to L = max_limbs (a JAX pytree as a NamedTuple)."""

    limb_mask: np.ndarray
    """[K, L] bool, True for real limbs."""
    parents: np.ndarray
    """[K, L] int32 parent limb index; -1 for the torso and for padding."""
    traversal_positions: np.ndarray
    """[K, L, 3] int32 pre/in/post-order positions (eq. 3); padding 0."""
    relations: np.ndarray
    """[K, L, L, 3] float32 laplacian/spd/ppr relations (eq. 4); padding rows and columns 0."""
    limb_types: np.ndarray
    """[K, L] int32 limb type index; -1 for unmatched limbs and for padding."""
    joint_ranges: np.ndarray
    """[K, L, 2] float32 joint range in degrees; 0 for the torso and for padding."""
    limb_motors: np.ndarray
    """[K, L] int32 actuator index driving each limb; -1 for the torso and for padding."""
    num_limbs: np.ndarray
    """[K] int32 real limb count per body."""


def pad_structures(
    bodies: Sequence[Morphology], max_limbs: int | None = None, *, reference_inorder: bool = False
) -> StructureBatch:
    """Encode each body and pad every per-limb array to ``max_limbs``.

    Args:
        bodies: K bodies, any families.
        max_limbs: L, the padded limb count; defaults to the largest body's limb count.
        reference_inorder: use the reference code's in-order traversal (BENCHMARK.md quirk 2,
            see :func:`traversal_positions`).

    Returns:
        A :class:`StructureBatch` of NumPy arrays with leading dimension K.

    Raises:
        ValueError: ``bodies`` is empty, or a body has more than ``max_limbs`` limbs.
    """
    if len(bodies) == 0:
        raise ValueError("pad_structures needs at least one body")
    width = max(body.num_limbs for body in bodies) if max_limbs is None else max_limbs
    for body in bodies:
        if body.num_limbs > width:
            raise ValueError(f"body {body.name!r} has {body.num_limbs} limbs, more than max_limbs={width}")
    k = len(bodies)
    batch = StructureBatch(
        limb_mask=np.zeros((k, width), bool),
        parents=np.full((k, width), -1, np.int32),
        traversal_positions=np.zeros((k, width, len(TRAVERSAL_NAMES)), np.int32),
        relations=np.zeros((k, width, width, len(RELATION_NAMES)), np.float32),
        limb_types=np.full((k, width), -1, np.int32),
        joint_ranges=np.zeros((k, width, 2), np.float32),
        limb_motors=np.full((k, width), -1, np.int32),
        num_limbs=np.array([body.num_limbs for body in bodies], np.int32),
    )
    for row, body in enumerate(bodies):
        n = body.num_limbs
        batch.limb_mask[row, :n] = True
        batch.parents[row, :n] = body.parents
        batch.traversal_positions[row, :n] = traversal_positions(
            body.parents, reference_inorder=reference_inorder
        )
        batch.relations[row, :n, :n] = relation_features(body.parents)
        batch.limb_types[row, :n] = body.limb_types
        batch.joint_ranges[row, :n] = body.joint_range_array()
        batch.limb_motors[row, :n] = body.limb_motors
    return batch
