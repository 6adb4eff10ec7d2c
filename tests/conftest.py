"""Test-wide setup: the tests' own helpers (reference_numbers.py, mujoco_reference.py) are importable."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
