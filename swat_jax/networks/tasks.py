"""The task set: the bodies one policy acts on and their structure batch, built and checked in one place.

Training, evaluation, export and the figures all turn a list of bodies into the padded
:class:`~swat_jax.morphology.StructureBatch` the networks take (paper section 3: one limb one token,
bodies padded to a common limb count with a mask) through :func:`task_set`, which also checks that
the network can take every body. The environments never see the structure: they only step bodies.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from swat_jax.morphology import Morphology, StructureBatch, load, pad_structures
from swat_jax.networks.config import NetworkConfig
from swat_jax.networks.policies import check_structures


@dataclasses.dataclass(frozen=True)
class TaskSet:
    """K bodies and their structure padded to L limbs, checked against one network."""

    bodies: tuple[Morphology, ...]
    structure: StructureBatch
    """NumPy arrays with a leading [K] axis, padded to L = ``max_limbs``."""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(body.name for body in self.bodies)

    @property
    def max_limbs(self) -> int:
        """L, the padded limb count."""
        return int(self.structure.limb_mask.shape[1])


def task_set(
    bodies: Sequence[Morphology | str | Path],
    network: NetworkConfig,
    *,
    max_limbs: int | None = None,
    reference_inorder: bool = False,
) -> TaskSet:
    """Load the bodies, pad their structures to ``max_limbs`` and check that ``network`` takes them.

    Args:
        bodies: loaded bodies, benchmark names or MJCF paths (K of them).
        network: the policy network that will act on them.
        max_limbs: L; defaults to the largest body's limb count.
        reference_inorder: the reference code's in-order traversal in the positional encoding
            (docs/fidelity.md, row 13); a property of the trained network, so it comes from its run.

    Raises:
        MorphologyError: a body cannot be loaded.
        ValueError: no bodies, or a body larger than ``max_limbs``.
        StructureMismatch: the network cannot take a body (its ``setting`` and ``needed`` say the fix).
    """
    loaded = tuple(body if isinstance(body, Morphology) else load(body) for body in bodies)
    structure = pad_structures(loaded, max_limbs, reference_inorder=reference_inorder)
    check_structures(network, structure, [body.name for body in loaded])
    return TaskSet(loaded, structure)
