"""A Python function that programs call by name (:mod:`swat_jax.envs.named_callback`): what it receives,
what it returns, and how its errors come back."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.envs import named_callback

SEEN: list[dict] = []


def scale_and_count(args, results, attributes):
    """results: ``x * factor`` and each row's count of entries above ``floor``; records what it was given."""
    (x,) = args
    if attributes["mode"] == "fail":
        raise ValueError(f"no mode for {x.shape}")
    SEEN.append({"shape": x.shape, "dtype": x.dtype, **attributes})
    results[0][...] = x * attributes["factor"]
    results[1][...] = (x > 0.5).sum(axis=-1)


named_callback.register("test_scale_and_count", scale_and_count)


def scaled(x: jax.Array, mode: str = "scale") -> tuple[jax.Array, ...]:
    shapes = (jax.ShapeDtypeStruct(x.shape, x.dtype), jax.ShapeDtypeStruct((), jnp.int32))
    return named_callback.call("test_scale_and_count", shapes, x, mode=mode, factor=3)


def test_the_function_gets_the_vmapped_axes_and_its_attributes_and_fills_the_results():
    x = jnp.arange(24, dtype=jnp.float32).reshape(2, 3, 4) / 20
    SEEN.clear()
    product, count = jax.jit(jax.vmap(jax.vmap(scaled)))(x)
    (seen,) = SEEN
    assert seen == {"shape": (2, 3, 4), "dtype": np.float32, "mode": "scale", "factor": 3}, "one call"
    np.testing.assert_array_equal(product, x * 3)
    np.testing.assert_array_equal(count, (np.asarray(x) > 0.5).sum(axis=-1))
    assert count.dtype == jnp.int32


def test_an_exception_in_the_function_comes_back_with_the_target_and_its_message():
    with pytest.raises(Exception, match=r"test_scale_and_count: ValueError: no mode for \(3,\)"):
        jax.block_until_ready(jax.jit(lambda x: scaled(x, "fail"))(jnp.ones(3)))


def test_a_name_is_one_function():
    named_callback.register("test_scale_and_count", scale_and_count)  # again: nothing changes
    with pytest.raises(ValueError, match="'test_scale_and_count' is registered with another function"):
        named_callback.register("test_scale_and_count", lambda args, results, attributes: None)
