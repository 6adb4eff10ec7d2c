"""A small training-state stand-in for the checkpoint tests (one home for it, imported by the test modules
and by tests/killed_save.py): saving and reading it needs no compiled program."""

from __future__ import annotations

import numpy as np

from swat_jax.runs.checkpoint import CheckpointInfo

STATE = {
    "weights": np.arange(4096, dtype=np.float32).reshape(64, 64),
    "replay": np.random.default_rng(0).standard_normal((256, 64)).astype(np.float32),
}
"""Arrays of two sizes; the replay's random values do not compress, so its file is the largest."""


def info_at(env_steps: int) -> CheckpointInfo:
    """The info of a checkpoint of STATE after ``env_steps`` steps."""
    return CheckpointInfo(
        env_steps, 1, 1.0, seeds=(0,), bodies=("hopper_3",), max_limbs=4, observation_features=19
    )
