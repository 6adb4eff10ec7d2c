"""Test-wide setup: the tests' own helpers are importable; XLA compiles without backend optimisations; a tiny
training run shared by the command tests."""

import os
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

TEST_XLA_FLAGS = (
    "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"
    " --xla_disable_hlo_passes=while-loop-invariant-code-motion"
)
"""Compile time dominates the suite. With LLVM's optimisations, XLA's new CPU fusion emitters and its
loop-invariant code motion off (the last is a third of an MJX program's HLO passes), XLA compiles the
tests' programs (the programs users run, lowered the same way) in about a third of the CPU time, and runs
them 2-3x slower, which the tests' few steps do not feel (BENCHMARKS.md, "The test suite"). Set before
JAX starts its backend; the tests' subprocesses inherit it."""
USER_XLA_FLAGS = os.environ.get("XLA_FLAGS", "").replace(TEST_XLA_FLAGS, "").strip()
"""The XLA flags the suite was started with, for the tests that run with XLA's defaults (test_learning.py)."""
os.environ["XLA_FLAGS"] = f"{USER_XLA_FLAGS} {TEST_XLA_FLAGS}".strip()
XLA_DEFAULTS = {
    "xla_backend_optimization_level": 3,
    "xla_cpu_use_fusion_emitters": True,
    "xla_disable_hlo_passes": "",
}
"""``jax.jit(..., compiler_options=XLA_DEFAULTS)`` undoes TEST_XLA_FLAGS for one program: for the tests whose
programs run for seconds (thousands of updates), which run 3x faster compiled with XLA's defaults."""

from swat_jax import enable_caches  # noqa: E402 (after XLA_FLAGS: importing swat_jax may import jax)

enable_caches()
"""The tests compile as the commands do: with the persistent compilation cache and the program cache."""


WORKER_GROUPS = {
    **dict.fromkeys(
        (
            "test_train",
            "test_eval",
            "test_cli_output",
            "test_export",
            "test_onnx_export",
            "test_plot",
            "test_run_errors",
            "test_specialists",
        ),
        "tiny runs",
    ),
    "test_sharding": "sharded twins",
    "test_td3_iteration": "test_td3_iteration",
    "test_render": "test_render",
    "test_networks": "test_networks",
    "test_env_against_mujoco": "test_env_against_mujoco",
}
"""Modules whose tests run on one xdist worker under ``make test`` (``--dist loadgroup``), so that the
fixtures they share are built once: the tiny runs (``trained_run``, ``trained_swat_run``: a training
each), the sharded twins (a 4-minute subprocess) and the module-scoped fixtures. Every other test is
scheduled on its own. (pytest-xdist 3.8's ``xdist_group`` mark groups nothing under pytest 9.2: it renames
node ids through an attribute pytest 9 no longer reads, so the grouping is done here.)"""


def pytest_collection_modifyitems(items):
    """The tests marked ``slow`` first, the others after them, each set in file order. Under ``make test``
    xdist hands out the groups of :data:`WORKER_GROUPS` first (largest first), then every other test in this
    order: the long tests start early and the short ones fill the end, where a long one would leave the other
    worker idle."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup`` schedules by :data:`WORKER_GROUPS`; largest groups first."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class WorkerGroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = Path(nodeid.split("::", 1)[0]).stem
            return WORKER_GROUPS.get(module, nodeid)

    return WorkerGroupScheduling(config, log)


MORPHOLOGIES = Path(__file__).resolve().parents[1] / "morphologies"


def tiny_train_config(run_dir: Path, env_dir: Path, network=None, envs=None, **overrides):
    """A run small enough for CI: hopper_3 alone, 2 seeds in one program, 2 copies in the paper preset's
    lock-step rounds, a 1-layer AMORPHEUS of width 16, evaluated (2 episodes) at 400 steps and at the end.
    ``network`` and ``envs``: fields of those groups to change (a dict), the rest as given."""
    from swat_jax.runs.config import EnvConfig, NetworkSizes, TrainConfig
    from swat_jax.td3.iteration import IterationConfig
    from swat_jax.td3.learner import TD3Config

    fields = dict(
        env=str(env_dir),
        algo="amorpheus",
        steps=600,
        seeds=2,
        envs=EnvConfig(**{"copies": 2, **(envs or {})}),
        iteration=IterationConfig(chunk=50, random_steps=100, capacity=1000, loop="rounds"),
        td3=TD3Config(batch_size=16),
        network=NetworkSizes(**{"width": 16, "layers": 1, "feedforward": 32, **(network or {})}),
        log_interval=200,
        checkpoint_interval=400,
        eval_interval=400,
        eval_episodes=2,
        run_dir=str(run_dir),
    )
    return TrainConfig(**{**fields, **overrides})


def train_flags(config) -> list[str]:
    """``python -m swat_jax.train`` flags that build ``config`` (its preset and every value that differs)."""
    from swat_jax.runs.config import config_flags

    return config_flags(config)


@pytest.fixture(scope="session")
def hopper_folder(tmp_path_factory) -> Path:
    """A folder-of-MJCF environment set holding hopper_3 only."""
    folder = tmp_path_factory.mktemp("hopper_only")
    shutil.copy(MORPHOLOGIES / "hopper_3.xml", folder)
    shutil.copytree(MORPHOLOGIES / "assets", folder / "assets")
    return folder


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory, hopper_folder) -> Path:
    """The run directory of a finished tiny run (600 steps of hopper_3)."""
    from swat_jax.train import train

    run_dir = tmp_path_factory.mktemp("runs") / "tiny"
    train(tiny_train_config(run_dir, hopper_folder), progress=False)
    return run_dir


@pytest.fixture(scope="session")
def trained_swat_run(tmp_path_factory, hopper_folder) -> Path:
    """The run directory of a one-iteration SWAT run of hopper_3 (1 seed, no evaluation), whose traversal
    tables have 3 rows: exactly hopper_3's 3 limbs, so larger bodies do not fit."""
    from swat_jax.train import train

    run_dir = tmp_path_factory.mktemp("runs") / "tiny_swat"
    config = tiny_train_config(
        run_dir,
        hopper_folder,
        algo="swat",
        steps=100,
        seeds=1,
        eval_interval=0,
        network={"max_traversal_positions": 3},
    )
    train(config, progress=False)
    return run_dir
