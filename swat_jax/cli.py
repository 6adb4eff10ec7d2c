"""Pieces shared by the command lines (render, train, eval, export, plot)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

ERROR_STATUS = 2
"""Exit status for a bad input: an option, a body, a run directory or a file name."""


def positive_int(text: str) -> int:
    """argparse type: a whole number of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive whole number, got {text}")
    return value


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
