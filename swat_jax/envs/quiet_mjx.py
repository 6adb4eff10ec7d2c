"""``mujoco.mjx``, imported without writing to standard output: ``from swat_jax.envs.quiet_mjx import mjx``.

mujoco-mjx 3.17 ``print``s "Failed to import warp: ..." and "Failed to import mujoco_warp: ..." to
standard output when its optional Warp backend is not installed, which would put those lines in front
of ``--help`` and into ``--json`` output. swat_jax needs Warp only for ``--envs.physics warp``, where
``envs/physics.py`` imports it and names the fix if it is missing, so those two notices are dropped;
anything else the import prints is passed on to standard error.
Every module of swat_jax imports MJX from here.
"""

from __future__ import annotations

import contextlib
import io
import sys

WARP_NOTICES = ("Failed to import warp:", "Failed to import mujoco_warp:")
"""Starts of the lines mujoco.mjx prints when the optional Warp backend is missing."""


def forward_unexpected_lines(text: str) -> None:
    """Write the lines of ``text`` that are not Warp notices to standard error."""
    for line in text.splitlines():
        if not line.startswith(WARP_NOTICES):
            print(line, file=sys.stderr)


_captured = io.StringIO()
with contextlib.redirect_stdout(_captured):
    from mujoco import mjx
forward_unexpected_lines(_captured.getvalue())

__all__ = ["mjx"]
