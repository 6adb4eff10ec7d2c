"""The environment of the tests' Python subprocesses (one home for it, imported by the test modules)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def python_path_environment(*folders: str | Path, **variables: str) -> dict[str, str]:
    """This process's environment with ``folders`` put in front of ``PYTHONPATH`` and ``variables`` set.

    What ``PYTHONPATH`` held stays after the new folders: on a machine where the dependencies were
    installed with ``pip install --target DIR`` and found through ``PYTHONPATH=DIR``, replacing it would
    leave the subprocess without them.
    """
    entries = [str(folder) for folder in folders]
    if os.environ.get("PYTHONPATH"):
        entries.append(os.environ["PYTHONPATH"])
    return {**os.environ, **variables, "PYTHONPATH": os.pathsep.join(entries)}


def printed_words(script: str, environment: dict[str, str]) -> list[str]:
    """What ``python -c script`` prints, split into words, run in ``environment`` (fails if it fails)."""
    command = [sys.executable, "-c", script]
    return subprocess.run(command, capture_output=True, text=True, env=environment, check=True).stdout.split()
