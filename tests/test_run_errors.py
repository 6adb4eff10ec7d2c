"""Errors about a run that say what is wrong and what to do, in a few lines: an unreadable checkpoint,
a run without checkpoints given to eval, a network too small for the bodies of the set."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import tiny_train_config

from swat_jax.eval import main as eval_main
from swat_jax.runs.checkpoint import ERROR_LOG, CheckpointError, CheckpointInfo, Checkpoints
from swat_jax.runs.config import CONFIG_FILE, ConfigError
from swat_jax.runs.experiment import Experiment


def test_an_unreadable_checkpoint_fits_on_a_screen_and_logs_the_detail(tmp_path):
    state = {"weights": np.arange(4096, dtype=np.float32).reshape(64, 64)}
    checkpoints = Checkpoints(tmp_path)
    info = CheckpointInfo(100, 1, 1.0, seeds=(0,), bodies=("hopper_3",), max_limbs=4, observation_features=19)
    checkpoints.save(state, {"actor": state}, info)
    for chunk in (tmp_path / "checkpoints" / "100" / "actor").rglob("d/*"):
        chunk.write_bytes(b"not a chunk")
    with pytest.raises(CheckpointError) as raised:
        checkpoints.restore_item("actor", state)
    checkpoints.close()
    message = str(raised.value)
    assert len(message) < 600 and "\n" not in message, message
    assert f"{tmp_path / 'checkpoints' / '100'} is unreadable" in message
    assert "delete that folder" in message and str(tmp_path / ERROR_LOG) in message
    assert "Traceback" in (tmp_path / ERROR_LOG).read_text()


def test_checkpoint_info_reads_back_what_was_written_and_names_a_missing_field(tmp_path):
    info = CheckpointInfo(
        600,
        3,
        12.5,
        seeds=(0, 1),
        bodies=("hopper_3",),
        max_limbs=4,
        observation_features=19,
        metrics_window={"rows": 1},
    )
    stored = info.to_json()
    assert stored["seeds"] == [0, 1] and "converted_from" not in stored
    assert CheckpointInfo.from_json(stored, tmp_path) == info
    with pytest.raises(CheckpointError, match="before runs had a seed axis"):
        CheckpointInfo.from_json({"env_steps": 600}, tmp_path)
    with pytest.raises(CheckpointError, match="lacks observation_features"):
        CheckpointInfo.from_json({k: v for k, v in stored.items() if k != "observation_features"}, tmp_path)


def test_eval_of_a_run_without_checkpoints_says_so_in_its_own_words(trained_run, tmp_path, capsys):
    shutil.copy(trained_run / CONFIG_FILE, tmp_path / CONFIG_FILE)
    assert eval_main([str(tmp_path)]) == 2
    error = capsys.readouterr().err
    assert "has no checkpoint yet, so there is no trained policy to load" in error
    assert "--overwrite" not in error and "resume" not in error


def test_a_network_too_small_for_the_bodies_names_body_limbs_and_flag(tmp_path, hopper_folder):
    config = tiny_train_config(
        tmp_path / "run", hopper_folder, algo="swat", network={"max_traversal_positions": 2}
    )
    with pytest.raises(ConfigError) as raised:
        Experiment.build(config)
    assert "hopper_3 has 3 limbs, more than the 2 positions of each traversal table" in str(raised.value)
    assert "train with --network.max-traversal-positions 3 or more" in str(raised.value)
