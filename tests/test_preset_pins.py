"""A short run of each preset gives the numbers pinned in tests/data/preset_pins.json, to a tolerance that
the CPU's last bits stay inside and a change of what a preset computes does not.

The guard of refactorings: a change that should not change what a preset computes leaves these numbers
as they are (every metrics row as written, the final actor's parameters). When an issue changes a preset
on purpose, it re-pins them, and says so in its commit:

    python tests/preset_pins.py --write

Measured (2-core AMD EPYC, Zen 3 without AVX-512, against pins written on an EPYC with AVX-512, and
against the same run compiled for SSE4.2): the CPU moves a metric by at most 7e-4 of its value (the
`fast` run's twin-critic gap, a small difference of two estimates) and a parameter by 2e-6; tau 1% higher
moves a metric of the `paper` run by six times METRIC_RTOL and the `fast` run's by two hundred times.
(tests/preset_pins.py: the runs, their XLA flags, and what is pinned.)
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from subprocesses import python_path_environment

TESTS = Path(__file__).parent
PINS = json.loads((TESTS / "data" / "preset_pins.json").read_text())
"""Each pinned preset's numbers, written by ``python tests/preset_pins.py --write``."""
METRIC_RTOL, METRIC_ATOL = 2e-3, 1e-5
"""A numeric metrics cell agrees when ``|now - pinned| <= METRIC_ATOL + METRIC_RTOL * |pinned|``."""
PARAMETER_ATOL = 1e-4
"""A parameter of the final actor agrees when it is within this of its pinned value."""


def changed_cells(row: dict[str, str], pinned: dict[str, str]) -> dict[str, tuple[str, str]]:
    """The cells of a metrics row that differ from the pinned row's: numbers beyond the tolerance, other
    text at all; ``{column: (now, pinned)}``."""
    changed = {}
    for column, expected in pinned.items():
        try:
            now, then = float(row[column]), float(expected)
        except ValueError:
            agrees = row[column] == expected
        else:
            agrees = abs(now - then) <= METRIC_ATOL + METRIC_RTOL * abs(then)
        if not agrees:
            changed[column] = (row[column], expected)
    return changed


@pytest.mark.parametrize(
    ("now", "agrees"), [("0.615873", True), ("0.616", True), ("0.6172", False), ("nan", False), ("0", False)]
)
def test_a_metrics_cell_agrees_within_the_tolerance_only(now, agrees):
    assert (changed_cells({"loss": now}, {"loss": "0.615874"}) == {}) is agrees


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
        changed = changed_cells(got, expected)
        assert not changed, f"metrics row {row}: (now, pinned) {changed}"
    for leaf, (got, expected) in enumerate(zip(numbers["actor"], pinned["actor"], strict=True)):
        assert len(got) == len(expected), f"the final actor's leaf {leaf} has another size"
        difference = np.max(np.abs(np.subtract(got, expected)))
        assert difference <= PARAMETER_ATOL, f"the final actor's leaf {leaf} moved by {difference:.3g}"
