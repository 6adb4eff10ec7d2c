"""A very short run of each preset and the numbers it ends with, pinned in ``tests/data/preset_pins.json``
(tests/test_preset_pins.py runs it in a subprocess and compares, within the tolerances it states).

Each run is its preset's code paths at toy sizes: two bodies of Hopper++ (hopper_3, hopper_5: two limb counts), one seed, a
one-layer width-16 network, a few iterations with a short random phase, MuJoCo C physics, an evaluation
at the end. Its numbers: the metrics rows as ``metrics.csv`` writes them (timing columns left out) and the
final actor's parameters (leaves in tree order, flattened).

The runs are compiled with the test suite's XLA flags and for AVX2 at most (``--xla_cpu_max_isa``),
whatever the caller's. The last bits still depend on the CPU (XLA tunes its code to the processor it
runs on), so two machines agree to a tolerance, and one machine, before and after a change, to the bit:
compare the printed JSON of two runs for a bit-for-bit check of a refactoring.

    python tests/preset_pins.py                 # print every preset's numbers
    python tests/preset_pins.py --write         # re-pin: write them to tests/data/preset_pins.json
    python tests/preset_pins.py --write --preset paper   # re-pin one preset
    python tests/preset_pins.py --preset fast   # one preset's numbers, as JSON (what the test reads)
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import json
import os
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np
from conftest import TEST_XLA_FLAGS

from swat_jax.runs.config import PRESETS, TrainConfig
from swat_jax.runs.metrics import CSV_FILE
from swat_jax.runs.trained import load_policy
from swat_jax.train import train

PIN_XLA_FLAGS = f"{TEST_XLA_FLAGS} --xla_cpu_max_isa=AVX2"
"""The XLA flags of the pinned runs, whatever the caller's (set before JAX starts its backend)."""
PINS = Path(__file__).parent / "data" / "preset_pins.json"
PINNED_PRESETS = ("paper", "fast")
"""The presets a pinned run is kept of."""
TIMING_COLUMNS = ("steps_per_second",)
"""Metrics columns that measure the machine, not the run."""


def pin_config(preset: str, run_dir: Path) -> TrainConfig:
    """The preset at toy sizes: every switch the preset's, only sizes, budget and intervals smaller."""
    base = PRESETS[preset]
    iteration = {"paper": dict(random_steps=50), "fast": dict(random_steps=32, updates=16)}[preset]
    return dataclasses.replace(
        base,
        env="hopper",
        bodies=("hopper_3", "hopper_5"),
        steps={"paper": 600, "fast": 1024}[preset],
        seeds=1,
        envs=dataclasses.replace(base.envs, physics="c"),
        network=dataclasses.replace(base.network, width=16, heads=2, layers=1, feedforward=32),
        iteration=dataclasses.replace(base.iteration, **iteration),
        log_interval=1,
        eval_interval=10**9,
        eval_episodes=1,
        checkpoint_interval=10**9,
        run_dir=str(run_dir),
    )


def run_numbers(preset: str) -> dict:
    """Train the preset's pinned run in a temporary directory; its metrics rows (as written, less the
    timing columns) and its final actor's parameters (one flat list per leaf, leaves in tree order)."""
    with tempfile.TemporaryDirectory() as directory:
        run_dir = Path(directory) / preset
        with contextlib.redirect_stdout(sys.stderr):  # standard output: the numbers alone
            train(pin_config(preset, run_dir), progress=False)
        with (run_dir / CSV_FILE).open(newline="") as file:
            rows = [
                {column: value for column, value in row.items() if column not in TIMING_COLUMNS}
                for row in csv.DictReader(file)
            ]
        leaves = jax.tree_util.tree_leaves(load_policy(run_dir).params)
    return {"metrics": rows, "actor": [np.asarray(leaf, np.float64).ravel().tolist() for leaf in leaves]}


def main() -> None:
    """Print (or write) the pinned numbers of the presets the command line asks for."""
    os.environ["XLA_FLAGS"] = PIN_XLA_FLAGS
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", choices=PINNED_PRESETS, help="print one preset's numbers as JSON")
    parser.add_argument("--write", action="store_true", help=f"write every preset's numbers to {PINS}")
    arguments = parser.parse_args()
    presets = (arguments.preset,) if arguments.preset else PINNED_PRESETS
    numbers = {preset: run_numbers(preset) for preset in presets}
    if arguments.write:
        pinned = json.loads(PINS.read_text()) if PINS.exists() else {}
        PINS.write_text(json.dumps({**pinned, **numbers}, indent=1) + "\n")
    print(json.dumps(numbers[arguments.preset] if arguments.preset else numbers))


if __name__ == "__main__":
    main()
