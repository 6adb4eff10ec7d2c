"""The training state on a device mesh: seeds first, then tasks (JAX's SPMD partitioning, no process pool).

The mesh has two axes. ``seeds`` splits the leading seed axis of every seeded array
(:func:`swat_jax.axes.seed_axes`): independent runs, so no communication. ``tasks`` splits what
is per task within a seed: each task's replay ring and its part of the update (the mean over tasks of
the losses becomes a cross-device reduction that XLA inserts), and each body's environment copies.
Parameters and optimizer states are replicated over ``tasks``; step counters everywhere.

Shapes that do not divide (5 bodies on 4 devices) follow one rule, :func:`mesh_shape`: the seed axis
takes the largest divisor of the seed count that fits the devices; the task axis the largest size that
fits what is left and divides the task count or the copies per body. What it divides is split over it
(replay and update by task, or environment copies, or both); what it does not divide is replicated over
it (every device of the axis holds it whole and computes it redundantly). Devices beyond the mesh stay
idle, and the run says how many.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from swat_jax import axes
from swat_jax.td3.iteration import TrainState

SEEDS = "seeds"
TASKS = "tasks"


def mesh_shape(seeds: int, tasks: int, copies: int, devices: int) -> tuple[int, int]:
    """(seed-axis size, task-axis size) for ``devices`` devices (see the module docstring)."""
    seed_size = max(d for d in range(1, min(seeds, devices) + 1) if seeds % d == 0)
    fits = range(1, devices // seed_size + 1)
    return seed_size, max(d for d in fits if tasks % d == 0 or copies % d == 0)


@dataclasses.dataclass(frozen=True)
class Placement:
    """Where a run's arrays live: the mesh and whether environment copies are split over its tasks axis."""

    mesh: Mesh
    tasks_split: bool
    """Replay rings and the update are split by task over the ``tasks`` axis."""
    copies_split: bool
    """Every body's environment copies are split over the ``tasks`` axis."""
    idle: int
    """Devices given to the run that its shapes leave unused."""

    @property
    def devices(self) -> int:
        return int(self.mesh.devices.size)

    def state_shardings(self, state: TrainState) -> TrainState:
        """A NamedSharding per array of a seeded ``state`` (arrays or ShapeDtypeStructs)."""
        seeded = jax.tree.broadcast(axes.seed_axes(state), state, is_leaf=lambda x: x is None)
        split = jax.tree.broadcast(
            axes.split_axes(state, self.tasks_split, self.copies_split), state, is_leaf=lambda x: x is None
        )
        return jax.tree.map(self._sharding, state, seeded, split, is_leaf=lambda x: x is None)

    def replicated(self) -> NamedSharding:
        """The sharding of an array every device holds whole."""
        return NamedSharding(self.mesh, PartitionSpec())

    def seeded(self) -> NamedSharding:
        """The sharding of an array whose leading axis is the seed axis (metrics, evaluation results)."""
        return NamedSharding(self.mesh, PartitionSpec(SEEDS))

    def _sharding(
        self, leaf: jax.Array | None, seed_axis: int | None, task_axis: int | None
    ) -> NamedSharding | None:
        if leaf is None:  # an absent optional field (an environment state without a variant)
            return None
        dims: list[str | None] = [None] * len(leaf.shape)
        if seed_axis is not None:
            dims[0] = SEEDS
        if task_axis is not None and self.mesh.shape[TASKS] > 1:
            dims[task_axis + (seed_axis is not None)] = TASKS
        return NamedSharding(self.mesh, PartitionSpec(*dims))

    def describe(self) -> str:
        """One line: the mesh and what is sharded on each axis."""
        seeds, tasks = self.mesh.shape[SEEDS], self.mesh.shape[TASKS]
        kind = self.mesh.devices.flat[0].platform
        parts = [
            f"mesh of {self.devices} {kind} device{'s' * (self.devices > 1)}: seeds {seeds} x tasks {tasks}"
        ]
        if seeds > 1:
            parts.append(f"'seeds' splits the seed axis of the whole state ({seeds} way)")
        if tasks > 1:
            pieces = {
                "replay rings and update by task": self.tasks_split,
                "environment copies": self.copies_split,
            }
            parts.append(f"'tasks' splits {' and '.join(p for p, on in pieces.items() if on)} ({tasks} way)")
            kept = [piece for piece, on in pieces.items() if not on]
            if kept:
                parts.append(f"{' and '.join(kept)} replicated over 'tasks' (sizes do not divide)")
        if self.idle:
            parts.append(
                f"{self.idle} device{'s' * (self.idle > 1)} idle (seeds and tasks do not divide further)"
            )
        return "; ".join(parts)


def placement(seeds: int, tasks: int, copies: int, devices: Sequence[jax.Device]) -> Placement:
    """The mesh of a run with ``seeds`` seeds and ``tasks`` bodies of ``copies`` copies over ``devices``."""
    seed_size, task_size = mesh_shape(seeds, tasks, copies, len(devices))
    grid = np.asarray(devices[: seed_size * task_size], dtype=object).reshape(seed_size, task_size)
    return Placement(
        Mesh(grid, (SEEDS, TASKS)),
        tasks_split=task_size > 1 and tasks % task_size == 0,
        copies_split=task_size > 1 and copies % task_size == 0,
        idle=len(devices) - seed_size * task_size,
    )


def fetch(tree: Any) -> Any:
    """``tree``'s arrays on the host, whole: across several hosts every process gathers every shard."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    return multihost_utils.process_allgather(tree, tiled=True)


def all_processes_reach(name: str) -> None:
    """Wait until every process of a run over several hosts has reached the barrier ``name`` (nothing with one
    process)."""
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices(name)
