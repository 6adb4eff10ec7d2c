"""An exported policy file read back and run: needs only jax and numpy, nothing of training.

``python -m swat_jax.export`` writes the file (:mod:`swat_jax.export`); :func:`load` reads it. The file is
a NumPy ``.npz`` archive (read with ``allow_pickle=False``) holding

- ``program``: the serialised :class:`jax.export.Exported` (uint8 bytes): ``policy(observation [b, L, F],
  *structure fields) -> actions [b, L]`` ([b, L, 3] for 3D bodies), with the parameters baked in and a symbolic batch size;
- ``metadata``: a JSON string: format and version, the jax version that wrote the program, algo, env,
  env steps, max limbs, observation features, the order of the structure inputs, the bodies stored
  below and the platforms compiled for;
- ``structure.<field>``: the padded structure arrays of every body of the run's set (train and test),
  [K, L, ...] in the order of ``metadata["bodies"]``, so a body can be named instead of encoded::

    policy = swat_jax.serving.load("walker.npz")
    actions = policy(observation, "walker_3_main")  # observation [batch, L, F] -> actions [batch, L] ([batch, L, 3] in 3D)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from swat_jax.policy_files import (
    ExportError,
    PolicyFile,
    StructureInput,
    checked_metadata,
    checked_suffix,
)

FORMAT = "swat_jax.exported_policy"
"""``metadata["format"]`` of every exported policy file."""
FORMAT_VERSION = 1
"""``metadata["format_version"]`` written here; :func:`load` reads this version and earlier ones."""
SUFFIX = ".npz"
PROGRAM_KEY = "program"
METADATA_KEY = "metadata"
STRUCTURE_PREFIX = "structure."

__all__ = ["ExportError", "ExportedPolicy", "StructureInput", "load", "policy_path"]


def policy_path(path: str | Path) -> Path:
    """``path`` as a Path, checked to end in ``.npz``; ExportError otherwise."""
    return checked_suffix(path, SUFFIX, "an exported policy is a NumPy archive")


class ExportedPolicy(PolicyFile):
    """A policy read from an exported file; calling it needs only jax and numpy.

    ``policy(observation, structure)`` maps observation [batch, L, F] to actions [batch, L] ([batch, L, 3]
    for 3D bodies) in [-1, 1]
    (zero on padded limbs), where ``structure`` is a body name of the file, or the structure of one body
    padded to L limbs: a StructureBatch slice or a mapping from field name to array. Each new batch size
    compiles once.
    """

    def __init__(
        self,
        path: Path,
        exported: jax.export.Exported,
        metadata: dict[str, Any],
        structures: dict[str, np.ndarray],
    ):
        super().__init__(path, metadata, structures)
        self._exported = exported
        self._call = jax.jit(exported.call)
        self._by_name: dict[str, tuple[jax.Array, ...]] = {}

    def __call__(self, observation: Any, structure: StructureInput) -> jax.Array:
        """observation [batch, L, F] (rows beyond the body's limbs are ignored), one body's structure ->
        actions [batch, L] ([batch, L, 3] for 3D bodies) float32 in [-1, 1], zero on padded limbs."""
        observation = np.asarray(observation) if not isinstance(observation, jax.Array) else observation
        self.check_observation(observation)
        return self._call(observation.astype(np.float32), *self._structure_arrays(structure))

    def _structure_arrays(self, structure: StructureInput) -> tuple[Any, ...]:
        """The structure inputs of the program, in order, checked against its input shapes."""
        if isinstance(structure, str):
            if structure not in self._by_name:
                self._by_name[structure] = tuple(
                    jax.device_put(array) for array in self.structure(structure).values()
                )
            return self._by_name[structure]
        avals = self._exported.in_avals[1:]
        values = self.structure_fields(structure, [(aval.shape, aval.dtype) for aval in avals])
        return tuple(
            value.astype(aval.dtype) if isinstance(value, jax.Array) else np.asarray(value, aval.dtype)
            for value, aval in zip(values, avals, strict=True)
        )


def load(path: str | Path) -> ExportedPolicy:
    """Read an exported policy file and check that this jax can run its program.

    The program's StableHLO is deserialised and lowered here, for a batch of one, rather than at the first
    call: a file written by a newer jax than this one (whose StableHLO this jax cannot read) is refused at
    load time. ExportError names the file and what is wrong with it.
    """
    path = Path(path)
    with _open(path) as archive:
        metadata = _metadata(path, archive)
        fields = metadata["structure_fields"]
        missing = [
            f"{STRUCTURE_PREFIX}{name}" for name in fields if f"{STRUCTURE_PREFIX}{name}" not in archive
        ]
        if missing:
            raise ExportError(f"{path}: not a complete exported policy: no {', '.join(missing)}")
        structures = {name: archive[f"{STRUCTURE_PREFIX}{name}"] for name in fields}
        program = archive[PROGRAM_KEY]
    try:
        exported = jax.export.deserialize(bytearray(program.tobytes()))
    except ImportError:
        raise  # flatbuffers, which jax needs to read any exported program, is not installed
    except Exception as error:
        raise _unusable_program(path, metadata, "read", error) from error
    if len(exported.in_avals) != 1 + len(fields):
        raise ExportError(
            f"{path}: its program takes {len(exported.in_avals)} inputs, but the metadata names "
            f"{1 + len(fields)} (observation and {', '.join(fields)})"
        )
    try:
        jax.jit(exported.call).lower(*_one_sample_inputs(exported))
    except Exception as error:
        raise _unusable_program(path, metadata, "run", error) from error
    return ExportedPolicy(path, exported, metadata, structures)


def _one_sample_inputs(exported: jax.export.Exported) -> list[jax.ShapeDtypeStruct]:
    """The program's input shapes with the symbolic batch dimension set to 1: observation [1, L, F], then
    the structure fields [L, ...]."""
    return [
        jax.ShapeDtypeStruct(tuple(size if isinstance(size, int) else 1 for size in aval.shape), aval.dtype)
        for aval in exported.in_avals
    ]


def _unusable_program(path: Path, metadata: dict[str, Any], verb: str, error: Exception) -> ExportError:
    """The error for a program this jax cannot ``verb`` ("read" or "run"): export again with this jax."""
    written_with = metadata.get("jax_version", "an unrecorded version")
    reason = str(error).strip().splitlines()[0] if str(error).strip() else ""
    return ExportError(
        f"{path}: its program was written by jax {written_with} and cannot be {verb} by this jax "
        f"{jax.__version__} ({type(error).__name__}: {reason}); export the policy again with jax "
        f"{jax.__version__} (python -m swat_jax.export RUN_DIR -o {path.name})"
    )


def _open(path: Path) -> Any:
    """The NpzFile of ``path``; ExportError if it is missing or not an exported policy."""
    if not path.is_file():
        raise ExportError(f"{path}: no such file; write one with python -m swat_jax.export RUN_DIR -o {path}")
    try:
        archive = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise ExportError(f"{path}: not an exported policy (not a NumPy .npz archive: {error})") from error
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ExportError(f"{path}: not an exported policy (a single .npy array, not an .npz archive)")
    missing = [key for key in (PROGRAM_KEY, METADATA_KEY) if key not in archive]
    if missing:
        archive.close()
        raise ExportError(
            f"{path}: not an exported policy: the archive has no {' or '.join(missing)} "
            f"(it holds {', '.join(archive.files) or 'nothing'}); write one with python -m swat_jax.export"
        )
    return archive


def _metadata(path: Path, archive: Any) -> dict[str, Any]:
    """The checked metadata of an open archive."""
    return checked_metadata(path, str(archive[METADATA_KEY]), FORMAT, FORMAT_VERSION)
