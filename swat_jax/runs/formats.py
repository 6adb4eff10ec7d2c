"""The versions of what a run writes, and the readers of the older layouts: one module for both.

A run directory holds two files whose layout has changed over swat_jax's history: ``config.json`` (the
resolved :class:`~swat_jax.runs.config.TrainConfig`) and each checkpoint's ``info`` item
(:class:`~swat_jax.runs.checkpoint.CheckpointInfo`). Each now carries ``format_version``; a file without
one was written before versions existed (version 1) and is read by the readers below, each of which names
the change it undoes. Each layout has a stored file in ``tests/data/formats/`` that its test reads.

``config.json``, version 1 (swat_jax of 2026-11-22 to 2026-12-07), any of these layouts:

- *flat* (before 2026-12-04): the network sizes and environment switches at the top level
  (:data:`REGROUPED` says where each went);
- *before a switch*: a switch whose default changed what a run computes is missing; it is read with the
  value that computed the run (:data:`EARLIER_SWITCHES`): Flax's initial weights before the original
  code's existed, the loop of the original before its round updates, reset next states and replay sizing,
  no learning diagnostics before they existed. (Switches whose default kept the computation, such as
  ``td3.action_penalty`` = 0, need no reader: the field's default is the earlier value.)

Version 2: ``format_version`` and the fields as :class:`~swat_jax.runs.config.TrainConfig` holds them.

A checkpoint's ``info``, version 1: before runs had a seed axis (refused: its state cannot be read into a
run's), or before 3D bodies (no ``motors_per_limb``: 1, one motor per limb). Version 2: ``format_version``
and :class:`~swat_jax.runs.checkpoint.CheckpointInfo`'s fields.

A file of a newer version than this swat_jax writes is refused with the versions named.
"""

from __future__ import annotations

from typing import Any

CONFIG_VERSION = 2
"""The ``format_version`` of the config.json this swat_jax writes."""
CHECKPOINT_VERSION = 2
"""The ``format_version`` of the checkpoint ``info`` this swat_jax writes."""
VERSION_KEY = "format_version"

REGROUPED = {
    **{
        name: "network"
        for name in (
            "width",
            "heads",
            "layers",
            "feedforward",
            "max_traversal_positions",
            "max_children",
            "smp_hidden",
            "reference_inorder",
        )
    },
    **{name: "envs" for name in ("copies", "variants", "variation", "variant_seed", "physics")},
    **{name: "envs" for name in ("torso_relative_x", "stale_kinematics")},
}
"""The fields that a flat config.json (before 2026-12-04) holds at its top level, by their group today."""

EARLIER_SWITCHES = {
    "network": {"initialisation": "flax"},
    "iteration": {
        "round_updates": False,
        "reset_next_state": False,
        "capacity_all": None,
        "diagnostics": False,
    },
}
"""Switches whose defaults changed what a run computes or keeps in its checkpoints, with the value that
gives what a version-1 config.json without them computed and saved."""


class FormatError(ValueError):
    """A file of a layout this swat_jax cannot read; the message says why and what to do (the caller adds
    the file's name)."""


def versioned(fields: dict[str, Any], version: int) -> dict[str, Any]:
    """``fields`` with ``format_version`` first."""
    return {VERSION_KEY: version, **fields}


def current_config(fields: Any) -> Any:
    """The fields of a config.json in today's layout (without ``format_version``); FormatError for a
    version newer than :data:`CONFIG_VERSION`. What is not an object is returned as it is (the reader
    names it)."""
    if not isinstance(fields, dict):
        return fields
    version = _version(fields, CONFIG_VERSION)
    fields = {name: value for name, value in fields.items() if name != VERSION_KEY}
    return _with_earlier_switches(_regrouped(fields)) if version == 1 else fields


def current_checkpoint_info(data: dict[str, Any]) -> dict[str, Any]:
    """The fields of a checkpoint's ``info`` in today's layout (without ``format_version``); FormatError
    for a newer version, or a version-1 info written before runs had a seed axis."""
    version = _version(data, CHECKPOINT_VERSION)
    data = {name: value for name, value in data.items() if name != VERSION_KEY}
    if version > 1:
        return data
    if "seeds" not in data:
        raise FormatError(
            "written before runs had a seed axis (swat_jax 0.1.0 before multi-seed training); train the run again"
        )
    return {"motors_per_limb": 1, **data}


def _version(fields: dict[str, Any], newest: int) -> int:
    """The file's ``format_version`` (1 when it has none); FormatError if it is not one this swat_jax reads."""
    version = fields.get(VERSION_KEY, 1)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise FormatError(f"format_version must be a whole number from 1, got {version!r}")
    if version > newest:
        raise FormatError(
            f"format version {version} is newer than this swat_jax reads ({newest}); upgrade swat_jax "
            "(pip install -U, or the checkout that wrote the run)"
        )
    return version


def _regrouped(fields: dict[str, Any]) -> dict[str, Any]:
    """A flat config.json's fields with the top-level fields of :data:`REGROUPED` moved into their groups."""
    fields = dict(fields)
    for name, group in REGROUPED.items():
        if name in fields and isinstance(fields.get(group, {}), dict):
            fields[group] = {**fields.get(group, {}), name: fields.pop(name)}
    return fields


def _with_earlier_switches(fields: dict[str, Any]) -> dict[str, Any]:
    """A config.json's fields with the switches of :data:`EARLIER_SWITCHES` it lacks set to their earlier
    value, so a run written before them resumes with the computation (and the checkpoints) it had."""
    fields = dict(fields)
    for group, switches in EARLIER_SWITCHES.items():
        if isinstance(fields.get(group, {}), dict):
            fields[group] = {**switches, **fields.get(group, {})}
    return fields
