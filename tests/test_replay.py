"""Per-task replay buffers: inserts wrap around, samples come only from filled rows of their own task."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.td3 import Transitions, buffer_bytes, init_buffer, insert, sample
from swat_jax.td3.replay import check_buffer_fits, free_memory_bytes, resized

TASKS, CAPACITY, LIMBS, FEATURES, COPIES = 3, 10, 4, 2, 4


def numbered_batch(start: int) -> Transitions:
    """Rows whose every value encodes (task, insertion number): task * 1000 + number."""
    numbers = jnp.arange(start, start + COPIES, dtype=jnp.float32)
    value = jnp.arange(TASKS, dtype=jnp.float32)[:, None] * 1000 + numbers[None, :]
    return Transitions(
        observation=jnp.broadcast_to(value[..., None, None], (TASKS, COPIES, LIMBS, FEATURES)),
        action=jnp.broadcast_to(value[..., None], (TASKS, COPIES, LIMBS)),
        reward=value,
        next_observation=jnp.broadcast_to(-value[..., None, None], (TASKS, COPIES, LIMBS, FEATURES)),
        terminated=(value % 2) == 0,
    )


def filled(inserts: int):
    buffer = init_buffer(TASKS, CAPACITY, LIMBS, FEATURES)
    for i in range(inserts):
        buffer = jax.jit(insert)(buffer, numbered_batch(i * COPIES))
    return buffer


def test_inserts_wrap_around_and_overwrite_the_oldest_rows():
    buffer = filled(3)  # 12 rows into 10: rows 0-1 hold numbers 10-11
    assert int(buffer.size) == CAPACITY and int(buffer.position) == 2
    np.testing.assert_array_equal(buffer.data.reward[0], [10, 11, 2, 3, 4, 5, 6, 7, 8, 9])
    np.testing.assert_array_equal(buffer.data.reward[2], 2000 + np.array([10, 11, 2, 3, 4, 5, 6, 7, 8, 9]))
    np.testing.assert_array_equal(buffer.data.next_observation[1, :, 0, 0], -buffer.data.reward[1])


def test_samples_come_from_filled_rows_of_their_own_task():
    buffer = filled(1)  # 4 of 10 rows filled
    batch = jax.jit(sample, static_argnums=2)(buffer, jax.random.PRNGKey(0), 256)
    reward = np.asarray(batch.reward)
    assert reward.shape == (TASKS, 256)
    for task in range(TASKS):
        assert set(np.unique(reward[task]) - task * 1000) == {0, 1, 2, 3}
    np.testing.assert_array_equal(batch.observation[..., 0, 0], reward)
    np.testing.assert_array_equal(batch.action[..., 0], reward)
    np.testing.assert_array_equal(batch.terminated, reward % 2 == 0)
    assert not np.array_equal(reward[0] % 1000, reward[1] % 1000), "tasks sample independently"


@pytest.mark.parametrize(("motors", "episode_ends"), [(1, False), (1, True), (3, False)])
def test_buffer_bytes_counts_every_array(motors, episode_ends):
    """Planar, with the n-step returns' episode-end flag, and with a 3D body's three actions per limb."""
    buffer = init_buffer(TASKS, CAPACITY, LIMBS, FEATURES, episode_ends, motors)
    arrays = jax.tree_util.tree_leaves(buffer.data)
    assert buffer_bytes(TASKS, CAPACITY, LIMBS, FEATURES, motors, episode_ends) == sum(
        a.nbytes for a in arrays
    )


def test_buffer_check_reports_gib_and_names_the_flag_to_lower():
    needed = buffer_bytes(5, 500_000, 13, 21)
    assert needed / 2**30 == pytest.approx(5.22, abs=0.01)
    report = check_buffer_fits(5, 500_000, 13, 21, free_bytes=80 * 2**30)
    assert "5.22 GiB" in report and "5 tasks x 500,000 transitions" in report
    with pytest.raises(
        MemoryError,
        match=r"5.22 GiB .* do not fit in 3.20 GiB .* lower --iteration\.capacity to at most 306,646$",
    ) as error:
        check_buffer_fits(5, 500_000, 13, 21, free_bytes=4 * 2**30)
    fitting = int(str(error.value).rsplit(" ", 1)[1].replace(",", ""))
    assert buffer_bytes(5, fitting, 13, 21) <= 0.8 * 4 * 2**30 < buffer_bytes(5, fitting + 1, 13, 21)
    assert free_memory_bytes() > 0


def inserted(buffer, inserts: int, first: int = 0):
    for i in range(first, first + inserts):
        buffer = jax.jit(insert)(buffer, numbered_batch(i * COPIES))
    return buffer


@pytest.mark.parametrize("rows", [8, 12, 20])
def test_a_resized_ring_holds_and_samples_what_a_ring_of_its_size_would(rows):
    """2 inserts of 4 rows into a ring of 10, resized to ``rows`` (>= 8: nothing lost), then 1 more insert:
    every array, the write position and the samples equal those of a ring of ``rows`` given all 3 inserts
    (12 rows into 8: the ring wraps after the resize as it would have)."""
    grown = inserted(resized(filled(2), rows, stored=2 * COPIES), 1, first=2)
    direct = inserted(init_buffer(TASKS, rows, LIMBS, FEATURES), 3)
    assert jax.tree.all(jax.tree.map(np.array_equal, grown, direct))
    key = jax.random.key(3)
    assert jax.tree.all(jax.tree.map(np.array_equal, sample(grown, key, 16), sample(direct, key, 16)))


def test_a_resize_refuses_to_lose_rows():
    with pytest.raises(ValueError, match="8 rows stored per task do not fit a ring of 6 rows"):
        resized(filled(2), 6, stored=2 * COPIES)
    with pytest.raises(
        ValueError, match="12 rows stored per task do not fit a ring of 20 rows resized from 10"
    ):
        resized(filled(3), 20, stored=3 * COPIES)


def test_a_seeded_buffer_resizes_on_its_ring_axis():
    seeded = jax.tree.map(lambda leaf: jnp.stack([leaf, leaf * 2]), filled(1).data)
    buffer = resized(filled(1).replace(data=seeded), 6, stored=COPIES, ring_axis=2)
    assert buffer.data.observation.shape == (2, TASKS, 6, LIMBS, FEATURES)
    np.testing.assert_array_equal(buffer.data.reward[1, 1], [2000, 2002, 2004, 2006, 0, 0])
