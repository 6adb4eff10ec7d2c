"""Orbax checkpoints of everything a run needs to continue, and of the actor alone for eval and export.

A checkpoint is one step folder under ``RUN_DIR/checkpoints/<env steps>/`` with five items:

- ``state``: the whole :class:`~swat_jax.td3.iteration.TrainState` (parameters, target parameters,
  optimizer states, replay buffers, environment states, RNG keys, counters) as a flat dict of its
  non-empty arrays (Orbax cannot write zero-size arrays, and MJX data has some);
- ``manifest``: the shape and dtype of every array of ``state``, checked against what the run expects
  before anything is read, so a mismatched checkpoint fails with the arrays that differ;
- ``actor``: the actor parameters, so a policy loads without reading the replay buffers;
- ``critic``: the critic parameters and both target networks, so another run can start from this
  one's networks (``--init-from``) without reading the replay buffers;
- ``info``: a :class:`CheckpointInfo`: environment steps, iterations and seconds trained, and what a
  policy needs to be rebuilt (seeds, bodies, padded limb count, observation features).

Orbax writes each step to a temporary folder and renames it when complete, so an interrupted write
leaves the previous checkpoint intact. When the save is complete, the step folder gains a record of every
file it holds (:mod:`swat_jax.runs.integrity`), and nothing of a checkpoint is read before that record
checks out: a damaged checkpoint is refused with the reason, and a resumed run sets it aside and continues
from the newest intact one (:meth:`Checkpoints.set_aside_damaged`).
"""

from __future__ import annotations

import dataclasses
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from swat_jax.runs import formats
from swat_jax.runs.integrity import damage, write_record
from swat_jax.td3.sharding import all_processes_reach

MAX_LISTED = 5
"""Mismatched arrays named in an error message."""
MAX_SUMMARY = 200
"""Characters of a read error shown in the message; the whole error goes to ERROR_LOG."""
ERROR_LOG = "checkpoint_error.log"
"""File in the run directory that holds the whole error of the last unreadable checkpoint."""
TENSORSTORE_DETAIL = "See full TensorStore details"
"""Where TensorStore's read errors start appending their whole spec (dozens of lines)."""
DAMAGED_DIR = "damaged_checkpoints"
"""Folder of the run directory where a resumed run moves the checkpoints it refused."""
RESTORED = ("manifest", "state", "info")
"""The items :meth:`Checkpoints.restore` reads, checked before the first of them is read."""
UNFINISHED = ".orbax-checkpoint-tmp"
"""In the name of the temporary folder of a save that never finished (Orbax renames it when it does)."""


class CheckpointError(RuntimeError):
    """A checkpoint that is missing, unreadable or does not match the run; the message says what to do."""


@dataclasses.dataclass(frozen=True)
class CheckpointInfo:
    """What a checkpoint says about itself: its ``info`` item, stored as JSON."""

    env_steps: int
    """Environment steps trained, summed over bodies, of each seed (the checkpoint's folder name)."""
    iterations: int
    seconds: float
    """Wall clock spent training, over every start of the run."""
    seeds: tuple[int, ...]
    """The seed of each slice of the state's leading seed axis."""
    bodies: tuple[str, ...]
    """The bodies trained on, in task order."""
    max_limbs: int
    observation_features: int
    """Values per limb of the observation the actor takes."""
    motors_per_limb: int = 1
    """Actions per limb of the actor: 1 planar, 3 in 3D (checkpoints from before 3D bodies: 1)."""
    metrics_window: dict[str, Any] | None = None
    """The metrics accumulated since the last metrics row (:class:`~swat_jax.runs.metrics.MetricsWindow`)."""
    converted_from: str | None = None
    """For a run converted from the original code: the file its networks came from."""
    original_total_timesteps: int | None = None
    """For a converted run: the steps the original trainer had counted."""

    def to_json(self) -> dict[str, Any]:
        """The JSON object stored as the ``info`` item (fields that are None are left out)."""
        fields = {
            field.name: list(value) if isinstance(value, tuple) else value
            for field in dataclasses.fields(self)
            if (value := getattr(self, field.name)) is not None
        }
        return formats.versioned(fields, formats.CHECKPOINT_VERSION)

    @classmethod
    def from_json(cls, data: dict[str, Any], where: Path) -> CheckpointInfo:
        """Read a stored ``info`` item of any layout (:mod:`swat_jax.runs.formats`); CheckpointError naming
        ``where`` if it cannot be read or lacks a field it needs."""
        try:
            data = formats.current_checkpoint_info(data)
        except formats.FormatError as error:
            raise CheckpointError(f"{where}: {error}") from error
        fields = {field.name for field in dataclasses.fields(cls)}
        required = {f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING}
        if missing := sorted(required - set(data)):
            raise CheckpointError(f"{where}: its info lacks {', '.join(missing)}; train the run again")
        values = {key: value for key, value in data.items() if key in fields}
        return cls(
            **{
                **values,
                "seeds": tuple(int(seed) for seed in data["seeds"]),
                "bodies": tuple(data["bodies"]),
                "env_steps": int(data["env_steps"]),
                "iterations": int(data["iterations"]),
                "seconds": float(data["seconds"]),
                "max_limbs": int(data["max_limbs"]),
                "observation_features": int(data["observation_features"]),
            }
        )


def flatten(tree: Any) -> dict[str, np.ndarray | jax.Array]:
    """The non-empty arrays of ``tree`` by their key path (``.learner.actor_params['params']...``)."""
    return {
        jax.tree_util.keystr(path): leaf
        for path, leaf in jax.tree_util.tree_leaves_with_path(tree)
        if leaf.size
    }


def unflatten(template: Any, arrays: dict[str, Any]) -> Any:
    """``template`` (arrays or ShapeDtypeStructs) with its non-empty leaves taken from ``arrays``."""

    def fill(path: Any, leaf: Any) -> Any:
        if not np.prod(leaf.shape):
            return jnp.zeros(leaf.shape, leaf.dtype)
        return jnp.asarray(arrays[jax.tree_util.keystr(path)])

    return jax.tree_util.tree_map_with_path(fill, template)


def manifest(tree: Any) -> dict[str, list]:
    """[shape, dtype] of every non-empty array of ``tree``."""
    return {key: [list(leaf.shape), str(leaf.dtype)] for key, leaf in flatten(tree).items()}


class Checkpoints:
    """The checkpoints of one run directory: ``save`` after iterations, ``restore`` to continue."""

    def __init__(self, run_dir: Path, keep: int = 2):
        self.directory = Path(run_dir).absolute() / "checkpoints"
        self.manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
        )
        self.checked: set[tuple[int, str | None]] = set()
        """(step, item) pairs whose record checked out (item None: the whole checkpoint)."""

    def latest_step(self) -> int | None:
        """Environment steps of the newest complete checkpoint, or None."""
        return self.manager.latest_step()

    def save(self, state: Any, networks: dict[str, Any], info: CheckpointInfo) -> None:
        """Write a checkpoint named by ``info.env_steps``, wait until it is on disk, then record what it holds.

        Args:
            networks: the ``actor`` and ``critic`` items (pytrees of arrays), read alone by
                :meth:`restore_item`.
        """
        self.manager.save(
            info.env_steps,
            args=ocp.args.Composite(
                state=ocp.args.StandardSave(flatten(state)),
                manifest=ocp.args.JsonSave(manifest(state)),
                **{name: ocp.args.StandardSave(tree) for name, tree in networks.items()},
                info=ocp.args.JsonSave(info.to_json()),
            ),
            force=True,
        )
        self.manager.wait_until_finished()
        # Several hosts: every process has written its shards before process 0 records them.
        all_processes_reach("swat_jax checkpoint written")
        if jax.process_index() == 0:
            write_record(self._path(info.env_steps))
        all_processes_reach("swat_jax checkpoint recorded")

    def set_aside_damaged(self) -> list[str]:
        """Move the checkpoints newer than the newest intact one, and unfinished saves, to DAMAGED_DIR.

        Returns one line for each, naming it, why it was refused and where it went; the newest checkpoint
        is then intact. CheckpointError, moving nothing, if there are checkpoints and none is intact.
        """
        refused = []
        for step in sorted(self.manager.all_steps(), reverse=True):
            reason = damage(self._path(step))
            if reason is None:
                self.checked.add((step, None))
                break
            refused.append((self._path(step), reason))
        else:
            if refused:
                reasons = "; ".join(f"{path.name}: {reason}" for path, reason in refused)
                raise CheckpointError(
                    f"no intact checkpoint in {self.directory} ({reasons}); start the run again with --overwrite"
                )
        refused += [
            (path, "its save never finished") for path in sorted(self.directory.glob(f"*{UNFINISHED}*"))
        ]
        aside = self.directory.parent / DAMAGED_DIR
        targets = [_free_name(aside / path.name) for path, _ in refused]
        all_processes_reach("swat_jax checkpoints checked")
        if refused and jax.process_index() == 0:
            aside.mkdir(exist_ok=True)
            for (path, _), target in zip(refused, targets, strict=True):
                path.rename(target)
        all_processes_reach("swat_jax checkpoints set aside")
        if refused:
            self.manager.reload()
        return [
            f"refused {path}: {reason}; moved to {target}"
            for (path, reason), target in zip(refused, targets, strict=True)
        ]

    def saved_shape(self, key: str, template: Any) -> tuple[int, ...]:
        """The shape of array ``key`` (a key of :func:`flatten`) in the newest checkpoint, or in ``template``
        if the checkpoint has no such array (:meth:`restore` then says what differs). Read before
        :meth:`restore`, so it checks what that reads."""
        step = self._latest()
        self._check(step, RESTORED)
        saved = self._read(step, manifest=ocp.args.JsonRestore())["manifest"]
        return tuple(saved[key][0]) if key in saved else tuple(flatten(template)[key].shape)

    def restore(self, template: Any, shardings: Any) -> tuple[Any, CheckpointInfo]:
        """The newest checkpoint's state (shaped like ``template``, placed as ``shardings``, a matching
        pytree of shardings, whatever devices wrote it) and info."""
        step = self._latest()
        self._check(step, RESTORED)
        saved = self._read(step, manifest=ocp.args.JsonRestore())["manifest"]
        expected = manifest(template)
        if saved != expected:
            raise CheckpointError(
                f"{self._path(step)} does not match this run: {_differences(saved, expected)}"
            )
        places = {
            jax.tree_util.keystr(path): place
            for path, place in jax.tree_util.tree_leaves_with_path(shardings)
        }
        abstract = {
            key: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=places[key])
            for key, leaf in flatten(template).items()
        }
        restored = self._read(step, state=ocp.args.StandardRestore(abstract), info=ocp.args.JsonRestore())
        return unflatten(template, restored["state"]), CheckpointInfo.from_json(
            restored["info"], self._path(step)
        )

    def info(self) -> CheckpointInfo:
        """The newest checkpoint's info."""
        step = self._latest()
        return CheckpointInfo.from_json(
            self._read(step, info=ocp.args.JsonRestore())["info"], self._path(step)
        )

    def restore_item(self, name: str, template: Any) -> Any:
        """The newest checkpoint's ``name`` item (``actor`` or ``critic``), shaped like ``template``, on this
        process's first device (whatever devices wrote it)."""
        device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        abstract = jax.tree_util.tree_map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device), template
        )
        return self._read(self._latest(), **{name: ocp.args.StandardRestore(abstract)})[name]

    def close(self) -> None:
        self.manager.close()

    def _latest(self) -> int:
        step = self.manager.latest_step()
        if step is None:
            raise CheckpointError(
                f"no checkpoint in {self.directory}; nothing to resume (start a new run with --overwrite)"
            )
        return step

    def _path(self, step: int) -> Path:
        return self.directory / str(step)

    def _check(self, step: int, items: Sequence[str]) -> None:
        """CheckpointError, before anything of checkpoint ``step`` is read, if its record does not check out
        for ``items``."""
        if (step, None) in self.checked or all((step, item) in self.checked for item in items):
            return
        if reason := damage(self._path(step), items):
            raise CheckpointError(
                f"{self._path(step)} is damaged: {reason}; nothing of it was read "
                f"(python -m swat_jax.train --resume {self.directory.parent} sets it aside and continues "
                "from the newest intact checkpoint)"
            )
        self.checked |= {(step, item) for item in items}

    def _read(self, step: int, **items: Any) -> Any:
        """The ``items`` of checkpoint ``step``, after its record checked out; CheckpointError if it does not,
        or if Orbax cannot read what was recorded (written by another version of it, say)."""
        self._check(step, list(items))
        try:
            return self.manager.restore(step, args=ocp.args.Composite(**items))
        except Exception as error:
            raise CheckpointError(
                f"{self._path(step)} is unreadable ({_summary(error)}); delete that folder to fall back to "
                f"the previous checkpoint. {self._log_error(step, error)}"
            ) from error

    def _log_error(self, step: int, error: Exception) -> str:
        """Write the whole of ``error`` (TensorStore's runs to a screen or more) to ERROR_LOG; say where."""
        log = self.directory.parent / ERROR_LOG
        text = "".join(traceback.format_exception(error))
        try:
            log.write_text(f"reading checkpoint {self._path(step)}:\n{text}")
        except OSError as write_error:
            return f"(The full error could not be written to {log}: {write_error})"
        return f"The full error is in {log}"


def _free_name(path: Path) -> Path:
    """``path``, or ``path`` with the first suffix -1, -2, ... that names nothing yet."""
    free, copy = path, 1
    while free.exists():
        free, copy = path.with_name(f"{path.name}-{copy}"), copy + 1
    return free


def _summary(error: Exception) -> str:
    """The first line of ``error``, without the TensorStore spec it may append, at most MAX_SUMMARY long."""
    first = (str(error).splitlines() or [""])[0].split(TENSORSTORE_DETAIL)[0].strip()
    if len(first) > MAX_SUMMARY:
        first = first[: MAX_SUMMARY - 3] + "..."
    return f"{type(error).__name__}: {first}"


def _differences(saved: dict[str, list], expected: dict[str, list]) -> str:
    """A short list of the arrays that are missing, extra or differently shaped."""
    lines = [f"{key} is missing" for key in expected if key not in saved]
    lines += [f"{key} is not expected" for key in saved if key not in expected]
    lines += [
        f"{key} is {saved[key][0]} {saved[key][1]}, expected {expected[key][0]} {expected[key][1]}"
        for key in expected
        if key in saved and saved[key] != expected[key]
    ]
    more = f" (and {len(lines) - MAX_LISTED} more)" if len(lines) > MAX_LISTED else ""
    return (
        "; ".join(lines[:MAX_LISTED])
        + more
        + (
            ". Was config.json edited, or the code changed since it was written? Start a new run with --overwrite"
        )
    )
