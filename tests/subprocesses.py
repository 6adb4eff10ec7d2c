"""The environment of the tests' Python subprocesses (one home for it, imported by the test modules)."""

from __future__ import annotations

import os
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
