"""A trained policy as one file that runs without the training code: ``python -m swat_jax.export``.

:func:`export_policy` serialises the run's jitted actor with :mod:`jax.export`: the parameters are baked in
as constants, and the structure arrays of one body are inputs, so one file serves every body of up to
``max_limbs`` limbs at any batch size (the batch dimension is symbolic). The file's format and its loader,
which needs only jax and numpy, are :mod:`swat_jax.serving`::

    python -m swat_jax.export runs/walker-swat-seed0 -o walker.npz

    policy = swat_jax.serving.load("walker.npz")
    actions = policy(observation, "walker_3_main")  # observation [batch, L, F] -> actions [batch, L] ([batch, L, 3] in 3D)

``--format onnx`` writes the same actor as an ONNX model instead (:func:`onnx_actor`, through jax2onnx),
which onnxruntime runs without jax (:mod:`swat_jax.onnx_policy`)::

    python -m swat_jax.export runs/walker-swat-seed0 --format onnx -o walker.onnx
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import jax
import numpy as np
import tyro

from swat_jax.cli import run_command
from swat_jax.compilation_cache import enable_caches
from swat_jax.envs.config import EnvConfig
from swat_jax.envs.controller import body_interface, interface_arrays
from swat_jax.morphology import Morphology, StructureBatch, get_set
from swat_jax.morphology import load as load_body
from swat_jax.morphology.mjcf import compile_model
from swat_jax.networks import LimbNetwork, Params
from swat_jax.onnx_policy import ACTION_OUTPUT, OBSERVATION_INPUT, onnx_path
from swat_jax.onnx_policy import FORMAT as ONNX_FORMAT
from swat_jax.onnx_policy import FORMAT_VERSION as ONNX_FORMAT_VERSION
from swat_jax.onnx_policy import METADATA_KEY as ONNX_METADATA_KEY
from swat_jax.policy_files import arrays_to_json
from swat_jax.runs.checkpoint import CheckpointError
from swat_jax.runs.config import ConfigError, TrainConfig
from swat_jax.runs.trained import load_policy
from swat_jax.serving import (
    FORMAT,
    FORMAT_VERSION,
    METADATA_KEY,
    PROGRAM_KEY,
    STRUCTURE_PREFIX,
    ExportError,
    policy_path,
)

Platform = Literal["cpu", "cuda", "rocm", "tpu"]
"""A platform jax.export compiles for."""
KNOWN_PLATFORMS: tuple[str, ...] = get_args(Platform)
PLATFORMS: tuple[Platform, ...] = ("cpu", "cuda")
"""Default platforms compiled into the file: one file runs on CPU and on NVIDIA GPUs."""
WRITE_STATUS = 1
"""Exit status when the file cannot be written."""
FileFormat = Literal["jax", "onnx"]
"""What ``python -m swat_jax.export`` writes: a jax.export program in a .npz, or an ONNX model."""
CONVERTER_HINT = "pip install 'swat-jax[onnx]' (jax2onnx 0.12.5, onnx and onnxruntime)"


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
        [b, L] float32`` (``[b, L, M]`` for M > 1 actions per limb, 3D bodies), the structure fields as
        separate arguments in StructureBatch order.
    """

    (batch,) = jax.export.symbolic_shape("batch")
    observation = jax.ShapeDtypeStruct((batch, _limbs(structure), actor.obs_features), np.float32)
    policy = jax.jit(_actor_function(actor, params))
    exported = jax.export.export(policy, platforms=tuple(platforms))(observation, *_field_specs(structure))
    return exported.serialize()


def _actor_function(actor: LimbNetwork, params: Params) -> Any:
    """``policy(observation [b, L, F], *structure fields) -> actions``: the function both formats export."""

    def policy(observation: jax.Array, *fields: jax.Array) -> jax.Array:
        return actor.apply(params, observation, StructureBatch(*fields))

    return policy


def _limbs(structure: StructureBatch) -> int:
    """L of one body's padded structure."""
    return np.shape(structure.limb_mask)[0]


def _field_specs(structure: StructureBatch) -> list[jax.ShapeDtypeStruct]:
    """The shapes and dtypes of one body's structure fields, the exported function's inputs after the
    observation."""
    return [jax.ShapeDtypeStruct(np.shape(field), np.asarray(field).dtype) for field in structure]


def onnx_actor(actor: LimbNetwork, params: Params, structure: StructureBatch) -> Any:
    """The actor with ``params`` as initialisers, converted to an ONNX model (an ``onnx.ModelProto``) by
    jax2onnx: inputs ``observation`` [batch, L, F] float32 (the batch dimension dynamic) and the structure
    fields under their StructureBatch names, output ``actions`` [batch, L] ([batch, L, M] in 3D).

    Args:
        actor: the actor (``make_actor_critic(...)[0]``): SWAT, AMORPHEUS or SET; SMP's scan over limbs does
            not convert (ExportError).
        params: its parameters.
        structure: one body's StructureBatch slice padded to L limbs; only shapes and dtypes are used.
    """
    if actor.module.config.architecture == "smp":
        raise ExportError(
            "SMP's scan over the limbs does not convert to ONNX (jax2onnx 0.12.5); export an SMP policy with "
            "--format jax (swat_jax.serving.load)"
        )
    try:
        from jax2onnx import to_onnx
    except ImportError as error:
        raise ExportError(f"--format onnx needs jax2onnx: {CONVERTER_HINT}") from error

    with _quiet("jax2onnx", "onnx_ir"):
        return to_onnx(
            _actor_function(actor, params),
            [("batch", _limbs(structure), actor.obs_features), *_field_specs(structure)],
            model_name="swat_jax_policy",
            input_names=[OBSERVATION_INPUT, *structure._fields],
            output_names=[ACTION_OUTPUT],
        )


@contextlib.contextmanager
def _quiet(*loggers: str) -> Iterator[None]:
    """Only errors from ``loggers``, and no deprecation warnings of theirs, while converting (jax2onnx warns
    of every plugin it cannot import and of the jax APIs it still uses)."""
    levels = {name: logging.getLogger(name).level for name in loggers}
    for name in loggers:
        logging.getLogger(name).setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            for name in loggers:
                warnings.filterwarnings("ignore", category=DeprecationWarning, module=name)
            yield
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def write_onnx_policy(
    path: str | Path,
    model: Any,
    structures: StructureBatch,
    bodies: Sequence[str],
    observation_features: int,
    **details: Any,
) -> dict[str, Any]:
    """Write an ONNX policy file (:mod:`swat_jax.onnx_policy`): ``model`` from :func:`onnx_actor` with the
    metadata and the [K, L, ...] ``structures`` of ``bodies`` in its ``metadata_props``; arguments as
    :func:`write_policy`'s. Returns the metadata written (without the structures)."""
    path = onnx_path(path)
    metadata = policy_metadata(
        ONNX_FORMAT, ONNX_FORMAT_VERSION, structures, bodies, observation_features, details
    )
    del model.metadata_props[:]
    entry = model.metadata_props.add()
    entry.key = ONNX_METADATA_KEY
    entry.value = json.dumps({**metadata, "structures": arrays_to_json(structures._asdict())})
    _write_whole(path, model.SerializeToString())
    return metadata


def policy_metadata(
    file_format: str,
    version: int,
    structures: StructureBatch,
    bodies: Sequence[str],
    observation_features: int,
    details: dict[str, Any],
) -> dict[str, Any]:
    """A policy file's metadata (:mod:`swat_jax.policy_files`); ExportError if two bodies share a name."""
    if len(set(bodies)) != len(bodies):
        raise ExportError(f"body names must be distinct to be looked up by name, got {list(bodies)}")
    return {
        "format": file_format,
        "format_version": version,
        "jax_version": jax.__version__,
        **details,
        "max_limbs": int(np.shape(structures.limb_mask)[1]),
        "observation_features": int(observation_features),
        "structure_fields": list(structures._fields),
        "bodies": list(bodies),
    }


def _write_whole(path: Path, content: bytes) -> None:
    """``content`` to ``path`` through a ``.partial`` file renamed over it once written; parents created."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    try:
        partial.write_bytes(content)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


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
    metadata = policy_metadata(FORMAT, FORMAT_VERSION, structures, bodies, observation_features, details)
    arrays = {f"{STRUCTURE_PREFIX}{name}": np.asarray(field) for name, field in structures._asdict().items()}
    archive = io.BytesIO()
    np.savez(
        archive,
        **{
            PROGRAM_KEY: np.frombuffer(bytes(program), np.uint8),
            METADATA_KEY: np.array(json.dumps(metadata)),
        },
        **arrays,
    )
    _write_whole(path, archive.getvalue())
    return metadata


def export_policy(
    run_dir: str | Path,
    output: str | Path,
    *,
    max_limbs: int | None = None,
    platforms: Sequence[str] = PLATFORMS,
    seed_index: int = 0,
    file_format: FileFormat = "jax",
) -> dict[str, Any]:
    """Export the newest checkpoint's actor of ``run_dir`` to ``output`` (see the module docstring).

    Args:
        run_dir: a training run directory (``python -m swat_jax.train``).
        output: the file to write: ``.npz`` for ``file_format`` "jax", ``.onnx`` for "onnx".
        seed_index: which of the run's seeds (an index into its seed axis) to export.
        max_limbs: L, the limb count every input is padded to; default the largest body of the run's set
            (train and test splits). Raise it to serve larger bodies than the set's.
        platforms: platforms compiled for ("jax" only; an ONNX model runs wherever onnxruntime does).
        file_format: "jax" (a jax.export program, :mod:`swat_jax.serving`) or "onnx" (:mod:`swat_jax.onnx_policy`).

    Returns:
        The metadata written to the file.

    Raises:
        ConfigError, CheckpointError: the run directory cannot be read.
        MorphologyError: a body of the run's set cannot be loaded.
        ExportError: the output name, ``max_limbs`` or ``platforms`` does not fit.
    """
    output = onnx_path(output) if file_format == "onnx" else policy_path(output)
    platforms = _checked_platforms(platforms)
    policy = load_policy(run_dir)
    config = policy.config
    bodies, train_count = _set_bodies(run_dir, config)
    max_limbs = _checked_max_limbs(max_limbs, bodies, config)
    try:
        structures = policy.task_set(bodies, max_limbs=max_limbs).structure
    except ValueError as error:
        raise ExportError(f"{config.algo} cannot take the bodies of {config.env}: {error}") from error
    params, structure = policy.seed_params(seed_index), jax.tree.map(lambda x: x[0], structures)
    details = {
        "algo": config.algo,
        "env": config.env,
        "env_steps": policy.info.env_steps,
        "seed": policy.seeds[seed_index],
        "train_bodies": [body.name for body in bodies[:train_count]],
        "test_bodies": [body.name for body in bodies[train_count:]],
        "reference_inorder": config.network.reference_inorder,
        "torso_relative_x": config.envs.torso_relative_x,
        "network": dataclasses.asdict(config.network_config()),
        "interfaces": interfaces_to_json(bodies, config.envs),
    }
    names, features = [body.name for body in bodies], policy.info.observation_features
    if file_format == "onnx":
        model = onnx_actor(policy.actor, params, structure)
        return write_onnx_policy(output, model, structures, names, features, **details)
    program = serialize_actor(policy.actor, params, structure, platforms)
    return write_policy(output, program, structures, names, features, **details, platforms=list(platforms))


def interfaces_to_json(bodies: Sequence[Morphology], envs: EnvConfig) -> dict[str, dict[str, Any]]:
    """Each body's :class:`~swat_jax.envs.controller.BodyInterface` under the run's observation switches, as
    the JSON a policy file's metadata holds (:meth:`swat_jax.policy_files.PolicyFile.interface`)."""
    interfaces = {}
    for body in bodies:
        interface = body_interface(
            body,
            compile_model(body),
            torso_relative_x=envs.torso_relative_x,
            stale_kinematics=envs.stale_kinematics,
        )
        fields = interface_arrays(interface)
        arrays = {name: value for name, value in fields.items() if isinstance(value, np.ndarray)}
        interfaces[body.name] = {**fields, **arrays_to_json(arrays)}
    return interfaces


def _set_bodies(run_dir: str | Path, config: TrainConfig) -> tuple[list[Morphology], int]:
    """The bodies of the run's environment set, its train split then its test split, and how many are train
    bodies; ConfigError if the set is not available."""
    try:
        body_set = get_set(config.env)
    except ValueError as error:
        raise ConfigError(f"{run_dir}: the run's environment set is not available: {error}") from error
    train = body_set.split("train")
    return [load_body(body) for body in train + body_set.split("test")], len(train)


def _checked_max_limbs(max_limbs: int | None, bodies: Sequence[Morphology], config: TrainConfig) -> int:
    """The limb count the file's inputs are padded to: ``max_limbs``, or the largest of ``bodies`` for None;
    ExportError if it is below that body's or beyond the traversal positions the run's network learned."""
    largest = max(bodies, key=lambda body: body.num_limbs)
    if max_limbs is None:
        max_limbs = largest.num_limbs
    elif max_limbs < largest.num_limbs:
        raise ExportError(
            f"--max-limbs {max_limbs} is below the {largest.num_limbs} limbs of {largest.name}, a body of "
            f"{config.env}; use at least {largest.num_limbs}"
        )
    network = config.network_config()
    if network.traversals and max_limbs > network.max_traversal_positions:
        raise ExportError(
            f"--max-limbs {max_limbs} is more than the {network.max_traversal_positions} traversal positions "
            f"{config.algo} has learned, so larger bodies could not be encoded; use at most "
            f"{network.max_traversal_positions}"
        )
    return max_limbs


def _checked_platforms(platforms: Sequence[str]) -> tuple[str, ...]:
    chosen = tuple(platforms)
    unknown = [platform for platform in chosen if platform not in KNOWN_PLATFORMS]
    if not chosen or unknown:
        raise ExportError(f"platforms must be drawn from {', '.join(KNOWN_PLATFORMS)}, got {list(chosen)}")
    return chosen


@dataclasses.dataclass(frozen=True)
class ExportCommand:
    """Write the newest checkpoint's policy of a training run as one file that runs without the training
    code: a jax.export program (swat_jax.serving.load, which needs only jax and numpy) or, with --format onnx,
    an ONNX model (swat_jax.onnx_policy.load, which needs only onnxruntime and numpy). The body structure is
    an input, so the file serves every body of up to --max-limbs limbs, at any batch size."""

    run_dir: tyro.conf.Positional[Path]
    """Training run directory to export."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """Policy file to write: .npz (--format jax) or .onnx (--format onnx)."""
    format: FileFormat = "jax"
    """jax: a jax.export program in a .npz; onnx: an ONNX model of the actor (SWAT or AMORPHEUS; needs the onnx extra: pip install 'swat-jax[onnx]')."""
    max_limbs: int | None = None
    """Limb count every input is padded to; None: the largest body of the run's set, train and test."""
    platforms: tuple[Platform, ...] = PLATFORMS
    """Platforms to compile for (the file runs on each); --format jax only."""
    seed_index: int = 0
    """Which seed of a multi-seed run to export: an index into the run's seeds (0, the first)."""


def run(command: ExportCommand) -> str:
    """Export as the command says; returns what was written."""
    metadata = export_policy(
        command.run_dir,
        command.output,
        max_limbs=command.max_limbs,
        platforms=command.platforms,
        seed_index=command.seed_index,
        file_format=command.format,
    )
    size = command.output.stat().st_size / 2**20
    runs_on = (
        f"platforms {', '.join(metadata['platforms'])}"
        if "platforms" in metadata
        else "an ONNX model (onnxruntime)"
    )
    return (
        f"wrote {command.output} ({size:.1f} MiB): {metadata['algo']} policy (seed {metadata['seed']}) after "
        f"{metadata['env_steps']:,} environment steps; max limbs {metadata['max_limbs']}, "
        f"{metadata['observation_features']} observation features, {runs_on}; "
        f"bodies ({len(metadata['bodies'])}): {', '.join(metadata['bodies'])}"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad run or option, 1 if writing fails)."""
    enable_caches()
    try:
        return run_command(
            ExportCommand, run, argv, (ValueError, CheckpointError), prog="python -m swat_jax.export"
        )
    except OSError as error:
        print(f"error: {error}", file=sys.stderr)
        return WRITE_STATUS


if __name__ == "__main__":
    sys.exit(main())
