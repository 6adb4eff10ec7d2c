"""Run by tests/test_train.py: ``python -m swat_jax.train ARGS`` whose checkpoint writes never end. A write
prints WRITE_BEGAN and waits forever, so a signal sent after that line arrives while a checkpoint is being
written, however fast the machine.

    python tests/blocked_save_train.py ARGS
"""

from __future__ import annotations

import sys
import threading

from swat_jax import train
from swat_jax.runs.checkpoint import Checkpoints

WRITE_BEGAN = "checkpoint write began"


def blocked_save(*args, **kwargs) -> None:
    print(WRITE_BEGAN, flush=True)
    threading.Event().wait()


if __name__ == "__main__":
    Checkpoints.save = blocked_save
    sys.exit(train.main(sys.argv[1:]))
