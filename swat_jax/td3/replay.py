"""One replay buffer per task, on the device: fixed-shape arrays plus pure ``insert`` and ``sample``.

T tasks, C capacity per task, L limbs (padded), F features per limb. Every task receives the same number
of transitions per insert (n copies per task), so one write position and one size serve all tasks (of
a seed: each seed has its own, as one that waits for its round's updates stores nothing).
Sizes are checked on the host before allocation (:func:`buffer_bytes`), never under jit.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax import axes
from swat_jax.morphology.batch import LimbBucket, bucket_slice

GIB = 2**30
USABLE_FRACTION = 0.8
"""Share of the free memory the buffers may take; the rest is for networks, simulation and XLA."""


@struct.dataclass
class Transitions:
    """A batch of transitions with leading axes [T, B] (B = copies on insert, batch size on sample)."""

    observation: jax.Array
    """[T, B, L, F] float32."""
    action: jax.Array
    """[T, B, L] float32 ([T, B, L, M] for 3D bodies, M actions per limb)."""
    reward: jax.Array
    """[T, B] float32."""
    next_observation: jax.Array
    """[T, B, L, F] float32, the state the action reached (before any automatic reset)."""
    terminated: jax.Array
    """[T, B] bool; a truncated episode is not terminated, so its TD target bootstraps."""
    ended: jax.Array | None = None
    """[T, B] bool, the episode ended with this step (terminated or truncated): stored for n-step returns
    only (:func:`sample_n_step`), which stop summing there."""
    bootstrap: jax.Array | None = None
    """[T, B] float32, the discount of the TD target's bootstrap, discount^m for the m rewards summed into
    ``reward``: set by :func:`sample_n_step` only (None: the learner's discount, one reward)."""

    def bucket(self, bucket: LimbBucket) -> Transitions:
        """The bucket's tasks, cut to its limb count: [len(tasks), B, limbs, ...]."""
        per_sample = [
            None if leaf is None else bucket_slice(leaf, bucket, ())
            for leaf in (self.reward, self.terminated, self.ended, self.bootstrap)
        ]
        return Transitions(
            bucket_slice(self.observation, bucket, (2,)),
            bucket_slice(self.action, bucket, (2,)),
            per_sample[0],
            bucket_slice(self.next_observation, bucket, (2,)),
            *per_sample[1:],
        )


@struct.dataclass
class ReplayBuffer:
    """Transitions [T, C, ...] with the tasks' ring-buffer write position and fill level."""

    data: Transitions = axes.field(task=0)
    position: jax.Array
    """[] int32 next row to write, in [0, C)."""
    size: jax.Array
    """[] int32 rows filled, at most C."""

    @property
    def capacity(self) -> int:
        return self.data.reward.shape[1]


def buffer_bytes(
    tasks: int, capacity: int, max_limbs: int, features: int, motors: int = 1, episode_ends: bool = False
) -> int:
    """Bytes of the transitions :func:`init_buffer` allocates for these arguments (its arrays' shapes,
    computed without allocating them)."""
    shapes = jax.eval_shape(lambda: init_buffer(tasks, capacity, max_limbs, features, episode_ends, motors))
    return sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree_util.tree_leaves(shapes.data))


def free_memory_bytes(device: jax.Device | None = None) -> int:
    """Free memory of ``device`` (default: the first JAX device): the allocator's limit minus what is in
    use on a GPU, the available physical memory on a CPU."""
    device = device or jax.devices()[0]
    stats = device.memory_stats() if device.platform != "cpu" else None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"] - stats.get("bytes_in_use", 0))
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_buffer_fits(
    tasks: int,
    capacity: int,
    max_limbs: int,
    features: int,
    free_bytes: int,
    *,
    seeds: int = 1,
    flag: str = "--iteration.capacity",
    flag_rows: int = 1,
    why: str = "",
    motors: int = 1,
    episode_ends: bool = False,
) -> str:
    """Host-side check before allocating: a one-line size report, or MemoryError saying what to lower.

    Args:
        free_bytes: memory available for the buffers' device (see :func:`free_memory_bytes`).
        seeds: independent runs, each with its own buffers.
        flag: the option that sets ``capacity``, named in the error.
        flag_rows: the rows that one of ``flag``'s units sets per task's row: 1 for rows per task, ``tasks``
            for a cap on the rows of all tasks together.
        why: why the buffers have ``capacity`` rows, appended to the report.
        motors, episode_ends: as :func:`init_buffer`'s (3D bodies; n-step returns).
    """
    needed = seeds * buffer_bytes(tasks, capacity, max_limbs, features, motors, episode_ends)
    usable = int(USABLE_FRACTION * free_bytes)
    runs = f"{seeds} seeds x " if seeds > 1 else ""
    report = (
        f"replay buffers: {needed / GIB:.2f} GiB ({runs}{tasks} tasks x {capacity:,} transitions x "
        f"{max_limbs} limbs x {features} features{why})"
    )
    if needed > usable:
        fitting = usable // (seeds * buffer_bytes(tasks, 1, max_limbs, features, motors, episode_ends))
        raise MemoryError(
            f"{report} do not fit in {usable / GIB:.2f} GiB ({USABLE_FRACTION:.0%} of the "
            f"{free_bytes / GIB:.2f} GiB free); lower {flag} to at most {fitting * flag_rows:,}"
        )
    return report


def init_buffer(
    tasks: int, capacity: int, max_limbs: int, features: int, episode_ends: bool = False, motors: int = 1
) -> ReplayBuffer:
    """An empty buffer (all zeros; every array its own buffer, so a jitted step may donate them); with
    ``episode_ends`` it stores :attr:`Transitions.ended` too (n-step returns); ``motors`` actions per limb
    (an action axis [M] after the limbs when more than 1)."""
    observation_shape = (tasks, capacity, max_limbs, features)
    action_shape = (tasks, capacity, max_limbs) + ((motors,) if motors > 1 else ())
    return ReplayBuffer(
        data=Transitions(
            observation=jnp.zeros(observation_shape, jnp.float32),
            action=jnp.zeros(action_shape, jnp.float32),
            reward=jnp.zeros((tasks, capacity), jnp.float32),
            next_observation=jnp.zeros(observation_shape, jnp.float32),
            terminated=jnp.zeros((tasks, capacity), bool),
            ended=jnp.zeros((tasks, capacity), bool) if episode_ends else None,
        ),
        position=jnp.zeros((), jnp.int32),
        size=jnp.zeros((), jnp.int32),
    )


def resized(buffer: ReplayBuffer, rows: int, stored: int, ring_axis: int = 1) -> ReplayBuffer:
    """``buffer`` with rings of ``rows`` rows per task holding what a ring of that size would hold after the
    same inserts: at most ``stored`` rows per task (its ``size``: per seed, with a seed axis), written in order
    from row 0 and never overwritten.

    Args:
        buffer: its data's ring axis is ``ring_axis`` (1 for one seed's [T, C, ...], 2 with a seed axis in
            front); its rows past its size are empty.
        rows: the new ring size, at least ``stored``.

    Raises:
        ValueError: ``stored`` exceeds ``rows`` or the old ring (some rows would be lost, or were overwritten).
    """
    old_rows = buffer.data.reward.shape[ring_axis]
    if stored > min(rows, old_rows):
        raise ValueError(
            f"{stored:,} rows stored per task do not fit a ring of {rows:,} rows resized from {old_rows:,}"
        )

    def fit(leaf: jax.Array) -> jax.Array:
        kept = jax.lax.slice_in_dim(leaf, 0, min(rows, old_rows), axis=ring_axis)
        padding = [(0, 0)] * leaf.ndim
        padding[ring_axis] = (0, rows - kept.shape[ring_axis])
        return jnp.pad(kept, padding)

    return ReplayBuffer(
        data=jax.tree_util.tree_map(fit, buffer.data),
        position=buffer.size % rows,
        size=buffer.size,
    )


def insert(buffer: ReplayBuffer, batch: Transitions, write: jax.Array | None = None) -> ReplayBuffer:
    """Write ``batch`` [T, n, ...] at the write position, wrapping around; the oldest rows go first. With
    ``write`` [] bool, only where it is True (else the buffer is left as it was)."""
    copies = batch.reward.shape[1]
    rows = (buffer.position + jnp.arange(copies)) % buffer.capacity
    if write is None:
        data = jax.tree_util.tree_map(lambda stored, new: stored.at[:, rows].set(new), buffer.data, batch)
        written = copies
    else:
        data = jax.tree_util.tree_map(
            lambda stored, new: stored.at[:, rows].set(jnp.where(write, new, stored[:, rows])),
            buffer.data,
            batch,
        )
        written = jnp.where(write, copies, 0)
    return ReplayBuffer(
        data=data,
        position=(buffer.position + written) % buffer.capacity,
        size=jnp.minimum(buffer.size + written, buffer.capacity),
    )


def sample(buffer: ReplayBuffer, rng: jax.Array, batch_size: int) -> Transitions:
    """``batch_size`` rows per task, uniformly and independently per task from the filled rows."""
    return _gathered(buffer.data, _sampled_rows(buffer, rng, batch_size))


def sample_n_step(
    buffer: ReplayBuffer, rng: jax.Array, batch_size: int, steps: int, discount: float, stride: int
) -> Transitions:
    """``batch_size`` rows per task as :func:`sample` draws them, each with up to ``steps`` rewards of its
    copy's episode summed: the n-step return (Sutton and Barto 2018, section 7.1; FastTD3's and MR.Q's TD3).

    An insert writes one row per copy at consecutive positions, so the next step of the copy of row r is
    row (r + ``stride``) mod C, ``stride`` the copies per insert. A sampled row's return is
    sum_{k < m} discount^k r_{t+k} over the m <= ``steps`` rows up to and including the first whose episode
    ended (:attr:`Transitions.ended`) or the newest row of its copy; its ``next_observation`` and
    ``terminated`` are that last row's and its ``bootstrap`` is discount^m. With ``steps`` 1 every field
    equals :func:`sample`'s and ``bootstrap`` is ``discount``.

    Returns:
        [T, batch_size, ...] transitions with :attr:`Transitions.bootstrap` [T, batch_size]; no ``ended``.
    """
    data = buffer.data
    rows = _sampled_rows(buffer, rng, batch_size)
    # Rows written after each sampled row: the ring's newest row is position - 1.
    newer = (buffer.position - 1 - rows) % buffer.capacity
    first = _gathered(data.replace(next_observation=None, terminated=None), rows)  # the last row's, below
    reward, last, scale, alive = first.reward, rows, jnp.full(rows.shape, discount, jnp.float32), ~first.ended
    for k in range(1, steps):
        taken = alive & (k * stride <= newer)
        row = (rows + k * stride) % buffer.capacity
        later = _gathered(Transitions(None, None, data.reward, None, None, data.ended), row)
        reward = reward + jnp.where(taken, scale * later.reward, 0.0)
        last = jnp.where(taken, row, last)
        scale = jnp.where(taken, scale * discount, scale)
        alive = taken & ~later.ended
    end = _gathered(Transitions(None, None, None, data.next_observation, data.terminated), last)
    return first.replace(
        reward=reward,
        next_observation=end.next_observation,
        terminated=end.terminated,
        ended=None,
        bootstrap=scale,
    )


def _sampled_rows(buffer: ReplayBuffer, rng: jax.Array, batch_size: int) -> jax.Array:
    """[T, batch_size] int32 rows drawn uniformly and independently per task from the filled ones."""
    tasks = buffer.data.reward.shape[0]
    return jax.random.randint(rng, (tasks, batch_size), 0, jnp.maximum(buffer.size, 1))


def _gathered(data: Transitions, rows: jax.Array) -> Transitions:
    """Each task's ``rows`` [T, B] of ``data`` [T, C, ...] (its None fields stay None)."""
    return jax.tree_util.tree_map(lambda stored: jax.vmap(lambda s, r: s[r])(stored, rows), data)
