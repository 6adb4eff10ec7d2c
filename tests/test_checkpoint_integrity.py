"""A checkpoint is read only after the record of what its save wrote checks out: truncated, deleted, changed
and unfinished checkpoints are refused with the reason before Orbax opens anything, and a resume sets them
aside and continues from the newest intact one. (The resume of a training run from a damaged checkpoint is
in test_train.py.)"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from checkpoint_states import STATE, info_at
from subprocesses import python_path_environment

from swat_jax.runs.checkpoint import DAMAGED_DIR, CheckpointError, Checkpoints
from swat_jax.runs.integrity import RECORD, damage

TESTS = Path(__file__).parent


@pytest.fixture
def two_checkpoints(tmp_path) -> Path:
    """A run directory with intact checkpoints 100 and 200 of STATE."""
    checkpoints = Checkpoints(tmp_path)
    for steps in (100, 200):
        checkpoints.save(STATE, {"actor": STATE}, info_at(steps))
    checkpoints.close()
    return tmp_path


def largest_file(folder: Path) -> Path:
    return max((path for path in folder.rglob("*") if path.is_file()), key=lambda path: path.stat().st_size)


def truncate(folder: Path) -> str:
    path = largest_file(folder / "state")
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    return path.relative_to(folder).as_posix()


def delete(folder: Path) -> str:
    path = largest_file(folder / "state")
    path.unlink()
    return path.relative_to(folder).as_posix()


def flip_byte(folder: Path) -> str:
    """One bit of the middle byte of the largest array file, as a disk or copy error would."""
    path = largest_file(folder / "state")
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    return path.relative_to(folder).as_posix()


DAMAGES = {
    truncate: "has {size} bytes where",
    delete: "is missing",
    flip_byte: "changed after it was written",
}


def test_a_completed_save_records_every_file_and_checks_out(two_checkpoints):
    folder = two_checkpoints / "checkpoints" / "200"
    record = json.loads((folder / RECORD).read_text())
    files = {path.relative_to(folder).as_posix() for path in folder.rglob("*") if path.is_file()}
    assert set(record["files"]) == files - {RECORD}
    assert damage(folder) is None
    checkpoints = Checkpoints(two_checkpoints)
    assert checkpoints.set_aside_damaged() == []
    assert np.array_equal(checkpoints.restore_item("actor", STATE)["replay"], STATE["replay"])
    checkpoints.close()


@pytest.mark.parametrize("damaging", list(DAMAGES), ids=lambda function: function.__name__)
def test_a_damaged_checkpoint_is_refused_before_anything_is_read(two_checkpoints, damaging, monkeypatch):
    newest = two_checkpoints / "checkpoints" / "200"
    name = damaging(newest)
    size = (newest / name).stat().st_size if (newest / name).exists() else 0
    checkpoints = Checkpoints(two_checkpoints)
    monkeypatch.setattr(checkpoints.manager, "restore", lambda *args, **kwargs: pytest.fail("Orbax read"))
    with pytest.raises(CheckpointError) as raised:
        checkpoints.restore(STATE, jax_shardings(STATE))
    message = str(raised.value)
    assert "\n" not in message and len(message) < 400, message
    assert message.startswith(f"{newest} is damaged: ")
    assert name in message and DAMAGES[damaging].format(size=f"{size:,}") in message
    assert "--resume" in message


def test_a_resume_sets_damaged_checkpoints_aside_and_continues_from_the_newest_intact_one(two_checkpoints):
    flipped = flip_byte(two_checkpoints / "checkpoints" / "200")
    checkpoints = Checkpoints(two_checkpoints)
    lines = checkpoints.set_aside_damaged()
    aside = two_checkpoints / DAMAGED_DIR / "200"
    assert lines == [
        f"refused {two_checkpoints / 'checkpoints' / '200'}: the bytes of {flipped} changed after it was "
        f"written; moved to {aside}"
    ]
    assert aside.is_dir() and checkpoints.latest_step() == 100
    state, info = checkpoints.restore(STATE, jax_shardings(STATE))
    assert info.env_steps == 100 and np.array_equal(state["replay"], STATE["replay"])
    checkpoints.save(STATE, {"actor": STATE}, info_at(200))
    assert checkpoints.latest_step() == 200 and damage(two_checkpoints / "checkpoints" / "200") is None
    checkpoints.close()


def test_no_intact_checkpoint_is_one_error_and_nothing_is_moved(two_checkpoints):
    for steps in ("100", "200"):
        truncate(two_checkpoints / "checkpoints" / steps)
    checkpoints = Checkpoints(two_checkpoints)
    with pytest.raises(CheckpointError, match=r"no intact checkpoint in .*\(200: .*; 100: .*--overwrite"):
        checkpoints.set_aside_damaged()
    checkpoints.close()
    assert not (two_checkpoints / DAMAGED_DIR).exists()


def test_a_damaged_state_does_not_stop_a_policy_being_read_from_the_same_checkpoint(two_checkpoints):
    """eval and export read the actor alone: only its files are hashed (every file's size is checked)."""
    flip_byte(two_checkpoints / "checkpoints" / "200")
    checkpoints = Checkpoints(two_checkpoints)
    assert np.array_equal(checkpoints.restore_item("actor", STATE)["weights"], STATE["weights"])
    assert checkpoints.info().env_steps == 200
    checkpoints.close()


@pytest.mark.parametrize(
    ("where", "reason"),
    [("orbax", "its save never finished"), ("record", f"it has no {RECORD}: its save never finished")],
)
def test_a_save_killed_midway_is_refused_and_the_previous_checkpoint_resumes(tmp_path, where, reason):
    """kill -9 during the save of checkpoint 200: before Orbax's commit, or after it and before the record."""
    killed = subprocess.run(
        [sys.executable, str(TESTS / "killed_save.py"), str(tmp_path), where],
        env=python_path_environment(TESTS),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert killed.returncode == -9, killed.stderr[-2000:]
    checkpoints = Checkpoints(tmp_path)
    [line] = checkpoints.set_aside_damaged()
    assert line.startswith(f"refused {tmp_path / 'checkpoints'}/200") and f": {reason}" in line
    assert checkpoints.latest_step() == 100
    state, info = checkpoints.restore(STATE, jax_shardings(STATE))
    assert info.env_steps == 100 and np.array_equal(state["weights"], STATE["weights"])
    checkpoints.close()
    assert [path.name.split(".")[0] for path in (tmp_path / DAMAGED_DIR).iterdir()] == ["200"]


def jax_shardings(tree):
    import jax

    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    return jax.tree_util.tree_map(lambda _: device, tree)
