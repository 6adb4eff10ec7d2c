"""Where the benchmark's MJCF files live: ``morphologies/`` at the root of the source checkout."""

from __future__ import annotations

from pathlib import Path

MORPHOLOGY_DIR = Path(__file__).resolve().parents[2] / "morphologies"
