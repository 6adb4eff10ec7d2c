"""Run by tests/test_checkpoint_integrity.py: save checkpoint 100 of a small state, then die by SIGKILL in
the middle of saving checkpoint 200, at a point chosen on the command line, as a kill -9 would:

    python tests/killed_save.py RUN_DIR orbax    # every array written, Orbax's rename to 200/ not done
    python tests/killed_save.py RUN_DIR record   # Orbax's save done, its record not yet written

The kill is sent by the process to itself from inside the write, so where it lands does not depend on
timing. The process never exits normally.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from checkpoint_states import STATE, info_at
from orbax.checkpoint._src.path import async_path

from swat_jax.runs import checkpoint
from swat_jax.runs.checkpoint import Checkpoints


def die(*args, **kwargs) -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def main(run_dir: Path, where: str) -> None:
    checkpoints = Checkpoints(run_dir)
    checkpoints.save(STATE, {"actor": STATE}, info_at(100))
    if where == "orbax":
        async_path.rename = die
    else:
        checkpoint.write_record = die
    checkpoints.save(STATE, {"actor": STATE}, info_at(200))
    print("the save of 200 finished", file=sys.stderr)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2])
