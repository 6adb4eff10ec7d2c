"""swat_jax/runs/formats.py: each older layout of config.json and of a checkpoint's info is read from a stored
file of that layout (tests/data/formats/: the config.json files were written by swat_jax at the commit
before each change, `PRESETS[preset]` on hopper), into the config and info that computed the run; today's
files carry their version and read back equal; a newer version is refused with the versions named."""

import dataclasses
import json
from pathlib import Path

import pytest

from swat_jax.runs.checkpoint import CheckpointError, CheckpointInfo
from swat_jax.runs.config import PRESETS, ConfigError, TrainConfig, load_config
from swat_jax.runs.formats import CHECKPOINT_VERSION, CONFIG_VERSION

STORED = Path(__file__).parent / "data" / "formats"


def test_todays_config_json_carries_its_version_and_reads_back_equal(tmp_path):
    fast = dataclasses.replace(PRESETS["fast"], env="hopper")
    assert json.loads(fast.to_json())["format_version"] == CONFIG_VERSION
    written_then = dataclasses.replace(fast, td3=dataclasses.replace(fast.td3, target_pessimism=0.5))
    assert load_config(STORED / "config_v2.json") == written_then, (
        "the stored version-2 file: the fast preset it was written with, its pessimism 0.5 kept"
    )
    for preset in (fast, PRESETS["paper"]):
        (tmp_path / "config.json").write_text(preset.to_json())
        assert load_config(tmp_path / "config.json") == preset
    assert PRESETS["paper"] == TrainConfig()


def test_a_version_2_file_takes_todays_default_for_a_missing_field(tmp_path):
    """Only version 1 reads a missing switch as its earlier value: a version-2 file lacking one was not
    written by swat_jax, and gets the field's default."""
    fields = json.loads(PRESETS["paper"].to_json())
    del fields["iteration"]["diagnostics"]
    (tmp_path / "config.json").write_text(json.dumps(fields))
    assert load_config(tmp_path / "config.json").iteration.diagnostics is True


def test_a_flat_config_json_moves_its_fields_into_their_groups():
    """Before 2026-12-04 the network sizes and environment switches were top-level fields, and every
    network started from Flax's initial weights, every loop without the original's switches."""
    config = load_config(STORED / "config_v1_flat.json")
    assert (config.preset, config.envs.copies, config.envs.physics) == ("fast", 4, "auto")
    assert config.envs.torso_relative_x and not config.envs.stale_kinematics
    assert not config.network.reference_inorder and config.network.width is None
    assert config.network.initialisation == "flax"
    assert not config.iteration.round_updates and not config.iteration.diagnostics


def test_a_run_written_before_the_loop_switches_resumes_with_the_loop_it_had():
    """Without round_updates, reset_next_state and capacity_all (every run before them): updates after
    every chunk, time-limit next states as reached, 500K rows per body."""
    iteration = load_config(STORED / "config_v1_before_loop_switches.json").iteration
    assert not iteration.round_updates and not iteration.reset_next_state and iteration.capacity_all is None
    assert load_config(STORED / "config_v1_before_loop_switches.json").network.initialisation == "original"


def test_a_run_written_before_the_diagnostics_resumes_without_them():
    """Its checkpoints hold no episode values: it loads with the diagnostics off, so its state has the
    arrays its checkpoints hold (a new run has them on)."""
    config = load_config(STORED / "config_v1_before_diagnostics.json")
    assert config.iteration.diagnostics is False and config.iteration.round_updates is True
    assert PRESETS["paper"].iteration.diagnostics is True


def test_a_fast_run_written_before_the_action_penalty_resumes_without_it():
    """The fast preset of then had no --td3.action-penalty: the run goes on with TD3's actor loss, as it
    trained, not with the preset's penalty of today."""
    config = load_config(STORED / "config_v1_before_action_penalty.json")
    assert config.preset == "fast" and config.td3.action_penalty == 0.0 < PRESETS["fast"].td3.action_penalty
    assert config.iteration.diagnostics is True


def test_a_config_json_of_a_newer_version_is_refused_with_both_versions():
    with pytest.raises(
        ConfigError, match=r"config_newer.json: format version 3 is newer than this swat_jax reads \(2\)"
    ):
        load_config(STORED / "config_newer.json")


def test_checkpoint_info_of_each_layout():
    today = CheckpointInfo.from_json(json.loads((STORED / "checkpoint_info_v2.json").read_text()), STORED)
    assert today.to_json()["format_version"] == CHECKPOINT_VERSION
    assert CheckpointInfo.from_json(today.to_json(), STORED) == today
    before_3d = CheckpointInfo.from_json(
        json.loads((STORED / "checkpoint_info_v1_before_3d.json").read_text()), STORED
    )
    assert before_3d == today and before_3d.motors_per_limb == 1
    before_seeds = json.loads((STORED / "checkpoint_info_v1_before_seeds.json").read_text())
    with pytest.raises(CheckpointError, match="before runs had a seed axis"):
        CheckpointInfo.from_json(before_seeds, STORED)
    with pytest.raises(CheckpointError, match="format version 3 is newer"):
        CheckpointInfo.from_json({**today.to_json(), "format_version": 3}, STORED)
