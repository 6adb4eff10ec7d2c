"""``mujoco.mjx``, imported on first use and without writing to standard output:
``from swat_jax.envs.quiet_mjx import mjx``.

Importing MJX takes about 1.5 s (it imports MuJoCo Warp's kernels when warp-lang is installed), which a
command on C physics (the CPU's default) never needs: ``mjx`` here is a stand-in that imports the module at
its first attribute read, so ``--help``, evaluation and export on C physics start without it.

mujoco-mjx 3.17 ``print``s "Failed to import warp: ..." and "Failed to import mujoco_warp: ..." to
standard output when its optional Warp backend is not installed, which would put those lines in front
of ``--help`` and into ``--json`` output. swat_jax needs Warp only for ``--envs.physics warp``, where
``envs/physics.py`` imports it and names the fix if it is missing, so those two notices are dropped;
anything else the import prints is passed on to standard error.
Every module of swat_jax imports MJX from here.
"""

from __future__ import annotations

import contextlib
import functools
import io
import sys
from types import ModuleType
from typing import TYPE_CHECKING, Any

WARP_NOTICES = ("Failed to import warp:", "Failed to import mujoco_warp:")
"""Starts of the lines mujoco.mjx prints when the optional Warp backend is missing."""


def forward_unexpected_lines(text: str) -> None:
    """Write the lines of ``text`` that are not Warp notices to standard error."""
    for line in text.splitlines():
        if not line.startswith(WARP_NOTICES):
            print(line, file=sys.stderr)


@functools.cache
def imported_mjx() -> ModuleType:
    """``mujoco.mjx``, imported once with its Warp notices dropped."""
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        from mujoco import mjx
    forward_unexpected_lines(captured.getvalue())
    return mjx


class _OnFirstUse:
    """Reads every attribute from :func:`imported_mjx`."""

    def __getattr__(self, name: str) -> Any:
        return getattr(imported_mjx(), name)


if TYPE_CHECKING:
    from mujoco import mjx
else:
    mjx = _OnFirstUse()

__all__ = ["imported_mjx", "mjx"]
