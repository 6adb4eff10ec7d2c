"""The batch axes of the training state, declared once per field: vmaps and shardings read them here.

Besides the shapes of its arrays, a run's state has two kinds of batch axes:

- the **seed** axis: every array of a state with S seeds leads with [S] (independent runs in one
  program), except the fields declared ``seeded=False``: the step counters, equal in every seed and
  shared, so that the branches on them stay branches under ``vmap`` instead of becoming selects that
  compute both sides for every seed;
- a **split** axis: the axis of one seed's array that the ``tasks`` axis of a device mesh may split
  (:mod:`swat_jax.td3.sharding`): the task axis [K] of what is per task, or the copy axis [n] of what
  is per environment copy.

A state dataclass declares them with :func:`field` next to each field. An undeclared field has a seed
axis and no split axis; an undeclared field whose value is itself a state dataclass is read field by
field; a declared field's axes hold for its whole subtree. :func:`seed_axes` and :func:`split_axes` turn
a state into the prefix trees that ``jax.vmap`` and the shardings take, and :func:`over_seeds` maps a
function of one seed over the seed axis.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
from flax import struct

AXES = "swat_jax.axes"
"""The key of a field's :class:`Axes` in its dataclass metadata."""


@dataclasses.dataclass(frozen=True)
class Axes:
    """The batch axes of one field (of every array of its subtree)."""

    seeded: bool = True
    """The arrays lead with the seed axis [S] (False: one value shared by every seed)."""
    task: int | None = None
    """The task axis [K] of one seed's array, or None."""
    copy: int | None = None
    """The environment-copy axis [n] of one seed's array, or None."""


def field(
    *,
    seeded: bool = True,
    task: int | None = None,
    copy: int | None = None,
    default: Any = dataclasses.MISSING,
) -> Any:
    """A pytree field of a ``flax.struct`` dataclass with its batch axes (:class:`Axes`) declared (and its
    ``default``, if given)."""
    return struct.field(metadata={AXES: Axes(seeded, task, copy)}, default=default)


def _declared(tree: Any, read: Callable[[Axes], int | None], axes: Axes | None = None) -> Any:
    """A prefix tree of ``tree``: ``read(axes)`` for every declared subtree (:class:`Axes` () for an
    undeclared one that is not a state dataclass)."""
    if axes is not None or not (dataclasses.is_dataclass(tree) and not isinstance(tree, type)):
        return read(axes or Axes())
    prefix = {}
    for entry in dataclasses.fields(tree):
        value = getattr(tree, entry.name)
        if entry.metadata.get("pytree_node", True):
            prefix[entry.name] = _declared(value, read, entry.metadata.get(AXES))
    return tree.replace(**prefix)


def seed_axes(tree: Any) -> Any:
    """``jax.vmap``'s axes prefix of a seeded state ``tree``: 0 for the seeded subtrees, None for the shared."""
    return _declared(tree, lambda axes: 0 if axes.seeded else None)


def split_axes(tree: Any, tasks: bool, copies: bool) -> Any:
    """Per subtree of one seed's state ``tree``, the axis split over a mesh's ``tasks`` axis, or None: the
    copy axis where ``copies`` and it has one, else the task axis where ``tasks`` and it has one."""

    def split(axes: Axes) -> int | None:
        if copies and axes.copy is not None:
            return axes.copy
        return axes.task if tasks else None

    return _declared(tree, split)


SeedMap = Callable[..., Callable]
"""``over_seeds(function, in_axes=0, out_axes=0)``: ``function`` of one seed applied to every seed."""


def over_seeds(seeds: int) -> SeedMap:
    """How functions of one seed meet a seed axis of size ``seeds`` >= 1: ``jax.vmap`` for several, and
    for one the function on the seed's slice (``vmap`` over an axis of size 1 buys nothing and costs a
    pass over the traced program). ``in_axes`` and ``out_axes`` are ``vmap``'s: 0 or None per subtree
    (:func:`seed_axes`)."""

    def mapped(function: Callable, in_axes: Any = 0, out_axes: Any = 0) -> Callable:
        if seeds > 1:
            return jax.vmap(function, in_axes=in_axes, out_axes=out_axes)

        def on_the_slice(*args: Any) -> Any:
            axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
            args = tuple(
                _on_seed_axis(arg, axis, lambda leaf: leaf[0]) for arg, axis in zip(args, axes, strict=True)
            )
            return _on_seed_axis(function(*args), out_axes, lambda leaf: leaf[None])

        return on_the_slice

    return mapped


def _on_seed_axis(tree: Any, axes: Any, change: Callable[[jax.Array], jax.Array]) -> Any:
    """``tree`` with ``change`` applied to the arrays that have a seed axis in ``axes`` (a prefix of ``tree``)."""
    axes = jax.tree.broadcast(axes, tree, is_leaf=lambda x: x is None)
    return jax.tree.map(
        lambda leaf, axis: leaf if axis is None else change(leaf), tree, axes, is_leaf=lambda x: x is None
    )
