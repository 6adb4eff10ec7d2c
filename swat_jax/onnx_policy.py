"""An ONNX policy file read back and run with onnxruntime and NumPy alone: no jax, nothing of training.

``python -m swat_jax.export RUN_DIR --format onnx -o policy.onnx`` writes the file
(:func:`swat_jax.export.export_policy`): the actor of one seed as an ONNX graph with its parameters as
initialisers, ``policy(observation [batch, L, F] float32, *structure fields) -> actions [batch, L]``
([batch, L, 3] for 3D bodies), the batch dimension dynamic. Its ``metadata_props`` hold, under the key
``swat_jax``, a JSON object: the metadata of :mod:`swat_jax.policy_files` (format
``swat_jax.onnx_policy``) and ``structures``, the padded structure arrays of every body of the run's set
(per field: dtype, shape [K, L, ...] and values), so a body can be named instead of encoded::

    policy = swat_jax.onnx_policy.load("walker.onnx")
    actions = policy(observation, "walker_3_main")  # observation [batch, L, F] -> actions [batch, L]

Importing this module imports neither jax nor onnxruntime; :func:`load` needs onnxruntime.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from swat_jax.policy_files import (
    ExportError,
    PolicyFile,
    StructureInput,
    arrays_from_json,
    checked_metadata,
    checked_suffix,
)

FORMAT = "swat_jax.onnx_policy"
"""``metadata["format"]`` of every ONNX policy file."""
FORMAT_VERSION = 1
SUFFIX = ".onnx"
METADATA_KEY = "swat_jax"
"""The key of the model's ``metadata_props`` entry that holds the JSON metadata."""
OBSERVATION_INPUT = "observation"
ACTION_OUTPUT = "actions"
RUNTIME_HINT = "pip install onnxruntime==1.31.1 (or pip install 'swat-jax[onnx]')"


def onnx_path(path: str | Path) -> Path:
    """``path`` as a Path, checked to end in ``.onnx``; ExportError otherwise."""
    return checked_suffix(path, SUFFIX, "an ONNX policy is an ONNX model")


class OnnxPolicy(PolicyFile):
    """A policy read from an ONNX policy file, run by an onnxruntime session on the CPU.

    ``policy(observation, structure)`` maps observation [batch, L, F] to actions [batch, L] ([batch, L, 3]
    for 3D bodies) float32 in [-1, 1] (zero on padded limbs), where ``structure`` is a body name of the
    file, or one body's structure padded to L limbs (a mapping from field name to array, or a StructureBatch
    slice).
    """

    def __init__(self, path: Path, session: Any, metadata: dict[str, Any], structures: dict[str, np.ndarray]):
        super().__init__(path, metadata, structures)
        self.session = session
        """The onnxruntime InferenceSession."""
        self._inputs = [(tuple(structures[name].shape[1:]), structures[name].dtype) for name in self._fields]

    def __call__(self, observation: Any, structure: StructureInput) -> np.ndarray:
        """observation [batch, L, F] (rows beyond the body's limbs are ignored), one body's structure ->
        actions as NumPy float32."""
        self.check_observation(observation)
        if isinstance(structure, str):
            values = list(self.structure(structure).values())
        else:
            values = self.structure_fields(structure, self._inputs)
        feed = {OBSERVATION_INPUT: np.asarray(observation, np.float32)}
        feed.update(
            (name, np.asarray(value, dtype))
            for name, value, (_, dtype) in zip(self._fields, values, self._inputs, strict=True)
        )
        return self.session.run([ACTION_OUTPUT], feed)[0]


def load(path: str | Path) -> OnnxPolicy:
    """Read an ONNX policy file into an onnxruntime session (CPU); ExportError names the file and what is
    wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise ExportError(
            f"{path}: no such file; write one with python -m swat_jax.export RUN_DIR --format onnx -o {path}"
        )
    try:
        import onnxruntime
    except ImportError as error:
        raise ExportError(f"reading {path} needs onnxruntime: {RUNTIME_HINT}") from error
    try:
        session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own exception types for a file it cannot read
        raise ExportError(
            f"{path}: not an ONNX model onnxruntime can run ({type(error).__name__}: {error})"
        ) from error
    stored = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    if stored is None:
        raise ExportError(f"{path}: an ONNX model, but not a swat_jax policy (no {METADATA_KEY!r} metadata)")
    metadata = checked_metadata(path, stored, FORMAT, FORMAT_VERSION)
    structures = arrays_from_json(
        path, metadata.pop("structures", None), list(metadata["structure_fields"]), "structure"
    )
    return OnnxPolicy(path, session, metadata, structures)
