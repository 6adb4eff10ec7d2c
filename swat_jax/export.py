"""A trained policy as one file that runs without the training code: ``python -m swat_jax.export``.

``export_policy`` serialises the run's jitted actor with :mod:`jax.export`: the parameters are baked in
as constants, and the structure arrays of one body are inputs, so one file serves every body of up to
``max_limbs`` limbs at any batch size (the batch dimension is symbolic). The file is a NumPy ``.npz``
archive (read with ``allow_pickle=False``) holding

- ``program``: the serialised :class:`jax.export.Exported` (uint8 bytes);
- ``metadata``: a JSON string: format and version, the jax version that wrote the program, algo, env,
  env steps, max limbs, observation features, the order of the structure inputs, the bodies stored
  below and the platforms compiled for;
- ``structure.<field>``: the padded structure arrays of every body of the run's set (train and test),
  [K, L, ...] in the order of ``metadata["bodies"]``, so a body can be named instead of encoded.

:func:`load` and :class:`ExportedPolicy` import only jax and numpy (the training code, Flax, MuJoCo and
Orbax are imported lazily by :func:`export_policy` alone)::

    python -m swat_jax.export runs/walker-swat-seed0 -o walker.npz

    policy = swat_jax.export.load("walker.npz")
    actions = policy(observation, "walker_3_main")  # observation [batch, L, F] -> actions [batch, L]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from swat_jax.cli import ERROR_STATUS, positive_int

if TYPE_CHECKING:
    from swat_jax.morphology import StructureBatch
    from swat_jax.networks import LimbNetwork, Params

FORMAT = "swat_jax.exported_policy"
"""``metadata["format"]`` of every exported policy file."""
FORMAT_VERSION = 1
"""``metadata["format_version"]`` written here; :func:`load` reads this version and earlier ones."""
SUFFIX = ".npz"
PROGRAM_KEY = "program"
METADATA_KEY = "metadata"
STRUCTURE_PREFIX = "structure."
PLATFORMS = ("cpu", "cuda")
"""Default platforms compiled into the file: one file runs on CPU and on NVIDIA GPUs."""
KNOWN_PLATFORMS = ("cpu", "cuda", "rocm", "tpu")
WRITE_STATUS = 1
"""Exit status when the file cannot be written."""

StructureInput = str | Mapping[str, Any] | Any
"""A body name of the file, a mapping from structure field to array, or a StructureBatch slice."""


class ExportError(ValueError):
    """A run that cannot be exported as asked, or a file that is not a usable exported policy."""


def policy_path(path: str | Path) -> Path:
    """``path`` as a Path, checked to end in ``.npz``; ExportError otherwise."""
    path = Path(path)
    if path.suffix.lower() != SUFFIX:
        raise ExportError(
            f"{path}: an exported policy is a NumPy archive; use the suffix {SUFFIX}, "
            f"not {path.suffix or '(none)'!r}"
        )
    return path


def serialize_actor(
    actor: LimbNetwork, params: Params, structure: StructureBatch, platforms: Sequence[str] = PLATFORMS
) -> bytearray:
    """The jitted actor with ``params`` baked in, exported for a symbolic batch size and serialised.

    Args:
        actor: the actor (``make_actor_critic(...)[0]``); any architecture.
        params: its parameters, stored in the program as constants.
        structure: one body's StructureBatch slice padded to L limbs; only shapes and dtypes are used.
        platforms: platforms to compile for ("cpu", "cuda", "rocm", "tpu"); the file runs on any of them.

    Returns:
        The serialised program ``policy(observation [b, L, F] float32, *structure fields) -> actions
        [b, L] float32``, the structure fields as separate arguments in StructureBatch order.
    """
    from swat_jax.morphology import StructureBatch

    def policy(observation: jax.Array, *fields: jax.Array) -> jax.Array:
        return actor.apply(params, observation, StructureBatch(*fields))

    (batch,) = jax.export.symbolic_shape("batch")
    limbs = np.shape(structure.limb_mask)[0]
    observation = jax.ShapeDtypeStruct((batch, limbs, actor.obs_features), np.float32)
    fields = [jax.ShapeDtypeStruct(np.shape(field), np.asarray(field).dtype) for field in structure]
    exported = jax.export.export(jax.jit(policy), platforms=tuple(platforms))(observation, *fields)
    return exported.serialize()


def write_policy(
    path: str | Path,
    program: bytes | bytearray,
    structures: StructureBatch,
    bodies: Sequence[str],
    observation_features: int,
    **details: Any,
) -> dict[str, Any]:
    """Write an exported policy file (replacing any file of that name only once it is complete).

    Args:
        path: the ``.npz`` file to write; parent folders are created.
        program: from :func:`serialize_actor`.
        structures: [K, L, ...] padded structures of the bodies the file names.
        bodies: the K body names, in the order of ``structures``.
        observation_features: F, observation values per limb.
        details: further JSON-serialisable metadata (algo, env, env_steps, ...).

    Returns:
        The metadata written.
    """
    path = policy_path(path)
    if len(set(bodies)) != len(bodies):
        raise ExportError(f"body names must be distinct to be looked up by name, got {list(bodies)}")
    metadata = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "jax_version": jax.__version__,
        **details,
        "max_limbs": int(np.shape(structures.limb_mask)[1]),
        "observation_features": int(observation_features),
        "structure_fields": list(structures._fields),
        "bodies": list(bodies),
    }
    arrays = {f"{STRUCTURE_PREFIX}{name}": np.asarray(field) for name, field in structures._asdict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    try:
        with open(partial, "wb") as file:
            np.savez(
                file,
                **{
                    PROGRAM_KEY: np.frombuffer(bytes(program), np.uint8),
                    METADATA_KEY: np.array(json.dumps(metadata)),
                },
                **arrays,
            )
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return metadata


def export_policy(
    run_dir: str | Path,
    output: str | Path,
    *,
    max_limbs: int | None = None,
    platforms: Sequence[str] = PLATFORMS,
    seed_index: int = 0,
) -> dict[str, Any]:
    """Export the newest checkpoint's actor of ``run_dir`` to ``output`` (see the module docstring).

    Args:
        run_dir: a training run directory (``python -m swat_jax.train``).
        output: the ``.npz`` file to write.
        seed_index: which of the run's seeds (an index into its seed axis) to export.
        max_limbs: L, the limb count every input is padded to; default the largest body of the run's set
            (train and test splits). Raise it to serve larger bodies than the set's.
        platforms: platforms compiled for.

    Returns:
        The metadata written to the file.

    Raises:
        ConfigError, CheckpointError: the run directory cannot be read.
        MorphologyError: a body of the run's set cannot be loaded.
        ExportError: the output name, ``max_limbs`` or ``platforms`` does not fit.
    """
    # The training code is imported here only, so that `load` runs without it.
    from swat_jax.morphology import get_set
    from swat_jax.morphology import load as load_body
    from swat_jax.networks import task_set
    from swat_jax.runs.config import ConfigError
    from swat_jax.runs.experiment import load_policy

    output = policy_path(output)
    platforms = _checked_platforms(platforms)
    policy = load_policy(run_dir)
    config = policy.config
    try:
        body_set = get_set(config.env)
    except ValueError as error:
        raise ConfigError(f"{run_dir}: the run's environment set is not available: {error}") from error
    train, test = body_set.split("train"), body_set.split("test")
    bodies = [load_body(body) for body in train + test]
    largest = max(bodies, key=lambda body: body.num_limbs)
    if max_limbs is None:
        max_limbs = largest.num_limbs
    elif max_limbs < largest.num_limbs:
        raise ExportError(
            f"--max-limbs {max_limbs} is below the {largest.num_limbs} limbs of {largest.name}, a body of "
            f"{config.env}; use at least {largest.num_limbs}"
        )
    network = config.network()
    if network.traversals and max_limbs > network.max_traversal_positions:
        raise ExportError(
            f"--max-limbs {max_limbs} is more than the {network.max_traversal_positions} traversal positions "
            f"{config.algo} has learned, so larger bodies could not be encoded; use at most "
            f"{network.max_traversal_positions}"
        )
    try:
        structures = task_set(
            bodies, network, max_limbs=max_limbs, reference_inorder=config.reference_inorder
        ).structure
    except ValueError as error:
        raise ExportError(f"{config.algo} cannot take the bodies of {config.env}: {error}") from error
    program = serialize_actor(
        policy.actor, policy.seed_params(seed_index), jax.tree.map(lambda x: x[0], structures), platforms
    )
    return write_policy(
        output,
        program,
        structures,
        [body.name for body in bodies],
        int(policy.info["observation_features"]),
        algo=config.algo,
        env=config.env,
        env_steps=int(policy.info["env_steps"]),
        seed=policy.seeds[seed_index],
        train_bodies=[body.name for body in bodies[: len(train)]],
        test_bodies=[body.name for body in bodies[len(train) :]],
        reference_inorder=config.reference_inorder,
        torso_relative_x=config.torso_relative_x,
        network=dataclasses.asdict(network),
        platforms=list(platforms),
    )


def _checked_platforms(platforms: Sequence[str]) -> tuple[str, ...]:
    chosen = tuple(platforms)
    unknown = [platform for platform in chosen if platform not in KNOWN_PLATFORMS]
    if not chosen or unknown:
        raise ExportError(f"platforms must be drawn from {', '.join(KNOWN_PLATFORMS)}, got {list(chosen)}")
    return chosen


class ExportedPolicy:
    """A policy read from an exported file; calling it needs only jax and numpy.

    ``policy(observation, structure)`` maps observation [batch, L, F] to actions [batch, L] in [-1, 1]
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
        self.path = path
        self.metadata = metadata
        """The file's metadata (see the module docstring)."""
        self._exported = exported
        self._call = jax.jit(exported.call)
        self._fields: list[str] = list(metadata["structure_fields"])
        self._structures = structures
        self._by_name: dict[str, tuple[jax.Array, ...]] = {}

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

    def __call__(self, observation: Any, structure: StructureInput) -> jax.Array:
        """observation [batch, L, F] (rows beyond the body's limbs are ignored), one body's structure ->
        actions [batch, L] float32 in [-1, 1], zero on padded limbs."""
        observation = np.asarray(observation) if not isinstance(observation, jax.Array) else observation
        expected = (self.max_limbs, self.observation_features)
        if observation.ndim != 3 or tuple(observation.shape[1:]) != expected or observation.shape[0] < 1:
            raise ValueError(
                f"observation must be [batch, {expected[0]}, {expected[1]}] (batch >= 1, limbs padded to max_limbs "
                f"{expected[0]}, {expected[1]} observation features), got shape "
                f"{tuple(observation.shape)}"
            )
        fields = self._structure_arrays(structure)
        return self._call(observation.astype(np.float32), *fields)

    def _structure_arrays(self, structure: StructureInput) -> tuple[Any, ...]:
        """The structure inputs of the program, in order, checked against its input shapes."""
        if isinstance(structure, str):
            if structure not in self._by_name:
                self._by_name[structure] = tuple(
                    jax.device_put(array) for array in self.structure(structure).values()
                )
            return self._by_name[structure]
        arrays = []
        for name, aval in zip(self._fields, self._exported.in_avals[1:], strict=True):
            value = structure.get(name) if isinstance(structure, Mapping) else getattr(structure, name, None)
            if value is None:
                raise ValueError(f"structure has no field {name!r}; it needs {', '.join(self._fields)}")
            if tuple(np.shape(value)) != tuple(aval.shape):
                raise ValueError(
                    f"structure.{name} must be {list(aval.shape)} {aval.dtype} (one body padded to max_limbs "
                    f"{self.max_limbs}), got shape {list(np.shape(value))}"
                )
            arrays.append(
                value.astype(aval.dtype) if isinstance(value, jax.Array) else np.asarray(value, aval.dtype)
            )
        return tuple(arrays)


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
    try:
        metadata = json.loads(str(archive[METADATA_KEY]))
    except (ValueError, TypeError) as error:
        raise ExportError(f"{path}: not an exported policy: its metadata is not JSON ({error})") from error
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        raise ExportError(f"{path}: not an exported policy: its metadata format is not {FORMAT!r}")
    version = metadata.get("format_version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise ExportError(
            f"{path}: format version {version!r} is newer than this swat_jax reads ({FORMAT_VERSION}); "
            f"update swat_jax or export the policy again"
        )
    missing = [
        key
        for key in ("max_limbs", "observation_features", "structure_fields", "bodies")
        if key not in metadata
    ]
    if missing:
        raise ExportError(f"{path}: not a complete exported policy: its metadata has no {', '.join(missing)}")
    return metadata


def _platform_list(text: str) -> tuple[str, ...]:
    try:
        return _checked_platforms([part.strip() for part in text.split(",") if part.strip()])
    except ExportError as error:
        raise argparse.ArgumentTypeError(str(error)) from error


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser."""
    parser = argparse.ArgumentParser(
        prog="python -m swat_jax.export",
        description="Write the newest checkpoint's policy of a training run as one file that runs without "
        "the training code (swat_jax.export.load, which needs only jax and numpy). The body structure is an "
        "input, so the file serves every body of up to --max-limbs limbs, at any batch size.",
    )
    parser.add_argument("run_dir", metavar="RUN_DIR", type=Path, help="training run directory to export")
    parser.add_argument("-o", "--output", type=Path, required=True, help=f"policy file to write ({SUFFIX})")
    parser.add_argument(
        "--max-limbs",
        type=positive_int,
        metavar="N",
        help="limb count every input is padded to (default: the largest body of the run's set, train and test)",
    )
    parser.add_argument(
        "--platforms",
        type=_platform_list,
        metavar="LIST",
        default=PLATFORMS,
        help=f"comma-separated platforms to compile for, of {', '.join(KNOWN_PLATFORMS)} "
        f"(default {','.join(PLATFORMS)})",
    )
    parser.add_argument(
        "--seed-index",
        type=int,
        default=0,
        metavar="K",
        help="which seed of a multi-seed run to export: an index into the run's seeds (default 0, the first)",
    )
    return parser


def run(args: argparse.Namespace) -> None:
    """Export one parsed command line and print what was written."""
    metadata = export_policy(
        args.run_dir,
        args.output,
        max_limbs=args.max_limbs,
        platforms=args.platforms,
        seed_index=args.seed_index,
    )
    size = args.output.stat().st_size / 2**20
    print(
        f"wrote {args.output} ({size:.1f} MiB): {metadata['algo']} policy (seed {metadata['seed']}) after "
        f"{metadata['env_steps']:,} "
        f"environment steps; max limbs {metadata['max_limbs']}, {metadata['observation_features']} observation "
        f"features, platforms {', '.join(metadata['platforms'])}; bodies ({len(metadata['bodies'])}): "
        f"{', '.join(metadata['bodies'])}"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad run or option, 1 if writing fails)."""
    from swat_jax.runs.checkpoint import CheckpointError

    args = build_parser().parse_args(argv)
    try:
        run(args)
    except (ValueError, CheckpointError) as error:
        print(f"error: {error}", file=sys.stderr)
        return ERROR_STATUS
    except OSError as error:
        print(f"error: {error}", file=sys.stderr)
        return WRITE_STATUS
    return 0


if __name__ == "__main__":
    sys.exit(main())
