"""Pieces shared by the command lines (render, train, eval, export)."""

from __future__ import annotations

import argparse

ERROR_STATUS = 2
"""Exit status for a bad input: an option, a body, a run directory or a file name."""


def positive_int(text: str) -> int:
    """argparse type: a whole number of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive whole number, got {text}")
    return value
