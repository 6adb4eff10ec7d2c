"""Pieces shared by the command lines (render, train, eval, export, plot)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from typing import Any

ERROR_STATUS = 2
"""Exit status for a bad input: an option, a body, a run directory or a file name."""


def positive_int(text: str) -> int:
    """argparse type: a whole number of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive whole number, got {text}")
    return value


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
    parser: argparse.ArgumentParser,
    run: Callable[[argparse.Namespace], str | None],
    argv: Sequence[str] | None,
    errors: tuple[type[Exception], ...],
) -> int:
    """Parse ``argv``, call ``run`` and print the text it returns; returns the exit status.

    An exception of ``errors`` (bad input: a run directory, a body, an option) is printed as one
    ``error: ...`` line on standard error and gives ERROR_STATUS; anything else is a bug and raises.
    """
    args = parser.parse_args(argv)
    try:
        text = run(args)
    except errors as error:
        print(f"error: {error}", file=sys.stderr)
        return ERROR_STATUS
    if text is not None:
        print(text)
    return 0
