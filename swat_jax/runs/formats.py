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

Version 2 (2026-12-07 to 2026-12-08): ``format_version`` and the fields as TrainConfig held them, the
training loop in three fields of ``iteration`` (``rounds``, ``round_updates``, ``schedule``).

Version 3: the training loop is one field, ``iteration.loop`` (rounds with round updates: ``rounds``,
rounds without: ``rounds_chunked``, no rounds: the schedule's ``per_body`` or ``all_tasks``), and every other field as :class:`~swat_jax.runs.config.TrainConfig`
holds it.

A checkpoint's ``info``, version 1: before runs had a seed axis (refused: its state cannot be read into a
run's), or before 3D bodies (no ``motors_per_limb``: 1, one motor per limb). Version 2: ``format_version``
and :class:`~swat_jax.runs.checkpoint.CheckpointInfo`'s fields.

A file of a newer version than this swat_jax writes is refused with the versions named.
"""

from __future__ import annotations

from typing import Any

CONFIG_VERSION = 3
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


V2_LOOP_FIELDS = {"rounds": True, "round_updates": True, "schedule": "original"}
"""Version 2's three fields of the training loop in ``iteration``, with the defaults it had."""


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
    if version == 1:
        fields = _with_earlier_switches(_regrouped(fields))
    return _with_one_loop(fields) if version < 3 else fields


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


def _with_one_loop(fields: dict[str, Any]) -> dict[str, Any]:
    """A version-2 layout's fields with its three loop fields (:data:`V2_LOOP_FIELDS`, each missing one at
    its version-2 default) as the one ``iteration.loop`` of version 3."""
    if not isinstance(fields.get("iteration", {}), dict):
        return fields
    iteration = dict(fields.get("iteration", {}))
    rounds, round_updates, schedule = (
        iteration.pop(name, default) for name, default in V2_LOOP_FIELDS.items()
    )
    return {**fields, "iteration": {**iteration, "loop": v2_loop(rounds, round_updates, schedule)}}


def v2_loop(rounds: Any, round_updates: Any, schedule: Any) -> str:
    """The training loop of version 2's ``rounds``, ``round_updates`` and ``schedule``: with rounds, rounds
    (round updates) or rounds_chunked; without, the schedule's per_body (original) or all_tasks.
    FormatError for a combination version 2 refused (rounds on the all_tasks schedule)."""
    if rounds is True and schedule == "original":
        return "rounds" if round_updates else "rounds_chunked"
    if rounds is False and schedule in ("original", "all_tasks"):
        return "per_body" if schedule == "original" else "all_tasks"
    raise FormatError(
        f"rounds {rounds!r} and schedule {schedule!r} are no training loop (rounds ran on the original "
        "schedule alone); give --iteration.loop, one of rounds, rounds_chunked, per_body, all_tasks"
    )


OLD_LOOP_FLAGS = {
    "--iteration.rounds": ("rounds", True),
    "--iteration.no-rounds": ("rounds", False),
    "--iteration.round-updates": ("round_updates", True),
    "--iteration.no-round-updates": ("round_updates", False),
}
"""The switches of the training loop before ``--iteration.loop`` (with ``--iteration.schedule NAME``), read
for one release: the field of :data:`V2_LOOP_FIELDS` each sets, and to what."""


def with_loop_flag(argv: list[str], loop: str) -> tuple[list[str], str | None]:
    """``argv`` with the old loop flags (:data:`OLD_LOOP_FLAGS`, ``--iteration.schedule``) replaced by the
    ``--iteration.loop`` they give, applied to the defaults' ``loop``, and the line that says so (None
    without them); FormatError for a combination that is no loop."""
    given = {"rounds": loop in ("rounds", "rounds_chunked"), "round_updates": loop == "rounds"}
    given["schedule"] = "all_tasks" if loop == "all_tasks" else "original"
    kept, old, arguments = [], [], iter(argv)
    for argument in arguments:
        name, _, value = argument.partition("=")
        if argument in OLD_LOOP_FLAGS:
            field, given[field] = OLD_LOOP_FLAGS[argument]
        elif name == "--iteration.schedule":
            given["schedule"] = value or next(arguments, "")
        else:
            kept.append(argument)
            continue
        old.append(name)
    if not old:
        return argv, None
    new = v2_loop(given["rounds"], given["round_updates"], given["schedule"])
    return [*kept, "--iteration.loop", new], (
        f"{', '.join(old)}: old names, read for one release; give --iteration.loop {new} instead"
    )
