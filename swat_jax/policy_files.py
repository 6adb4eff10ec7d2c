"""What the two kinds of policy file share, with NumPy alone: the error type, the metadata check and the
bodies' structures looked up by name.

``python -m swat_jax.export`` writes a policy as a ``.npz`` of a :mod:`jax.export` program
(:mod:`swat_jax.serving`, needs jax) or as an ONNX model (:mod:`swat_jax.onnx_policy`, needs onnxruntime
and no jax). Both carry the same metadata (format and version, max limbs L, observation features F, the
order of the structure inputs, the bodies) and the padded structure arrays of every body of the run's set,
[K, L, ...] in the order of ``bodies``; both take ``policy(observation [batch, L, F], structure)``.

Both also carry each body's :class:`~swat_jax.envs.controller.BodyInterface` under ``interfaces``, so a
control loop on MuJoCo C builds the observation, maps the actions to the actuators and steps the body as the
environment does, without JAX (:meth:`PolicyFile.observe`, :meth:`PolicyFile.controls`,
:meth:`PolicyFile.simulate`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # imported where used: reading a file needs neither MuJoCo nor the controller
    import mujoco

    from swat_jax.envs.controller import BodyInterface

REQUIRED_METADATA = ("max_limbs", "observation_features", "structure_fields", "bodies")
"""Metadata every policy file has besides its format and version."""

StructureInput = str | Mapping[str, Any] | Any
"""A body name of the file, a mapping from structure field to array, or a StructureBatch slice."""


class ExportError(ValueError):
    """A run that cannot be exported as asked, or a file that is not a usable exported policy."""


def arrays_to_json(arrays: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Arrays by name as JSON-ready values: ``{name: {"dtype", "shape", "values"}}``."""
    return {
        name: {
            "dtype": np.asarray(array).dtype.name,
            "shape": list(np.shape(array)),
            "values": np.ravel(array).tolist(),
        }
        for name, array in arrays.items()
    }


def arrays_from_json(path: Path, stored: Any, names: Sequence[str], what: str) -> dict[str, np.ndarray]:
    """The arrays :func:`arrays_to_json` wrote, one per name of ``names``; ExportError naming ``path`` and
    ``what`` they are if one is missing or malformed."""
    arrays = {}
    for name in names:
        entry = stored.get(name) if isinstance(stored, dict) else None
        try:
            arrays[name] = np.asarray(entry["values"], np.dtype(entry["dtype"])).reshape(entry["shape"])
        except (TypeError, KeyError, ValueError) as error:
            raise ExportError(
                f"{path}: not a complete exported policy: no readable {what} {name!r} ({error})"
            ) from error
    return arrays


def checked_suffix(path: str | Path, suffix: str, kind: str) -> Path:
    """``path`` as a Path, checked to end in ``suffix``; ExportError naming ``kind`` (what such a file is)
    otherwise."""
    path = Path(path)
    if path.suffix.lower() != suffix:
        raise ExportError(f"{path}: {kind}; use the suffix {suffix}, not {path.suffix or '(none)'!r}")
    return path


def checked_metadata(path: Path, text: str, file_format: str, version: int) -> dict[str, Any]:
    """The JSON metadata ``text`` parsed and checked to be of ``file_format`` at ``version`` or earlier, with
    every :data:`REQUIRED_METADATA` key; ExportError naming ``path`` and the fault otherwise."""
    try:
        metadata = json.loads(text)
    except ValueError as error:
        raise ExportError(f"{path}: not an exported policy: its metadata is not JSON ({error})") from error
    if not isinstance(metadata, dict) or metadata.get("format") != file_format:
        raise ExportError(f"{path}: not an exported policy: its metadata format is not {file_format!r}")
    written = metadata.get("format_version")
    if not isinstance(written, int) or written > version:
        raise ExportError(
            f"{path}: format version {written!r} is newer than this swat_jax reads ({version}); "
            f"update swat_jax or export the policy again"
        )
    missing = [key for key in REQUIRED_METADATA if key not in metadata]
    if missing:
        raise ExportError(f"{path}: not a complete exported policy: its metadata has no {', '.join(missing)}")
    return metadata


class PolicyFile:
    """The metadata and body structures of a policy file, and the checks of a call's inputs; the two
    loaders' policies derive from it."""

    def __init__(self, path: Path, metadata: dict[str, Any], structures: Mapping[str, np.ndarray]):
        self.path = path
        self.metadata = metadata
        """The file's metadata (:mod:`swat_jax.policy_files`)."""
        self._fields: list[str] = list(metadata["structure_fields"])
        self._structures = dict(structures)
        self._interfaces: dict[str, BodyInterface] = {}

    @property
    def max_limbs(self) -> int:
        """L: observations and structures are padded to this many limbs."""
        return int(self.metadata["max_limbs"])

    @property
    def observation_features(self) -> int:
        """F: observation values per limb."""
        return int(self.metadata["observation_features"])

    @property
    def bodies(self) -> tuple[str, ...]:
        """The body names whose structures the file holds (the run's train and test bodies)."""
        return tuple(self.metadata["bodies"])

    def structure(self, body: str) -> dict[str, np.ndarray]:
        """One body's structure padded to L limbs, by field name (limb_mask [L], parents [L], ...)."""
        if body not in self.bodies:
            raise ValueError(f"{self.path} has no body {body!r}; it has {', '.join(self.bodies)}")
        row = self.bodies.index(body)
        return {name: self._structures[name][row] for name in self._fields}

    def interface(self, body: str) -> BodyInterface:
        """The controller constants of ``body`` (:mod:`swat_jax.envs.controller`), decoded from the metadata
        once per body (a control loop asks for them at every step); ExportError for a file exported before
        policy files carried them."""
        from swat_jax.envs.controller import ARRAY_FIELDS, interface_from_arrays

        if body not in self._interfaces:
            self.structure(body)
            stored = self.metadata.get("interfaces", {}).get(body)
            if stored is None:
                raise ExportError(f"{self.path}: no controller interface of {body!r}; export the run again")
            arrays = arrays_from_json(self.path, stored, ARRAY_FIELDS, body)
            self._interfaces[body] = interface_from_arrays({**stored, **arrays})
        return self._interfaces[body]

    def observe(self, body: str, data: mujoco.MjData, target: Any = None) -> np.ndarray:
        """[1, L, F] float32: ``body``'s observation of MuJoCo's ``data`` (after :meth:`simulate`, or
        ``mujoco.mj_forward`` at an episode's start), padded to L limbs, ready for ``policy(observation,
        body)``; ``target`` [2] is the point a 3D body walks to."""
        from swat_jax.envs.controller import observe

        observation = observe(self.interface(body), data, target)
        padded = np.zeros((1, self.max_limbs, self.observation_features), np.float32)
        padded[0, : observation.shape[0]] = observation
        return padded

    def controls(self, body: str, actions: Any) -> np.ndarray:
        """[nu] the actuator controls of ``body`` for its ``actions`` ([L] or [L, M], one row of the policy's
        output), clipped to [-1, 1]: assign them to ``data.ctrl``."""
        from swat_jax.envs.controller import controls

        return controls(self.interface(body).motor_actions, actions)

    def simulate(self, body: str, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """One environment step of ``body`` on MuJoCo C under ``data.ctrl``, in place: the frame skip's physics
        steps and the kinematics the next observation reads (:func:`swat_jax.envs.controller.simulate`)."""
        from swat_jax.envs.controller import simulate

        simulate(self.interface(body), model, data)

    def check_observation(self, observation: Any) -> None:
        """ValueError unless ``observation`` is [batch, L, F] with batch >= 1."""
        expected = (self.max_limbs, self.observation_features)
        shape = tuple(np.shape(observation))
        if len(shape) != 3 or shape[1:] != expected or shape[0] < 1:
            raise ValueError(
                f"observation must be [batch, {expected[0]}, {expected[1]}] (batch >= 1, limbs padded to max_limbs "
                f"{expected[0]}, {expected[1]} observation features), got shape {shape}"
            )

    def structure_fields(
        self, structure: Mapping[str, Any] | Any, inputs: Sequence[tuple[tuple, Any]]
    ) -> list:
        """The fields of one body's ``structure`` (a mapping from field name to array, or a StructureBatch
        slice) in input order, each checked against its input's (shape, dtype) in ``inputs``."""
        values = []
        for name, (shape, dtype) in zip(self._fields, inputs, strict=True):
            value = structure.get(name) if isinstance(structure, Mapping) else getattr(structure, name, None)
            if value is None:
                raise ValueError(f"structure has no field {name!r}; it needs {', '.join(self._fields)}")
            if tuple(np.shape(value)) != tuple(shape):
                raise ValueError(
                    f"structure.{name} must be {list(shape)} {np.dtype(dtype).name} (one body padded to max_limbs "
                    f"{self.max_limbs}), got shape {list(np.shape(value))}"
                )
            values.append(value)
        return values
