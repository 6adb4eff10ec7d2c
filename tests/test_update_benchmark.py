"""experiments/update_benchmark.py: the FLOP count it divides by time is XLA's count of the program."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

from update_benchmark import compiled_flops, matmul_ceiling


def test_flops_of_a_matmul_are_two_n_cubed():
    a = jnp.ones((64, 64), jnp.float32)
    compiled = jax.jit(lambda x: x @ x).lower(a).compile()
    assert compiled_flops(compiled) == 2 * 64**3


def test_matmul_ceiling_is_a_rate():
    assert 1e6 < matmul_ceiling(size=256, repeats=2) < 1e16
