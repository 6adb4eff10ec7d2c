"""Structural encodings (paper sections 4.1-4.2) on hand-worked limb trees, and their padded batch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from swat_jax.morphology.batch import StructureBatch, pad_structures
from swat_jax.morphology.encodings import (
    RELATION_NAMES,
    TRAVERSAL_NAMES,
    adjacency,
    normalized_laplacian,
    personalized_pagerank,
    relation_features,
    shortest_path_hops,
    traversal_positions,
)
from swat_jax.morphology.types import FamilySpec, Morphology, ResetNoise, Reward, Termination

CHAIN_3 = (-1, 0, 1)
CHAIN_5 = (-1, 0, 1, 2, 3)
STAR_5 = (-1, 0, 0, 0, 0)
FULL_BINARY_7 = (-1, 0, 1, 1, 0, 4, 4)
WALKER_3 = (-1, 0, 0)
WALKER_7_MAIN = (-1, 0, 1, 2, 0, 4, 5)
CHEETAH_7_FULL = (-1, 0, 1, 2, 0, 4, 5)
HUMANOID_2D_9_FULL = (-1, 0, 1, 0, 3, 0, 5, 0, 7)
NERVENET_OSTRICH = (-1, 0, 0, 0, 3, 4, 0, 6, 7)
NERVENET_FULLCHEETAH = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11)

TREES = {
    "single": (-1,),
    "chain_3": CHAIN_3,
    "chain_5": CHAIN_5,
    "star_5": STAR_5,
    "full_binary_7": FULL_BINARY_7,
    "walker_3": WALKER_3,
    "walker_7_main": WALKER_7_MAIN,
    "cheetah_7_full": CHEETAH_7_FULL,
    "humanoid_2d_9_full": HUMANOID_2D_9_FULL,
    "nervenet_ostrich": NERVENET_OSTRICH,
    "nervenet_fullcheetah": NERVENET_FULLCHEETAH,
}
MULTI_LIMB = {name: parents for name, parents in TREES.items() if len(parents) > 1}

FAMILY = FamilySpec(
    name="test",
    limb_type_rules=(("torso",), ("thigh",), ("leg",)),
    reward=Reward(alive_bonus=1.0, control_cost=1e-3),
    termination=Termination(),
    reset_noise=ResetNoise(qpos_uniform=5e-3, qvel_scale=5e-3),
)


def make_body(name: str, parents: tuple[int, ...]) -> Morphology:
    """A Morphology with the given tree and distinct, recognisable per-limb values."""
    n = len(parents)
    return Morphology(
        name=name,
        path=Path(f"{name}.xml"),
        family=FAMILY,
        limb_names=tuple(f"limb{i}" for i in range(n)),
        parents=parents,
        limb_types=tuple(i % 3 if i < 5 else -1 for i in range(n)),
        joint_names=((), *tuple((f"joint{i}",) for i in range(1, n))),
        joint_ranges=((), *tuple(((-10.0 * i, 5.0 * i),) for i in range(1, n))),
        limb_motors=((), *tuple((i - 1,) for i in range(1, n))),
        timestep=0.002,
        integrator="RK4",
    )


def lcrs_from_parents(parents: tuple[int, ...]) -> dict[int, tuple[int, int]]:
    """Limb -> (first child, next sibling) of the LCRS binary tree, -1 for none."""
    children = {limb: [c for c in range(len(parents)) if parents[c] == limb] for limb in range(len(parents))}
    links = {}
    for limb in range(len(parents)):
        first_child = children[limb][0] if children[limb] else -1
        siblings = children[parents[limb]] if parents[limb] >= 0 else [limb]
        rank = siblings.index(limb)
        next_sibling = siblings[rank + 1] if rank + 1 < len(siblings) else -1
        links[limb] = (first_child, next_sibling)
    return links


def binary_tree_from_pre_in(pre_seq: list[int], in_seq: list[int]) -> dict[int, tuple[int, int]]:
    """Rebuild node -> (left, right) of a binary tree from its pre-order and in-order sequences."""
    links: dict[int, tuple[int, int]] = {}

    def build(pre: list[int], ino: list[int]) -> int:
        if not pre:
            return -1
        root = pre[0]
        split = ino.index(root)
        left = build(pre[1 : 1 + split], ino[:split])
        right = build(pre[1 + split :], ino[split + 1 :])
        links[root] = (left, right)
        return root

    build(pre_seq, in_seq)
    return links


def sequence(positions: np.ndarray) -> list[int]:
    """Limb visited at each step, from a column of per-limb positions."""
    return np.argsort(positions).tolist()


@pytest.mark.parametrize("reference_inorder", [False, True])
@pytest.mark.parametrize("parents", TREES.values(), ids=TREES.keys())
def test_traversal_columns_are_permutations_and_pre_is_identity(parents, reference_inorder):
    positions = traversal_positions(parents, reference_inorder=reference_inorder)
    n = len(parents)
    assert positions.shape == (n, 3) and positions.dtype == np.int32
    for column in range(3):
        assert sorted(positions[:, column].tolist()) == list(range(n))
    np.testing.assert_array_equal(positions[:, 0], np.arange(n))
    assert positions[0, 2] == n - 1
    assert TRAVERSAL_NAMES == ("pre", "in", "post")


@pytest.mark.parametrize("parents", TREES.values(), ids=TREES.keys())
def test_pre_and_in_order_reconstruct_the_lcrs_tree(parents):
    positions = traversal_positions(parents)
    rebuilt = binary_tree_from_pre_in(sequence(positions[:, 0]), sequence(positions[:, 1]))
    assert rebuilt == lcrs_from_parents(parents)


EXPECTED_TRAVERSALS = {
    # name: (parents, pre, true in, reference in, post)
    "walker_3": (WALKER_3, [0, 1, 2], [2, 0, 1], [2, 1, 0], [2, 1, 0]),
    "star_5": (STAR_5, [0, 1, 2, 3, 4], [4, 0, 1, 2, 3], [4, 3, 2, 1, 0], [4, 3, 2, 1, 0]),
    "full_binary_7": (
        FULL_BINARY_7,
        [0, 1, 2, 3, 4, 5, 6],
        [6, 2, 0, 1, 5, 3, 4],
        [6, 2, 1, 0, 5, 4, 3],
        [6, 5, 1, 0, 4, 3, 2],
    ),
    "chain_5": (CHAIN_5, [0, 1, 2, 3, 4], [4, 3, 2, 1, 0], [4, 3, 2, 1, 0], [4, 3, 2, 1, 0]),
    "walker_7_main": (
        WALKER_7_MAIN,
        [0, 1, 2, 3, 4, 5, 6],
        [6, 2, 1, 0, 5, 4, 3],
        [6, 2, 1, 0, 5, 4, 3],
        [6, 5, 1, 0, 4, 3, 2],
    ),
    "nervenet_ostrich": (
        NERVENET_OSTRICH,
        list(range(9)),
        [8, 0, 1, 4, 3, 2, 7, 6, 5],
        [8, 7, 6, 2, 1, 0, 5, 4, 3],
        [8, 7, 6, 5, 1, 0, 4, 3, 2],
    ),
}


@pytest.mark.parametrize("name", EXPECTED_TRAVERSALS)
def test_hand_computed_traversals(name):
    parents, pre, true_in, reference_in, post = EXPECTED_TRAVERSALS[name]
    true_positions = traversal_positions(parents)
    reference_positions = traversal_positions(parents, reference_inorder=True)
    np.testing.assert_array_equal(true_positions, np.stack([pre, true_in, post], axis=1))
    np.testing.assert_array_equal(reference_positions, np.stack([pre, reference_in, post], axis=1))


@pytest.mark.parametrize("parents", [WALKER_3, STAR_5, FULL_BINARY_7, NERVENET_OSTRICH])
def test_reference_inorder_differs_when_a_leaf_has_a_next_sibling(parents):
    true_in = traversal_positions(parents)[:, 1]
    reference_in = traversal_positions(parents, reference_inorder=True)[:, 1]
    assert not np.array_equal(true_in, reference_in)


@pytest.mark.parametrize(
    "parents", [CHAIN_3, CHAIN_5, WALKER_7_MAIN, CHEETAH_7_FULL, HUMANOID_2D_9_FULL, NERVENET_FULLCHEETAH]
)
def test_reference_inorder_agrees_when_no_leaf_has_a_next_sibling(parents):
    np.testing.assert_array_equal(
        traversal_positions(parents), traversal_positions(parents, reference_inorder=True)
    )


def test_reference_inorder_makes_walker_3_look_like_a_chain():
    reference_walker = traversal_positions(WALKER_3, reference_inorder=True)
    np.testing.assert_array_equal(reference_walker, traversal_positions(CHAIN_3))
    assert not np.array_equal(traversal_positions(WALKER_3), traversal_positions(CHAIN_3))


@pytest.mark.parametrize(
    "parents, message",
    [
        ((), "empty"),
        ((0, 0), "torso"),
        ((-1, 1), "earlier limb"),
        ((-1, 0, 5), "earlier limb"),
        ((-1, 0, 0, 1), "pre-order"),
    ],
)
def test_invalid_parents_raise(parents, message):
    with pytest.raises(ValueError, match=message):
        adjacency(parents)
    if parents:
        with pytest.raises(ValueError, match=message):
            traversal_positions(parents)


@pytest.mark.parametrize("parents", TREES.values(), ids=TREES.keys())
def test_adjacency_is_the_tree(parents):
    adj = adjacency(parents)
    n = len(parents)
    assert adj.shape == (n, n) and adj.dtype == np.float64
    np.testing.assert_array_equal(adj, adj.T)
    assert adj.sum() == 2 * (n - 1)
    for limb in range(1, n):
        assert adj[limb, parents[limb]] == 1.0


@pytest.mark.parametrize("parents", MULTI_LIMB.values(), ids=MULTI_LIMB.keys())
def test_normalized_laplacian_entries(parents):
    adj = adjacency(parents)
    lap = normalized_laplacian(adj)
    degree = adj.sum(axis=1)
    np.testing.assert_allclose(lap, lap.T)
    np.testing.assert_allclose(np.diag(lap), 1.0)
    for i, j in zip(*np.nonzero(~np.eye(len(parents), dtype=bool)), strict=True):
        expected = -1.0 / np.sqrt(degree[i] * degree[j]) if adj[i, j] else 0.0
        assert lap[i, j] == pytest.approx(expected)


def test_normalized_laplacian_values_on_chain_and_single_limb():
    lap = normalized_laplacian(adjacency(CHAIN_3))
    np.testing.assert_allclose(lap[0, 1], -0.7071, atol=1e-4)
    np.testing.assert_allclose(lap[1, 2], -0.7071, atol=1e-4)
    assert lap[0, 2] == 0.0
    np.testing.assert_array_equal(normalized_laplacian(adjacency((-1,))), np.zeros((1, 1)))


@pytest.mark.parametrize("parents", TREES.values(), ids=TREES.keys())
def test_hops_are_tree_distances(parents):
    hops = shortest_path_hops(adjacency(parents))
    n = len(parents)
    np.testing.assert_array_equal(hops, hops.T)
    np.testing.assert_array_equal(np.diag(hops), np.zeros(n))
    for limb in range(1, n):
        assert hops[limb, parents[limb]] == 1
        assert hops[0, limb] == hops[0, parents[limb]] + 1


@pytest.mark.parametrize(
    "parents, i, j, expected",
    [
        (STAR_5, 1, 4, 2),
        (STAR_5, 2, 3, 2),
        (CHAIN_5, 0, 4, 4),
        (CHAIN_5, 1, 3, 2),
        (FULL_BINARY_7, 2, 6, 4),
        (HUMANOID_2D_9_FULL, 2, 8, 4),
        (NERVENET_OSTRICH, 5, 8, 6),
        (NERVENET_OSTRICH, 1, 2, 2),
    ],
)
def test_hops_hand_values(parents, i, j, expected):
    assert shortest_path_hops(adjacency(parents))[i, j] == expected


def test_hops_reject_disconnected_graph():
    with pytest.raises(ValueError, match="not connected"):
        shortest_path_hops(np.zeros((2, 2)))


@pytest.mark.parametrize("parents", TREES.values(), ids=TREES.keys())
def test_ppr_rows_are_fixed_point_distributions(parents):
    adj = adjacency(parents)
    ppr = personalized_pagerank(adj)
    n = len(parents)
    assert (ppr >= 0).all()
    np.testing.assert_allclose(ppr.sum(axis=1), 1.0)
    walk = (adj + np.eye(n)) / (adj + np.eye(n)).sum(axis=1, keepdims=True)
    np.testing.assert_allclose(ppr, 0.9 * ppr @ walk + 0.1 * np.eye(n), atol=1e-12)


def test_ppr_hopper_3_worked_values():
    expected = [[0.3953, 0.3913, 0.2134], [0.2609, 0.4783, 0.2609], [0.2134, 0.3913, 0.3953]]
    np.testing.assert_allclose(personalized_pagerank(adjacency(CHAIN_3)), expected, atol=5e-5)


def test_ppr_rejects_bad_restart():
    with pytest.raises(ValueError, match="restart"):
        personalized_pagerank(adjacency(CHAIN_3), restart=0.0)


@pytest.mark.parametrize("parents", TREES.values(), ids=TREES.keys())
def test_relation_features_channels(parents):
    features = relation_features(parents)
    n = len(parents)
    adj = adjacency(parents)
    assert features.shape == (n, n, 3) and features.dtype == np.float32
    assert RELATION_NAMES == ("laplacian", "spd", "ppr")
    np.testing.assert_allclose(features[..., 0], normalized_laplacian(adj), atol=1e-6)
    np.testing.assert_allclose(features[..., 1], shortest_path_hops(adj) / n, atol=1e-6)
    np.testing.assert_allclose(features[..., 2], personalized_pagerank(adj), atol=1e-6)


def test_relation_features_hopper_3_spd_from_torso():
    np.testing.assert_allclose(relation_features(CHAIN_3)[0, :, 1], [0.0, 1 / 3, 2 / 3], atol=1e-6)


BATCH_BODIES = {"hopper_3": CHAIN_3, "walker_7_main": WALKER_7_MAIN, "nervenet_ostrich": NERVENET_OSTRICH}


def make_batch_bodies() -> list[Morphology]:
    return [make_body(name, parents) for name, parents in BATCH_BODIES.items()]


def test_pad_structures_shapes_and_dtypes():
    batch = pad_structures(make_batch_bodies())
    assert isinstance(batch, StructureBatch)
    k, width = 3, 9
    expected = {
        "limb_mask": ((k, width), np.bool_),
        "parents": ((k, width), np.int32),
        "traversal_positions": ((k, width, 3), np.int32),
        "relations": ((k, width, width, 3), np.float32),
        "limb_types": ((k, width), np.int32),
        "motor_mask": ((k, width, 1), np.bool_),
        "num_limbs": ((k,), np.int32),
    }
    for field, (shape, dtype) in expected.items():
        value = getattr(batch, field)
        assert value.shape == shape and value.dtype == dtype, field
    np.testing.assert_array_equal(batch.num_limbs, [3, 7, 9])


@pytest.mark.parametrize("reference_inorder", [False, True])
def test_pad_structures_real_slices_match_unpadded_encodings(reference_inorder):
    bodies = make_batch_bodies()
    batch = pad_structures(bodies, reference_inorder=reference_inorder)
    for row, body in enumerate(bodies):
        n = body.num_limbs
        np.testing.assert_array_equal(batch.limb_mask[row], np.arange(9) < n)
        np.testing.assert_array_equal(batch.parents[row, :n], body.parents)
        np.testing.assert_array_equal(
            batch.traversal_positions[row, :n],
            traversal_positions(body.parents, reference_inorder=reference_inorder),
        )
        np.testing.assert_array_equal(batch.relations[row, :n, :n], relation_features(body.parents))
        np.testing.assert_array_equal(batch.limb_types[row, :n], body.limb_types)
        np.testing.assert_array_equal(batch.motor_mask[row, :n], body.motor_mask())
    assert batch.motor_mask[1, :, 0].tolist() == [False] + [True] * (bodies[1].num_limbs - 1) + [False] * (
        9 - bodies[1].num_limbs
    ), "the torso and padding have no motor"


def test_pad_structures_padding_values():
    batch = pad_structures(make_batch_bodies(), max_limbs=12)
    for row, n in enumerate(batch.num_limbs):
        assert not batch.limb_mask[row, n:].any()
        assert (batch.parents[row, n:] == -1).all()
        assert (batch.traversal_positions[row, n:] == 0).all()
        assert (batch.relations[row, n:, :] == 0).all()
        assert (batch.relations[row, :, n:] == 0).all()
        assert (batch.limb_types[row, n:] == -1).all()
        assert not batch.motor_mask[row, n:].any()


def test_pad_structures_growing_max_limbs_keeps_real_entries():
    small = pad_structures(make_batch_bodies())
    large = pad_structures(make_batch_bodies(), max_limbs=16)
    assert large.limb_mask.shape == (3, 16)
    for field, small_value, large_value in zip(StructureBatch._fields, small, large, strict=True):
        if field == "num_limbs":
            np.testing.assert_array_equal(small_value, large_value)
        elif field == "relations":
            np.testing.assert_array_equal(small_value, large_value[:, :9, :9])
        else:
            np.testing.assert_array_equal(small_value, large_value[:, :9], err_msg=field)


def test_pad_structures_rejects_too_large_body_and_empty_input():
    with pytest.raises(ValueError, match=r"'nervenet_ostrich' has 9 limbs.*max_limbs=8"):
        pad_structures(make_batch_bodies(), max_limbs=8)
    with pytest.raises(ValueError, match="at least one body"):
        pad_structures([])
