"""Pieces shared by the command lines (train, eval, export, plot, render, morphology, convert)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Sequence
from typing import Any

import tyro

ERROR_STATUS = 2
"""Exit status for a bad input: an option, a body, a run directory or a file name."""


def strict_json(value: Any, indent: int | None = None) -> str:
    """``value`` as standard JSON: a NaN or infinite number (an undefined statistic, such as the standard
    error of one seed) becomes ``null``, which every JSON reader accepts (``json.dumps`` would write ``NaN``).
    NumPy scalars are written as the numbers they hold."""

    def plain(item: Any) -> Any:
        if isinstance(item, dict):
            return {key: plain(entry) for key, entry in item.items()}
        if isinstance(item, (list, tuple)):
            return [plain(entry) for entry in item]
        if hasattr(item, "item") and callable(item.item) and getattr(item, "shape", None) == ():
            item = item.item()
        if isinstance(item, float) and not math.isfinite(item):
            return None
        return item

    return json.dumps(plain(value), indent=indent, allow_nan=False)


def run_command(
    command_type: Any,
    run: Callable[[Any], str | None],
    argv: Sequence[str] | None,
    errors: tuple[type[Exception], ...],
    *,
    prog: str,
) -> int:
    """Parse ``argv`` into ``command_type`` with tyro (a frozen dataclass whose fields' docstrings are the
    ``--help`` lines, or a union of them for subcommands), call ``run`` on it and print the text it returns;
    returns the exit status.

    An exception of ``errors`` (bad input: a run directory, a body, an option's value), raised while the
    command is built or run, is printed as one ``error: ...`` line on standard error and gives
    ERROR_STATUS; anything else is a bug and raises. An unknown option exits with ERROR_STATUS from tyro.
    """
    try:
        text = run(tyro.cli(command_type, args=argv, prog=prog))
    except errors as error:
        print(f"error: {error}", file=sys.stderr)
        return ERROR_STATUS
    if text is not None:
        print(text)
    return 0
