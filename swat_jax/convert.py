"""Turn a model saved by the original SWAT code into a swat_jax run directory.

    python -m swat_jax.convert ORIGINAL_RUN --run-dir runs/converted

``ORIGINAL_RUN`` is what the original ``main.py`` writes for one experiment: a folder with its
``args.txt`` (every option of the run, as JSON) and the ``model_N.pyth`` / ``model.pyth`` checkpoints
(PyTorch pickles of the actor, critic and target state dicts). The newest checkpoint is read, or the
one ``--checkpoint`` names. The result is a run directory like one ``swat_jax.train`` writes, at 0
environment steps, whose actor, critic and targets are the original's networks (read one to one by
:mod:`swat_jax.networks.original_weights`): ``swat_jax.eval``, ``swat_jax.export``, ``swat_jax.render``
and ``--init-from`` take it, and ``swat_jax.train --resume`` continues training it (with fresh optimizer
states and empty replay buffers). Its config is the ``paper`` preset with the original run's network
sizes, algorithm, seed and environment set.

Reading ``.pyth`` files needs PyTorch (``pip install -e ".[original]"``); nothing else does.
"""

from __future__ import annotations

import dataclasses
import json
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np
import tyro

from swat_jax.cli import run_command
from swat_jax.compilation_cache import enable_caches
from swat_jax.networks import NetworkConfig
from swat_jax.networks.original_weights import StateDict, actor_params, critic_params
from swat_jax.runs.checkpoint import Checkpoints
from swat_jax.runs.config import PRESETS, ConfigError, NetworkSizes, TrainConfig
from swat_jax.runs.experiment import Experiment
from swat_jax.runs.trained import network_items
from swat_jax.train import prepare_run_dir

ALGORITHMS = {"swat": "swat", "transformer": "amorpheus", "smp": "smp"}
"""The original's ``--actor_type`` / ``--critic_type`` and our algorithm of the same network."""
SET_FOLDERS = {
    "hoppers": "hopper",
    "walkers": "walker",
    "cheetahs": "cheetah",
    "humanoids": "humanoid",
    "walker_humanoids": "wh",
    "walker_humanoids_hopper": "whh",
    "cheetah_walker_humanoids": "cwh",
    "cheetah_walker_humanoids_hopper": "cwhh",
    "wh": "wh",
    "whh": "whh",
    "cwh": "cwh",
    "cwhh": "cwhh",
}
"""The original's ``--custom_xml`` folders and the environment set each holds."""
ARGS_FILE = "args.txt"


class ConversionError(ValueError):
    """An original run that cannot be converted; the message names the file and the fix."""


@dataclasses.dataclass(frozen=True)
class OriginalModel:
    """One checkpoint of the original code, as NumPy state dicts, and the options of its run."""

    args: dict[str, Any]
    actor: StateDict
    critic: StateDict
    target_actor: StateDict
    target_critic: StateDict
    total_timesteps: int
    path: Path


def checkpoint_file(original: Path, name: str | None = None) -> Path:
    """The checkpoint to read: ``name`` in ``original``, else ``model.pyth`` (written when the original's
    training ends), else the ``model_N.pyth`` with the largest N."""
    if name:
        path = original / name
        if not path.is_file():
            raise ConversionError(f"{path}: no such checkpoint; --checkpoint names a file in {original}")
        return path
    if (original / "model.pyth").is_file():
        return original / "model.pyth"
    numbered = sorted(
        (int(match.group(1)), path)
        for path in original.glob("model_*.pyth")
        if (match := re.fullmatch(r"model_(\d+)\.pyth", path.name))
    )
    if not numbered:
        raise ConversionError(
            f"{original}: no model.pyth or model_N.pyth; is it a run folder of the original main.py?"
        )
    return numbered[-1][1]


def read_original(original: str | Path, checkpoint: str | None = None) -> OriginalModel:
    """The newest (or the named) checkpoint of an original run folder and its ``args.txt``."""
    original = Path(original)
    if not original.is_dir():
        raise ConversionError(
            f"{original}: no such folder (give the original run's folder, with {ARGS_FILE})"
        )
    args_path = original / ARGS_FILE
    try:
        args = json.loads(args_path.read_text())
    except FileNotFoundError as error:
        raise ConversionError(
            f"{args_path}: missing; the original main.py writes it at the start of a run"
        ) from error
    except json.JSONDecodeError as error:
        raise ConversionError(f"{args_path}: not JSON ({error})") from error
    path = checkpoint_file(original, checkpoint)
    saved = _torch_load(path)
    missing = [key for key in ("actor_state", "critic_state") if key not in saved]
    if missing:
        raise ConversionError(f"{path}: no {', '.join(missing)}; not a checkpoint of the original code")
    actor, critic = _numpy(saved["actor_state"]), _numpy(saved["critic_state"])
    return OriginalModel(
        args=args,
        actor=actor,
        critic=critic,
        target_actor=_numpy(saved.get("actor_target_state", saved["actor_state"])),
        target_critic=_numpy(saved.get("critic_target_state", saved["critic_state"])),
        total_timesteps=int(saved.get("total_timesteps", 0)),
        path=path,
    )


def _torch_load(path: Path) -> Mapping[str, Any]:
    try:
        import torch
    except ImportError as error:
        raise ConversionError(
            f"reading {path} needs PyTorch: pip install -e '.[original]' (or any torch CPU build)"
        ) from error
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:
        raise ConversionError(f"{path}: PyTorch cannot read it ({type(error).__name__}: {error})") from error


def _numpy(state_dict: Mapping[str, Any]) -> dict[str, np.ndarray]:
    return {key: np.asarray(value.detach().cpu().numpy(), np.float32) for key, value in state_dict.items()}


def train_config(model: OriginalModel, *, env: str | None, run_dir: str) -> TrainConfig:
    """The ``paper`` preset with the original run's algorithm, network sizes, seed and environment set."""
    args, where = model.args, model.path.parent / ARGS_FILE
    actor_type, critic_type = args.get("actor_type", "swat"), args.get("critic_type", "swat")
    if actor_type != critic_type or actor_type not in ALGORITHMS:
        raise ConversionError(
            f"{where}: actor_type {actor_type!r} and critic_type {critic_type!r}: swat_jax converts runs whose "
            f"actor and critic are the same one of {', '.join(ALGORITHMS)}"
        )
    algo = ALGORITHMS[actor_type]
    if algo == "smp" and int(args.get("msg_dim", 32)) != NetworkConfig().message_width:
        raise ConversionError(
            f"{where}: msg_dim {args['msg_dim']}: swat_jax's train config keeps SMP's messages at "
            f"{NetworkConfig().message_width} values (the original's default)"
        )
    if algo == "smp" and not (args.get("td") and args.get("bu")):
        raise ConversionError(
            f"{where}: an SMP run without --td and --bu has no message passing; swat_jax's SMP is the two-way one"
        )
    if algo != "smp" and not args.get("condition_decoder_on_features", 1):
        raise ConversionError(
            f"{where}: condition_decoder_on_features=0 is not supported (the decoder reads the limb input)"
        )
    sizes: dict[str, Any] = {}
    if algo != "smp":
        sizes = dict(
            width=int(args.get("attention_embedding_size", 128)),
            heads=int(args.get("attention_heads", 2)),
            layers=int(args.get("attention_layers", 3)),
            feedforward=int(args.get("attention_hidden_size", 256)),
        )
    elif args.get("max_children") is not None:
        sizes["max_children"] = int(args["max_children"])
    env = env or _environment_set(args, where)
    try:
        return dataclasses.replace(
            PRESETS["paper"],
            env=env,
            algo=algo,
            seed=int(args.get("seed", 0)),
            run_dir=run_dir,
            network=NetworkSizes(**sizes),
        )
    except ConfigError as error:
        raise ConversionError(f"{where}: {error}") from error


def _environment_set(args: Mapping[str, Any], where: Path) -> str:
    folder = Path(str(args.get("custom_xml") or "")).name
    if folder in SET_FOLDERS:
        return SET_FOLDERS[folder]
    raise ConversionError(
        f"{where}: cannot tell the environment set from custom_xml={args.get('custom_xml')!r}; give --env "
        "(a set name such as hopper or cwhh, or a folder of MJCF files)"
    )


def network_params(model: OriginalModel, network: NetworkConfig) -> dict[str, Any]:
    """Our actor, critic and target parameters, one seed, from the original's state dicts."""
    if not network.final_norm or network.layer_norm_epsilon != 1e-5:
        raise ConversionError("the original networks end in a LayerNorm with epsilon 1e-5")
    return {
        "actor_params": actor_params(model.actor, network),
        "critic_params": critic_params(model.critic, network),
        "target_actor_params": actor_params(model.target_actor, network),
        "target_critic_params": critic_params(model.target_critic, network),
    }


def convert(model: OriginalModel, config: TrainConfig, *, overwrite: bool = False) -> Path:
    """Write ``config``'s run directory with one checkpoint holding ``model``'s networks; returns its path."""
    experiment = Experiment.build(config)
    converted = network_params(model, config.network_config())
    state = experiment.init_state()
    learner = state.learner.replace(
        **{
            name: _with_seed_axis(model.path, name, getattr(state.learner, name), params)
            for name, params in converted.items()
        }
    )
    run_dir = prepare_run_dir(config, resume=False, overwrite=overwrite)
    checkpoints = Checkpoints(run_dir, config.keep_checkpoints)
    try:
        info = experiment.checkpoint_info(
            0, 0, 0.0, converted_from=str(model.path), original_total_timesteps=model.total_timesteps
        )
        checkpoints.save(state.replace(learner=learner), network_items(learner), info)
    finally:
        checkpoints.close()
    return run_dir


def _with_seed_axis(path: Path, name: str, ours: Any, theirs: Any) -> Any:
    """``theirs`` (one seed) repeated along ``ours``'s leading seed axis; ConversionError where a weight is
    missing or its shape differs."""
    if jax.tree_util.tree_structure(ours) != jax.tree_util.tree_structure(theirs):
        raise ConversionError(f"{path}: the original's {name} do not have the weights of this network")
    mismatched = [
        f"{jax.tree_util.keystr(key)} {np.shape(weight)} (expected {tuple(leaf.shape[1:])})"
        for (key, weight), leaf in zip(
            jax.tree_util.tree_leaves_with_path(theirs), jax.tree_util.tree_leaves(ours), strict=True
        )
        if np.shape(weight) != tuple(leaf.shape[1:])
    ]
    if mismatched:
        raise ConversionError(f"{path}: {name} weights of other shapes: {'; '.join(mismatched[:3])}")
    return jax.tree_util.tree_map(
        lambda leaf, weight: np.broadcast_to(np.asarray(weight, leaf.dtype), leaf.shape), ours, theirs
    )


@dataclasses.dataclass(frozen=True)
class ConvertCommand:
    """Turn a model saved by the original SWAT code (its main.py) into a swat_jax run directory that eval,
    export, render and --init-from accept."""

    original: tyro.conf.Positional[Path]
    """The original run's folder: its args.txt and model_N.pyth files."""
    run_dir: str
    """The swat_jax run directory to write."""
    checkpoint: str | None = None
    """Which file of the folder to read; None: model.pyth, else the newest model_N.pyth."""
    env: str | None = None
    """Environment set or MJCF folder of the run; None: from the original's custom_xml folder name."""
    overwrite: bool = False
    """Replace --run-dir if it exists."""


def run(command: ConvertCommand) -> str:
    """Convert as the command says; returns what was written."""
    model = read_original(command.original, command.checkpoint)
    config = train_config(model, env=command.env, run_dir=command.run_dir)
    run_dir = convert(model, config, overwrite=command.overwrite)
    return f"wrote {run_dir} ({config.algo} on {config.env}) from {model.path}"


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for an unreadable original run or a bad option)."""
    enable_caches()
    return run_command(
        ConvertCommand, run, argv, (ConversionError, ConfigError), prog="python -m swat_jax.convert"
    )


if __name__ == "__main__":
    sys.exit(main())
