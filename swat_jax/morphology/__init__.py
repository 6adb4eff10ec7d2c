"""Bodies as trees of limbs: MJCF parsing, family constants, structural encodings, environment sets."""

from swat_jax.morphology.batch import (
    LimbBucket,
    StructureBatch,
    bucket_slice,
    bucket_structures,
    limb_buckets,
    pad_structures,
)
from swat_jax.morphology.encodings import (
    RELATION_NAMES,
    TRAVERSAL_NAMES,
    relation_features,
    traversal_positions,
)
from swat_jax.morphology.mjcf import MorphologyError, benchmark_names, load
from swat_jax.morphology.sets import SETS, EnvironmentSet, get_set
from swat_jax.morphology.types import FamilySpec, Morphology

__all__ = [
    "RELATION_NAMES",
    "SETS",
    "TRAVERSAL_NAMES",
    "EnvironmentSet",
    "FamilySpec",
    "LimbBucket",
    "Morphology",
    "MorphologyError",
    "StructureBatch",
    "benchmark_names",
    "bucket_slice",
    "bucket_structures",
    "get_set",
    "limb_buckets",
    "load",
    "pad_structures",
    "relation_features",
    "traversal_positions",
]
