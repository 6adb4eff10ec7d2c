"""Errors about a run that say what is wrong and what to do, in a few lines: an unreadable checkpoint,
a run without checkpoints given to eval, a network too small for the bodies of the set."""

from __future__ import annotations

import shutil

import pytest
from checkpoint_states import STATE, info_at
from conftest import tiny_train_config

from swat_jax.eval import main as eval_main
from swat_jax.runs.checkpoint import ERROR_LOG, CheckpointError, CheckpointInfo, Checkpoints
from swat_jax.runs.config import CONFIG_FILE, ConfigError
from swat_jax.runs.experiment import Experiment
from swat_jax.runs.integrity import write_record


def test_an_unreadable_checkpoint_fits_on_a_screen_and_logs_the_detail(tmp_path):
    """A checkpoint whose record checks out but that Orbax cannot read (damaged before its record was
    written, or written by another Orbax): one line, the detail in ERROR_LOG."""
    checkpoints = Checkpoints(tmp_path)
    checkpoints.save(STATE, {"actor": STATE}, info_at(100))
    folder = tmp_path / "checkpoints" / "100"
    (folder / "actor" / "_METADATA").write_text("not JSON")
    write_record(folder)
    with pytest.raises(CheckpointError) as raised:
        checkpoints.restore_item("actor", STATE)
    checkpoints.close()
    message = str(raised.value)
    assert len(message) < 600 and "\n" not in message, message
    assert f"{folder} is unreadable" in message
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


def test_eval_of_a_damaged_checkpoint_names_it_and_why_in_one_line(trained_run, tmp_path, capsys):
    run_dir = tmp_path / "run"
    shutil.copytree(trained_run, run_dir)
    actor = run_dir / "checkpoints" / "600" / "actor"
    largest = max((p for p in actor.rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    largest.write_bytes(largest.read_bytes()[:-1])
    assert eval_main([str(run_dir)]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert f"{run_dir / 'checkpoints' / '600'} is damaged: actor/" in line
    assert "bytes where" in line and f"--resume {run_dir} sets it aside" in line
