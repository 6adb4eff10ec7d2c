"""Per-limb policies in Flax: SWAT, AMORPHEUS and SMP actors and twin critics (paper sections 4.1-4.3), and
SGRL's SET for 3D bodies (Chen et al. 2023)."""

from swat_jax.networks.config import ARCHITECTURES, NAMED_VARIANTS, NetworkConfig, network_config
from swat_jax.networks.policies import (
    Actor,
    ArchitectureMismatch,
    Critic,
    LimbNetwork,
    Params,
    StructureMismatch,
    check_structures,
    make_actor_critic,
    param_count,
)
from swat_jax.networks.tasks import TaskSet, task_set

__all__ = [
    "ARCHITECTURES",
    "NAMED_VARIANTS",
    "Actor",
    "ArchitectureMismatch",
    "Critic",
    "LimbNetwork",
    "NetworkConfig",
    "Params",
    "StructureMismatch",
    "TaskSet",
    "check_structures",
    "make_actor_critic",
    "network_config",
    "param_count",
    "task_set",
]
