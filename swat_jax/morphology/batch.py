"""A batch of bodies padded to a common limb count, as plain arrays for jitted code.

The structural encodings of each body (paper sections 4.1-4.2, see encodings.py) are
computed once on the host and padded; ``limb_mask`` tells real limbs from padding.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
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
    motor_mask: np.ndarray
    """[K, L, M] bool: the limb has a motor in this action slot (M = 1 planar, 3 in 3D); False for the
    torso and for padding."""
    num_limbs: np.ndarray
    """[K] int32 real limb count per body."""


def pad_structures(
    bodies: Sequence[Morphology], max_limbs: int | None = None, *, reference_inorder: bool = False
) -> StructureBatch:
    """Encode each body and pad every per-limb array to ``max_limbs``.

    Args:
        bodies: K bodies, any families.
        max_limbs: L, the padded limb count; defaults to the largest body's limb count.
        reference_inorder: use the reference code's in-order traversal (docs/fidelity.md, row 13;
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
        motor_mask=np.zeros((k, width, _motors_per_limb(bodies)), bool),
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
        batch.motor_mask[row, :n] = body.motor_mask()
    return batch


def _motors_per_limb(bodies: Sequence[Morphology]) -> int:
    """M of the bodies (one policy acts with M values per limb, so they must agree)."""
    counts = {body.motors_per_limb for body in bodies}
    if len(counts) > 1:
        names = ", ".join(f"{body.name} ({body.motors_per_limb})" for body in bodies)
        raise ValueError(
            f"bodies with different motors per limb cannot share a policy (planar bodies have 1, 3D bodies "
            f"3): {names}"
        )
    return counts.pop()


class LimbBucket(NamedTuple):
    """Tasks computed together at their own padded limb count (static: part of the program's shapes)."""

    tasks: tuple[int, ...]
    """Indices into the task axis, in order."""
    limbs: int
    """The largest limb count of these tasks; their arrays are cut to it."""


def limb_buckets(num_limbs: Sequence[int], count: int) -> tuple[LimbBucket, ...]:
    """Group tasks into at most ``count`` buckets of similar size, with the fewest padded limb slots.

    Tasks sorted by limb count are cut into contiguous runs; a run of tasks costs (tasks) x (its largest
    limb count) slots, and the cuts minimise the total (dynamic programming over the sorted counts).
    Animal-Walkers' [4, 7, 8, 9, 13] limbs take 65 slots padded to 13, 44 in 3 buckets ({4}, {7, 8, 9},
    {13}). Each bucket is one more copy of the networks in the compiled update: fewer FLOPs, longer
    compile.

    Returns:
        The buckets, smallest limb count first; task indices ascend within each.
    """
    if count < 1:
        raise ValueError(f"limb buckets must be at least 1, got {count}")
    order = sorted(range(len(num_limbs)), key=lambda task: (num_limbs[task], task))
    sizes = [int(num_limbs[task]) for task in order]
    tasks = len(sizes)
    count = min(count, tasks)
    # best[k][end]: fewest slots for the first `end` sorted tasks in k buckets; cut[k][end]: where the last starts.
    best = [[float("inf")] * (tasks + 1) for _ in range(count + 1)]
    cut = [[0] * (tasks + 1) for _ in range(count + 1)]
    best[0][0] = 0
    for k in range(1, count + 1):
        for end in range(1, tasks + 1):
            for start in range(end):
                slots = best[k - 1][start] + (end - start) * sizes[end - 1]
                if slots < best[k][end]:
                    best[k][end], cut[k][end] = slots, start
    k = min(range(1, count + 1), key=lambda used: (best[used][tasks], used))
    buckets, end = [], tasks
    while end > 0:
        start = cut[k][end]
        buckets.append(LimbBucket(tuple(sorted(order[start:end])), sizes[end - 1]))
        end, k = start, k - 1
    return tuple(reversed(buckets))


def bucket_slice(array: jax.Array, bucket: LimbBucket, limb_axes: Sequence[int]) -> jax.Array:
    """``array``'s rows ``bucket.tasks`` (axis 0), cut to ``bucket.limbs`` along every axis of ``limb_axes``."""
    array = array[np.asarray(bucket.tasks)]
    for axis in limb_axes:
        array = jax.lax.slice_in_dim(array, 0, bucket.limbs, axis=axis)
    return array


STRUCTURE_LIMB_AXES = StructureBatch(
    limb_mask=(1,),
    parents=(1,),
    traversal_positions=(1,),
    relations=(1, 2),
    limb_types=(1,),
    motor_mask=(1,),
    num_limbs=(),
)
"""The limb axes of each field of a [K, L, ...] StructureBatch."""


def bucket_structures(structures: StructureBatch, bucket: LimbBucket) -> StructureBatch:
    """The bucket's tasks of a [K, L, ...] StructureBatch, cut to its limb count: [len(tasks), limbs, ...]."""
    return StructureBatch(
        *(
            bucket_slice(leaf, bucket, axes)
            for leaf, axes in zip(structures, STRUCTURE_LIMB_AXES, strict=True)
        )
    )
