"""The persistent compilation cache is on by default, per user, can be moved and turned off."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

PROBE = """
import {first}, {second}
import jax.numpy as jnp
print(jax.config.jax_compilation_cache_dir)
jax.jit(lambda x: jnp.sin(x) * 2)(jnp.ones(3)).block_until_ready()
"""


def run_probe(tmp_path, first="jax", second="swat_jax", **env) -> str:
    environment = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "SWAT_JAX_"))}
    environment.update(
        XDG_CACHE_HOME=str(tmp_path / "xdg"), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", **env
    )
    result = subprocess.run(
        [sys.executable, "-c", PROBE.format(first=first, second=second)],
        env=environment,
        capture_output=True,
        text=True,
        check=True,
    )
    return result.stdout.strip()


@pytest.mark.parametrize("imports", [("jax", "swat_jax"), ("swat_jax", "jax")])
def test_cache_is_on_by_default_and_filled(tmp_path, imports):
    directory = tmp_path / "xdg" / "swat_jax" / "jax"
    assert run_probe(tmp_path, *imports) == str(directory)
    assert any(directory.iterdir()), "the jitted probe left no cache entry"


def test_cache_directory_can_be_moved(tmp_path):
    assert run_probe(tmp_path, SWAT_JAX_CACHE_DIR=str(tmp_path / "elsewhere")) == str(tmp_path / "elsewhere")


def test_cache_can_be_turned_off(tmp_path):
    assert run_probe(tmp_path, SWAT_JAX_COMPILATION_CACHE="0") == "None"
    assert not (tmp_path / "xdg" / "swat_jax").exists()
