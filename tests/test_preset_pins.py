"""A short run of each preset gives, bit for bit, the numbers pinned in tests/data/preset_pins.json.

The guard of refactorings: a change that should not change what a preset computes leaves these numbers
as they are (every metrics row as written, the final actor's parameters to the bit). When an issue
changes a preset on purpose, it re-pins them, and says so in its commit:

    python tests/preset_pins.py --write

(tests/preset_pins.py: the runs, their XLA flags, and what is pinned.)
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from subprocesses import python_path_environment

TESTS = Path(__file__).parent
PINS = json.loads((TESTS / "data" / "preset_pins.json").read_text())
"""Each pinned preset's numbers, written by ``python tests/preset_pins.py --write``."""


@pytest.mark.slow
@pytest.mark.parametrize("preset", sorted(PINS))
def test_a_short_run_of_the_preset_gives_its_pinned_numbers(preset):
    """In a fresh process, so the XLA flags are the pins' own (tests/preset_pins.py)."""
    result = subprocess.run(
        [sys.executable, str(TESTS / "preset_pins.py"), "--preset", preset],
        capture_output=True,
        text=True,
        env=python_path_environment(TESTS.parent),
        check=False,
    )
    assert result.returncode == 0, result.stderr
    numbers, pinned = json.loads(result.stdout), PINS[preset]
    for row, (got, expected) in enumerate(zip(numbers["metrics"], pinned["metrics"], strict=True)):
        assert got.keys() == expected.keys(), f"metrics row {row}: other columns"
        changed = {column: (got[column], value) for column, value in expected.items() if got[column] != value}
        assert not changed, f"metrics row {row}: (now, pinned) {changed}"
    assert numbers["actor_sha256"] == pinned["actor_sha256"], "the final actor's parameters changed"
