"""What the two kinds of policy file share, with NumPy alone: the error type, the metadata check and the
bodies' structures looked up by name.

``python -m swat_jax.export`` writes a policy as a ``.npz`` of a :mod:`jax.export` program
(:mod:`swat_jax.serving`, needs jax) or as an ONNX model (:mod:`swat_jax.onnx_policy`, needs onnxruntime
and no jax). Both carry the same metadata (format and version, max limbs L, observation features F, the
order of the structure inputs, the bodies) and the padded structure arrays of every body of the run's set,
[K, L, ...] in the order of ``bodies``; both take ``policy(observation [batch, L, F], structure)``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

REQUIRED_METADATA = ("max_limbs", "observation_features", "structure_fields", "bodies")
"""Metadata every policy file has besides its format and version."""

StructureInput = str | Mapping[str, Any] | Any
"""A body name of the file, a mapping from structure field to array, or a StructureBatch slice."""


class ExportError(ValueError):
    """A run that cannot be exported as asked, or a file that is not a usable exported policy."""


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
