"""Structural encodings of a limb tree (paper sections 4.1 and 4.2), computed once per body on the host.

Positional (section 4.1, eq. 3): the limb tree rooted at the torso is turned into its
left-child-right-sibling (LCRS) binary form, children ordered by limb index (MJCF order);
each limb's index in the pre-, in- and post-order traversals of that binary tree feeds one
learned embedding table per traversal. Pre- and in-order together identify a binary tree,
hence the original tree.

Relational (section 4.2, eq. 4): for every limb pair, the normalised graph Laplacian, the
shortest-path distance divided by the number of limbs, and personalised PageRank. A linear
map of these three values becomes an additive attention bias.

All inputs are ``parents`` tuples in MJCF pre-order: ``parents[0] == -1`` (the torso) and
every other limb's parent precedes it. Everything here is plain NumPy.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

TRAVERSAL_NAMES = ("pre", "in", "post")
"""Column order of :func:`traversal_positions`."""
RELATION_NAMES = ("laplacian", "spd", "ppr")
"""Channel order of :func:`relation_features` (the three relations of eq. 4)."""


def _validate_parents(parents: Sequence[int]) -> None:
    """Raise ValueError unless ``parents`` is a tree rooted at limb 0 listed in pre-order.

    Pre-order means each limb's parent is the previous limb or one of its ancestors, so
    every subtree occupies a contiguous index range (the order MJCF nesting produces).
    """
    if len(parents) == 0:
        raise ValueError("parents is empty: a body needs at least a torso")
    if parents[0] != -1:
        raise ValueError(f"parents[0] must be -1 (the torso is the root), got {parents[0]}")
    ancestors = [0]
    for limb in range(1, len(parents)):
        parent = parents[limb]
        if not 0 <= parent < limb:
            raise ValueError(
                f"parents[{limb}] = {parent}: every non-torso parent must be an earlier limb "
                f"(0 <= parent < {limb})"
            )
        if parent not in ancestors:
            raise ValueError(
                f"parents {tuple(parents)} are not in pre-order: limb {limb} has parent {parent}, "
                f"which is not limb {limb - 1} or one of its ancestors {ancestors[:-1]}"
            )
        del ancestors[ancestors.index(parent) + 1 :]
        ancestors.append(limb)


def adjacency(parents: Sequence[int]) -> np.ndarray:
    """Symmetric 0/1 adjacency of the limb tree.

    Args:
        parents: [n] parent index per limb in pre-order, -1 for the torso at index 0.

    Returns:
        [n, n] float64, ``A[i, j] = 1`` when limbs i and j are joined (parent and child).

    Raises:
        ValueError: ``parents`` is empty, not rooted at limb 0, or not in pre-order.
    """
    _validate_parents(parents)
    n = len(parents)
    adj = np.zeros((n, n), np.float64)
    children = np.arange(1, n)
    adj[children, np.asarray(parents[1:], int)] = 1.0
    return np.maximum(adj, adj.T)


def _lcrs_links(parents: Sequence[int]) -> tuple[list[int], list[int]]:
    """Left (first child) and right (next sibling) links of the LCRS binary tree; -1 = none."""
    n = len(parents)
    left, right, last_child = [-1] * n, [-1] * n, [-1] * n
    for limb in range(1, n):
        parent = parents[limb]
        if last_child[parent] == -1:
            left[parent] = limb
        else:
            right[last_child[parent]] = limb
        last_child[parent] = limb
    return left, right


def _traversal(left: list[int], right: list[int], kind: str, reference_inorder: bool) -> list[int]:
    """Limb indices in ``kind`` ("pre", "in" or "post") order of the binary tree rooted at 0."""
    order: list[int] = []

    def visit(node: int) -> None:
        if node == -1:
            return
        first, second = left[node], right[node]
        if kind == "in" and reference_inorder and first == -1:
            first, second = second, -1
        if kind == "pre":
            order.append(node)
        visit(first)
        if kind == "in":
            order.append(node)
        visit(second)
        if kind == "post":
            order.append(node)

    visit(0)
    return order


def traversal_positions(parents: Sequence[int], *, reference_inorder: bool = False) -> np.ndarray:
    """Position of each limb in the pre-, in- and post-order of the LCRS binary tree (eq. 3).

    In the LCRS form a limb's left link is its first child and its right link its next
    sibling, children ordered by limb index. The in-order is a true binary in-order (left
    subtree, node, right subtree), so column 0 equals ``arange(n)`` and (pre, in) determine
    the tree.

    Args:
        parents: [n] parent index per limb in pre-order, -1 for the torso at index 0.
        reference_inorder: reproduce the reference code's in-order (docs/fidelity.md, row 13):
            a limb with no left link (no children) but a right link (a next sibling) treats
            that sibling as its left child, so the limb is listed after its sibling's subtree
            instead of before it. Pre- and post-order are unaffected by this change.

    Returns:
        [n, 3] int32, columns in :data:`TRAVERSAL_NAMES` order, each a permutation of range(n).
    """
    _validate_parents(parents)
    left, right = _lcrs_links(parents)
    n = len(parents)
    positions = np.empty((n, len(TRAVERSAL_NAMES)), np.int32)
    for column, kind in enumerate(TRAVERSAL_NAMES):
        positions[_traversal(left, right, kind, reference_inorder), column] = np.arange(n)
    return positions


def normalized_laplacian(adj: np.ndarray) -> np.ndarray:
    """Normalised graph Laplacian ``D^-1/2 (D - A) D^-1/2`` (section 4.2, R_lap of eq. 4).

    A limb of degree 0 (a single-limb body) gets an all-zero row and column, not NaN.

    Args:
        adj: [n, n] symmetric 0/1 adjacency.

    Returns:
        [n, n] float64; diagonal 1 for limbs with neighbours, ``-1 / sqrt(d_i d_j)`` for
        neighbours i, j, 0 elsewhere.
    """
    degree = adj.sum(axis=1)
    inv_sqrt = np.divide(1.0, np.sqrt(degree), out=np.zeros_like(degree), where=degree > 0)
    return inv_sqrt[:, None] * (np.diag(degree) - adj) * inv_sqrt[None, :]


def shortest_path_hops(adj: np.ndarray) -> np.ndarray:
    """Shortest-path distance in edges between every limb pair, by breadth-first search.

    Args:
        adj: [n, n] symmetric 0/1 adjacency of a connected graph.

    Returns:
        [n, n] int32 hop counts, zero on the diagonal.

    Raises:
        ValueError: the graph is not connected.
    """
    n = adj.shape[0]
    neighbours = [np.flatnonzero(row) for row in adj]
    hops = np.full((n, n), -1, np.int32)
    for source in range(n):
        hops[source, source] = 0
        queue = deque([source])
        while queue:
            node = queue.popleft()
            for other in neighbours[node]:
                if hops[source, other] < 0:
                    hops[source, other] = hops[source, node] + 1
                    queue.append(other)
    if (hops < 0).any():
        raise ValueError("adjacency is not connected: some limb pairs have no path")
    return hops


def personalized_pagerank(adj: np.ndarray, restart: float = 0.1) -> np.ndarray:
    """Personalised PageRank of every limb (section 4.2, R_ppr of eq. 4).

    The walk follows ``P`` = row-normalised ``A + I`` and jumps back to the restart limb
    with probability ``restart``: ``PPR = restart * inv(I - (1 - restart) P)``.

    Args:
        adj: [n, n] symmetric 0/1 adjacency.
        restart: restart probability epsilon, in (0, 1].

    Returns:
        [n, n] float64; row i is the visitation distribution of the walk restarting at limb i
        (nonnegative, sums to 1).
    """
    if not 0.0 < restart <= 1.0:
        raise ValueError(f"restart must be in (0, 1], got {restart}")
    n = adj.shape[0]
    walk = adj + np.eye(n)
    transition = walk / walk.sum(axis=1, keepdims=True)
    return restart * np.linalg.inv(np.eye(n) - (1.0 - restart) * transition)


def relation_features(parents: Sequence[int]) -> np.ndarray:
    """The three pairwise relations of eq. 4 for one body.

    Args:
        parents: [n] parent index per limb in pre-order, -1 for the torso at index 0.

    Returns:
        [n, n, 3] float32, channels in :data:`RELATION_NAMES` order: normalised Laplacian,
        shortest-path hops / n, personalised PageRank (restart 0.1).
    """
    adj = adjacency(parents)
    n = adj.shape[0]
    channels = (normalized_laplacian(adj), shortest_path_hops(adj) / n, personalized_pagerank(adj))
    return np.stack(channels, axis=-1).astype(np.float32)
