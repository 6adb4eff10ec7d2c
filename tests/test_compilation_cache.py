"""The persistent compilation cache is off until ``swat_jax.enable_caches()`` (which every command calls),
then per user, can be moved and turned off; the program cache loads a run's compiled programs without tracing them, in this process or another, and only when
nothing they are traced from has changed."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MORPHOLOGIES, tiny_train_config
from subprocesses import printed_words

from swat_jax import compilation_cache
from swat_jax.compilation_cache import CacheSettingError, compile_cached
from swat_jax.envs.multi_task import MultiTaskEnv
from swat_jax.runs.programs import recipe as program_recipe
from swat_jax.td3.learner import TD3Config

PROBE = """
import {first}, {second}
import jax.numpy as jnp
print(jax.config.jax_compilation_cache_dir, end=" ")
swat_jax.enable_caches()
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
def test_import_leaves_the_cache_off_and_enable_caches_fills_it(tmp_path, imports):
    directory = tmp_path / "xdg" / "swat_jax" / "jax"
    assert run_probe(tmp_path, *imports) == f"None {directory}"
    assert any(directory.iterdir()), "the jitted probe left no cache entry"


def test_cache_directory_can_be_moved(tmp_path):
    assert (
        run_probe(tmp_path, SWAT_JAX_CACHE_DIR=str(tmp_path / "elsewhere"))
        == f"None {tmp_path / 'elsewhere'}"
    )


def test_cache_can_be_turned_off(tmp_path):
    assert run_probe(tmp_path, SWAT_JAX_COMPILATION_CACHE="0") == "None None"
    assert not (tmp_path / "xdg" / "swat_jax").exists()


class Probe:
    """A jitted function that counts its traces: ``build`` for :func:`compile_cached`."""

    def __init__(self, scale: float = 2.0):
        self.scale, self.traces = scale, 0

    def build(self):
        def function(x):
            self.traces += 1
            return jnp.linalg.cholesky(x @ x.T + jnp.eye(x.shape[0])) * self.scale

        return jax.jit(function)


@pytest.fixture
def program_cache(tmp_path, monkeypatch):
    """The program cache in a fresh directory, every call as in a fresh process (nothing kept in memory);
    returns the directory its programs go to."""
    monkeypatch.setattr(compilation_cache, "IN_MEMORY_PROGRAMS", 0)
    monkeypatch.setenv("SWAT_JAX_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.delenv("SWAT_JAX_COMPILATION_CACHE", raising=False)
    return tmp_path / "cache" / compilation_cache.PROGRAMS


def test_a_saved_program_is_loaded_without_tracing(program_cache):
    x = jnp.arange(12.0).reshape(4, 3) / 10
    first, second = Probe(), Probe()
    expected = compile_cached("probe", first.build, (x,), ("recipe",))(x)
    loaded = compile_cached("probe", second.build, (x,), ("recipe",))
    assert (first.traces, second.traces) == (1, 0)
    np.testing.assert_array_equal(loaded(x), expected)
    assert len(list(program_cache.iterdir())) == 1


def test_a_process_traces_a_program_once_even_when_it_is_not_saved(program_cache, monkeypatch):
    """JAX's own cache may give a program that is then not saved; the process keeps it all the same, the
    most recently used IN_MEMORY_PROGRAMS of them."""
    monkeypatch.setattr(compilation_cache, "IN_MEMORY_PROGRAMS", 2)
    monkeypatch.setattr(compilation_cache, "_save_program", lambda *args: None)
    x = jnp.ones((4, 3))

    def traces(recipe: str) -> int:
        probe = Probe()
        compile_cached("probe", probe.build, (x,), (recipe,))
        return probe.traces

    assert [traces("first"), traces("first"), traces("second"), traces("first")] == [1, 0, 1, 0]
    assert traces("third") == 1
    assert traces("second") == 1, "the least recently used of 2 programs was dropped"
    assert not program_cache.exists()


def test_another_recipe_or_argument_is_another_program(program_cache):
    x = jnp.ones((4, 3))
    probe = Probe()
    compile_cached("probe", probe.build, (x,), ("recipe",))
    compile_cached("probe", probe.build, (x,), ("another recipe",))
    compile_cached("probe", probe.build, (jnp.ones((5, 3)),), ("recipe",))
    compile_cached("probe", probe.build, (jnp.ones((4, 3), jnp.float16),), ("recipe",))
    assert probe.traces == 4
    assert len(list(program_cache.iterdir())) == 4


def test_an_unreadable_program_is_compiled_again(program_cache, capsys):
    x = jnp.ones((4, 3))
    compile_cached("probe", Probe().build, (x,), ("recipe",))
    (path,) = program_cache.iterdir()
    path.write_bytes(b"truncated")
    probe = Probe()
    np.testing.assert_allclose(compile_cached("probe", probe.build, (x,), ("recipe",))(x), Probe().build()(x))
    assert probe.traces == 1
    assert f"ignoring the unreadable cached program {path}" in capsys.readouterr().err
    reloaded = Probe()
    compile_cached("probe", reloaded.build, (x,), ("recipe",))
    assert reloaded.traces == 0, "the unreadable program was not replaced"


def test_programs_that_call_into_this_process_are_not_saved(program_cache):
    def build():
        return jax.jit(lambda x: jax.pure_callback(np.sin, jax.ShapeDtypeStruct(x.shape, x.dtype), x))

    x = jnp.ones(3)
    np.testing.assert_allclose(compile_cached("callback", build, (x,), ("recipe",))(x), np.sin(1.0))
    traced = jax.jit(lambda x: x + 1)
    traced(x)
    probe = Probe()
    compile_cached("probe", probe.build, (jnp.ones((2, 2)),), None)
    assert probe.traces == 1
    assert not program_cache.exists() or not any(program_cache.iterdir())
    assert traced._cache_size() == 1, "a program no cache holds is lowered without clearing JAX's caches"


def test_the_program_cache_is_off_with_the_compilation_cache(program_cache, monkeypatch):
    monkeypatch.setenv("SWAT_JAX_COMPILATION_CACHE", "0")
    probe, x = Probe(), jnp.ones((2, 2))
    compile_cached("probe", probe.build, (x,), ("recipe",))
    compile_cached("probe", probe.build, (x,), ("recipe",))
    assert probe.traces == 2
    assert not program_cache.exists()


def test_the_program_cache_keeps_nothing_before_enable_caches(program_cache, monkeypatch):
    """Nor does it clear JAX's in-memory caches, which belong to the library user's whole process (with the
    caches on, lowering as a fresh process would clears them)."""
    monkeypatch.setattr(compilation_cache, "_programs_enabled", False)
    users = jax.jit(lambda x: x + 1)
    users(jnp.ones(2))
    probe, x = Probe(), jnp.ones((2, 2))
    compile_cached("probe", probe.build, (x,), ("recipe",))
    compile_cached("probe", probe.build, (x,), ("recipe",))
    assert probe.traces == 2
    assert not program_cache.exists()
    assert users._cache_size() == 1, "the user's compiled function was dropped"
    monkeypatch.setattr(compilation_cache, "_programs_enabled", True)
    compile_cached("probe", probe.build, (x,), ("recipe",))
    assert users._cache_size() == 0


def test_the_least_recently_used_programs_go_when_the_cache_is_full(program_cache, monkeypatch):
    x = jnp.ones((4, 3))

    def compile_probe(recipe: str) -> Probe:
        probe = Probe()
        compile_cached("probe", probe.build, (x,), (recipe,))
        return probe

    compile_probe("first")
    (first,) = program_cache.iterdir()
    compile_probe("second")
    (second,) = set(program_cache.iterdir()) - {first}
    assert compile_probe("first").traces == 0
    assert first.stat().st_mtime_ns > second.stat().st_mtime_ns, (
        "loading a program within one kernel clock tick of saving another left them tied"
    )
    largest = max(path.stat().st_size for path in program_cache.iterdir())
    monkeypatch.setenv("SWAT_JAX_PROGRAM_CACHE_GIB", str(2.5 * largest / 2**30))
    compile_probe("third")
    assert len(list(program_cache.iterdir())) == 2, "a program over the limit was kept"
    assert first.exists(), "the recently loaded program was evicted instead of the least recently used"
    assert compile_probe("second").traces == 1
    assert compile_probe("third").traces == 0


@pytest.mark.parametrize("size", ["-1", "two", "nan"])
def test_a_bad_size_limit_names_the_variable_and_the_fix(program_cache, monkeypatch, size):
    monkeypatch.setenv("SWAT_JAX_PROGRAM_CACHE_GIB", size)
    with pytest.raises(
        CacheSettingError, match=rf"SWAT_JAX_PROGRAM_CACHE_GIB='{size}' is not a size in GiB.*unset"
    ):
        compile_cached("probe", Probe().build, (jnp.ones((2, 2)),), ("recipe",))


FRESH_PROCESS = """
import sys
import jax.numpy as jnp
sys.path.insert(0, {tests!r})
from test_compilation_cache import Probe
from swat_jax.compilation_cache import CacheSettingError, compile_cached
probe = Probe()
x = jnp.arange(12.0).reshape(4, 3) / 10
print(compile_cached("probe", probe.build, (x,), ("recipe",))(x).sum(), probe.traces)
"""


def test_a_program_saved_by_one_process_runs_in_another(program_cache):
    """The loading process has lowered nothing: the program's LAPACK calls (a Cholesky factorisation) find
    their kernels set up all the same (without that, the process crashes). Of the process's 2 devices the
    loaded program runs on the one it was compiled for (by default, JAX would load it onto both). A program
    that JAX's own cache gave is not saved: jax 0.10.2 saves such an executable without some of its
    kernels."""
    script = textwrap.dedent(FRESH_PROCESS.format(tests=str(Path(__file__).parent)))
    environment = {
        **os.environ,
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2",
    }

    def run() -> list[str]:
        return printed_words(script, environment)

    compiled, loaded = run(), run()
    assert (compiled[-1], loaded[-1]) == ("1", "0"), "traces: the second process traced again"
    assert loaded[0] == compiled[0]
    shutil.rmtree(program_cache)
    from_jax_cache = run()
    assert from_jax_cache == compiled
    assert not program_cache.exists() or not any(program_cache.iterdir())


def test_a_runs_recipe_holds_what_its_programs_are_traced_from(tmp_path, hopper_folder):
    """Where, how long and from which seed a run goes does not change its programs; its hyperparameters,
    seed count and bodies' physics do."""
    config = tiny_train_config(tmp_path / "run", hopper_folder)
    env = MultiTaskEnv(["hopper_3"], config.envs.copies)
    recipe = program_recipe(config, env)
    host_only = dataclasses.replace(
        config, run_dir=str(tmp_path / "other"), env="hopper", seed=7, steps=10**6, eval_interval=0
    )
    assert program_recipe(host_only, env) == recipe
    assert program_recipe(dataclasses.replace(config, seeds=3), env) != recipe
    assert program_recipe(dataclasses.replace(config, td3=TD3Config(batch_size=8)), env) != recipe
    assert program_recipe(config, MultiTaskEnv(["hopper_3"], config.envs.copies + 1)) != recipe
    on_c = program_recipe(config, MultiTaskEnv(["hopper_3"], config.envs.copies, physics="c"))
    assert on_c is not None and on_c != recipe, "C physics programs are kept, apart from MJX's"
    body = tmp_path / "hopper_3.xml"
    (tmp_path / "assets").symlink_to(MORPHOLOGIES / "assets")
    original = (MORPHOLOGIES / "hopper_3.xml").read_text()
    body.write_text(original)
    before = program_recipe(config, MultiTaskEnv([str(body)], config.envs.copies))
    body.write_text(original.replace('friction="0.9 0.005 0.0001"', 'friction="0.5 0.005 0.0001"', 1))
    assert body.read_text() != original, "the edit did not apply"
    assert program_recipe(config, MultiTaskEnv([str(body)], config.envs.copies)) != before, (
        "same morphology, other physics"
    )
