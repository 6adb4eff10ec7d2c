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
from swat_jax.train import parse_command

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
    assert config.iteration.loop == "all_tasks" and not config.iteration.diagnostics


def test_a_run_written_before_the_loop_switches_resumes_with_the_loop_it_had():
    """Without round_updates, reset_next_state and capacity_all (every run before them): updates after
    every chunk, time-limit next states as reached, 500K rows per body."""
    iteration = load_config(STORED / "config_v1_before_loop_switches.json").iteration
    assert (
        iteration.loop == "rounds_chunked"
        and not iteration.reset_next_state
        and iteration.capacity_all is None
    )
    assert load_config(STORED / "config_v1_before_loop_switches.json").network.initialisation == "original"


def test_a_run_written_before_the_diagnostics_resumes_without_them():
    """Its checkpoints hold no episode values: it loads with the diagnostics off, so its state has the
    arrays its checkpoints hold (a new run has them on)."""
    config = load_config(STORED / "config_v1_before_diagnostics.json")
    assert config.iteration.diagnostics is False and config.iteration.loop == "rounds"
    assert PRESETS["paper"].iteration.diagnostics is True


def test_a_fast_run_written_before_the_action_penalty_resumes_without_it():
    """The fast preset of then had no --td3.action-penalty: the run goes on with TD3's actor loss, as it
    trained, not with the preset's penalty of today."""
    config = load_config(STORED / "config_v1_before_action_penalty.json")
    assert config.preset == "fast" and config.td3.action_penalty == 0.0 < PRESETS["fast"].td3.action_penalty
    assert config.iteration.diagnostics is True


@pytest.mark.parametrize("preset", ["paper", "intended"])
def test_a_version_2_file_has_its_three_loop_fields_read_as_one_loop(preset):
    """Version 2 held the loop in rounds, round_updates and schedule (tests/data/formats/config_v2_*.json:
    the presets of then); it reads as today's preset, whose loop is one field."""
    assert load_config(STORED / f"config_v2_{preset}.json") == dataclasses.replace(
        PRESETS[preset], env="hopper"
    )


@pytest.mark.parametrize(
    ("fields", "loop"),
    [
        ({"rounds": False, "schedule": "original"}, "per_body"),
        ({"rounds": False}, "per_body"),
        ({"round_updates": False}, "rounds_chunked"),
        ({}, "rounds"),
    ],
)
def test_each_version_2_combination_is_its_loop_and_a_refused_one_is_named(tmp_path, fields, loop):
    stored = json.loads((STORED / "config_v2_paper.json").read_text())
    for name in ("rounds", "round_updates", "schedule"):
        del stored["iteration"][name]
    (tmp_path / "config.json").write_text(
        json.dumps({**stored, "iteration": {**stored["iteration"], **fields}})
    )
    assert load_config(tmp_path / "config.json").iteration.loop == loop
    refused = {**stored, "iteration": {**stored["iteration"], "schedule": "all_tasks"}}
    (tmp_path / "config.json").write_text(json.dumps(refused))
    with pytest.raises(
        ConfigError, match=r"config.json: .*rounds True and schedule 'all_tasks' are no training loop"
    ):
        load_config(tmp_path / "config.json")


@pytest.mark.parametrize(
    ("argv", "loop"),
    [
        (["--iteration.no-round-updates"], "rounds_chunked"),
        (["--preset", "intended", "--iteration.no-rounds"], "per_body"),
        (["--preset", "intended", "--iteration.no-rounds", "--iteration.schedule=all_tasks"], "all_tasks"),
        (["--preset", "intended", "--iteration.schedule", "original", "--iteration.round-updates"], "rounds"),
    ],
)
def test_the_old_loop_flags_are_read_for_one_release_with_a_line_saying_so(capsys, argv, loop):
    command, _ = parse_command(argv)
    assert command.iteration.loop == loop
    assert f"old names, read for one release; give --iteration.loop {loop} instead" in capsys.readouterr().err


def test_old_loop_flags_that_make_no_loop_are_refused_with_the_loops():
    with pytest.raises(
        ConfigError, match=r"rounds True and schedule 'all_tasks' are no training loop.*per_body"
    ):
        parse_command(["--iteration.schedule", "all_tasks"])


def test_a_config_json_of_a_newer_version_is_refused_with_both_versions():
    with pytest.raises(
        ConfigError, match=r"config_newer.json: format version 4 is newer than this swat_jax reads \(3\)"
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
