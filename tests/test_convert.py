"""``python -m swat_jax.convert``: a model saved by the original SWAT code becomes a run directory whose
policy acts as the original's.

The run folders in ``tests/data/original/models`` were written by the original code's own
``checkpoint.save_model`` (``tests/original_parity_data.py``); ``models.npz`` holds their state dicts
and the actions the original actors took. Reading ``.pyth`` files needs PyTorch, which CI does not
install: the test that reads them is skipped there, and the conversion itself is tested from the
state dicts.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pytest
from original_parity_data import filled_state_dict, stored_shapes

from swat_jax.convert import (
    ConversionError,
    OriginalModel,
    convert,
    main,
    read_original,
    train_config,
)
from swat_jax.networks import task_set
from swat_jax.runs.trained import load_policy

DATA = Path(__file__).parent / "data" / "original"
MODELS = np.load(DATA / "models.npz")
TOLERANCE = {"rtol": 1e-4, "atol": 1e-5}
ALGORITHMS = {"swat": "swat", "transformer": "amorpheus"}


def stored_model(architecture: str) -> OriginalModel:
    """The original run folder's checkpoint, from the state dicts the generator stored beside it."""

    def state_dict(name: str) -> dict[str, np.ndarray]:
        prefix = f"{architecture}/{name}/"
        return {key[len(prefix) :]: MODELS[key] for key in MODELS.files if key.startswith(prefix)}

    folder = DATA / "models" / architecture
    return OriginalModel(
        args=json.loads((folder / "args.txt").read_text()),
        actor=state_dict("actor"),
        critic=state_dict("critic"),
        target_actor=state_dict("target_actor"),
        target_critic=state_dict("target_critic"),
        total_timesteps=1234,
        path=folder / "model_1.pyth",
    )


def converted_actions(run_dir: Path) -> np.ndarray:
    """The converted policy's actions [B, limbs] on the fixture's observations of its body."""
    policy = load_policy(run_dir)
    body = str(MODELS["body"])
    tasks = task_set(
        [body], policy.config.network_config(), reference_inorder=policy.config.network.reference_inorder
    )
    one = jax.tree.map(lambda x: x[0], tasks.structure)
    observation = MODELS["observation"]
    limbs = int(one.num_limbs)
    observation = observation.reshape(observation.shape[0], limbs, -1)
    return np.asarray(policy.act(observation, one))[:, :limbs]


@pytest.mark.parametrize("architecture", ALGORITHMS)
def test_converted_policy_acts_as_the_original(architecture, tmp_path, hopper_folder):
    model = stored_model(architecture)
    config = train_config(model, env=str(hopper_folder), run_dir=str(tmp_path / "run"))
    assert config.algo == ALGORITHMS[architecture] and config.seed == 3
    network = config.network
    assert (network.width, network.heads, network.layers, network.feedforward) == (16, 2, 2, 32)
    run_dir = convert(model, config)
    np.testing.assert_allclose(converted_actions(run_dir), MODELS[f"{architecture}/actions"], **TOLERANCE)


def test_converted_smp_policy_acts_as_the_original(tmp_path, hopper_folder):
    """SMP at the original's sizes (its files would be megabytes: weights filled as the generator filled
    them); Hopper++'s child slots (1) come from the training bodies, as in the original."""
    weights = {
        name: filled_state_dict(stored_shapes(MODELS, f"smp/{name}"), seed)
        for name, seed in (("actor", 3), ("critic", 4))
    }
    model = OriginalModel(
        args=json.loads(str(MODELS["smp/args"])),
        actor=weights["actor"],
        critic=weights["critic"],
        target_actor=weights["actor"],
        target_critic=weights["critic"],
        total_timesteps=0,
        path=tmp_path / "model.pyth",
    )
    config = train_config(model, env=str(hopper_folder), run_dir=str(tmp_path / "run"))
    assert config.algo == "smp" and config.network_config().max_children == 1
    run_dir = convert(model, config)
    np.testing.assert_allclose(converted_actions(run_dir), MODELS["smp/actions"], **TOLERANCE)


def test_the_set_comes_from_the_original_folder_name():
    config = train_config(stored_model("swat"), env=None, run_dir="unused")
    assert config.env == "hopper"


def test_an_smp_run_without_message_passing_is_refused_with_the_reason():
    model = stored_model("swat")
    args = {**json.loads(str(MODELS["smp/args"])), "td": False, "bu": False}
    model = OriginalModel(**{**model.__dict__, "args": args})
    with pytest.raises(ConversionError, match="without --td and --bu"):
        train_config(model, env=None, run_dir="unused")


def test_a_folder_without_args_names_the_missing_file(tmp_path, capsys):
    assert main([str(tmp_path), "--run-dir", str(tmp_path / "run")]) == 2
    assert "args.txt: missing" in capsys.readouterr().err


def test_reading_the_original_files_gives_the_stored_state_dicts():
    pytest.importorskip("torch")
    read = read_original(DATA / "models" / "swat")
    stored = stored_model("swat")
    assert read.path.name == "model_1.pyth" and read.total_timesteps == 1234
    for name in ("actor", "critic", "target_actor", "target_critic"):
        ours, theirs = getattr(read, name), getattr(stored, name)
        assert ours.keys() == theirs.keys()
        for key in ours:
            np.testing.assert_array_equal(ours[key], theirs[key])
