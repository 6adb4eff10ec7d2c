"""experiments/benchmarks/update.py: the FLOP count it divides by time is XLA's count of the program, and the
PyTorch reference (SWAT's update) is given a FLOP rate only beside SWAT."""

import jax
import jax.numpy as jnp

from experiments.benchmarks.update import compiled_flops, matmul_ceiling, reference_report


def test_flops_of_a_matmul_are_two_n_cubed():
    a = jnp.ones((64, 64), jnp.float32)
    compiled = jax.jit(lambda x: x @ x).lower(a).compile()
    assert compiled_flops(compiled) == 2 * 64**3


def test_matmul_ceiling_is_a_rate():
    assert 1e6 < matmul_ceiling(size=256, repeats=2) < 1e16


def test_the_reference_gets_a_flop_rate_only_beside_swat():
    result = {"transitions_per_second": 1500.0, "tasks": 5, "useful_gflop": 40.0}
    swat = reference_report(1000.0, "swat", result, batch=100, ceiling=200.0)
    assert swat == (
        "reference: 1,000 transitions/s, 80 useful GFLOP/s (40% of the ceiling); vmapped / reference: 1.50x"
    )
    smp = reference_report(1000.0, "smp", {**result, "useful_gflop": 16.0}, batch=100, ceiling=200.0)
    assert smp == "reference (PyTorch SWAT): 1,000 transitions/s; vmapped / reference: 1.50x"
