"""Training over a device mesh (swat_jax.td3.sharding): the mesh rule, and a run on variants of its bodies
over 4 fake CPU devices that equals its unsharded twin, resumes on the other layout, evaluates and exports.

The 4 devices are XLA's fake host devices (``--xla_force_host_platform_device_count``), which must be set
before JAX starts, so the run happens in a subprocess (tests/sharded_twins.py).
"""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import MORPHOLOGIES, tiny_train_config
from subprocesses import python_path_environment

from swat_jax.runs.config import ConfigError
from swat_jax.td3.sharding import mesh_shape
from swat_jax.train import train

TESTS = Path(__file__).resolve().parent


@pytest.mark.parametrize(
    ("seeds", "tasks", "copies", "devices", "shape"),
    [
        (4, 5, 16, 4, (4, 1)),  # seeds fill the devices first
        (2, 2, 2, 4, (2, 2)),  # then tasks
        (1, 5, 16, 4, (1, 4)),  # 5 bodies on 4 devices: the copies divide, replay and update are replicated
        (1, 5, 7, 4, (1, 1)),  # nothing divides: one device, 3 idle
        (3, 5, 16, 8, (3, 2)),  # 2 of 8 idle
        (2, 3, 1, 1, (1, 1)),  # one device
    ],
)
def test_mesh_rule_fills_devices_with_seeds_then_tasks(seeds, tasks, copies, devices, shape):
    assert mesh_shape(seeds, tasks, copies, devices) == shape


@pytest.fixture(scope="session")
def sharded_twins(tmp_path_factory):
    """Session-scoped (its tests run on one worker, conftest.WORKER_GROUPS): a worker runs other modules' tests
    between them, which would end a module-scoped fixture and run the subprocess again."""
    folder = tmp_path_factory.mktemp("two_hoppers")
    for body in ("hopper_3", "hopper_4"):
        shutil.copy(MORPHOLOGIES / f"{body}.xml", folder)
    shutil.copytree(MORPHOLOGIES / "assets", folder / "assets")
    out = tmp_path_factory.mktemp("sharded")
    result = subprocess.run(
        [sys.executable, str(TESTS / "sharded_twins.py"), str(folder), str(out)],
        capture_output=True,
        text=True,
        env=python_path_environment(
            TESTS, XLA_FLAGS=f"{os.environ['XLA_FLAGS']} --xla_force_host_platform_device_count=4"
        ),
        timeout=1200,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1]) | {"stderr": result.stderr}


def test_a_run_over_a_2x2_mesh_equals_its_unsharded_twin(sharded_twins):
    assert sharded_twins["devices"] == 4
    sharded, unsharded = sharded_twins["meshes"][:2]
    assert sharded.startswith("mesh of 4 cpu devices: seeds 2 x tasks 2")
    assert "'tasks' splits replay rings and update by task and environment copies (2 way)" in sharded
    assert unsharded == "mesh of 1 cpu device: seeds 1 x tasks 1"
    assert sharded_twins["after_training"]["integers_equal"]
    assert sharded_twins["after_training"]["relative"] < 1e-3, "float32 sums in another order, nothing more"


def test_each_device_calls_the_physics_for_its_own_copies(sharded_twins):
    """The sharded runs (4 devices, trained and resumed) made the same number of MuJoCo C calls on every
    device; nothing was gathered onto one device for a callback, so XLA had nothing to warn about."""
    trained, unsharded, resumed_unsharded, resumed = sharded_twins["physics_calls"]
    assert unsharded is None and resumed_unsharded is None, "one device: no calls line"
    for line in (trained, resumed):
        counts = re.fullmatch(r"physics calls of process 0 in training: (.*)", line).group(1).split(", ")
        numbers = {int(count.split(" on device ")[0]) for count in counts}
        assert [count.split(" on device ")[1] for count in counts] == ["0", "1", "2", "3"], line
        assert len(numbers) == 1 and numbers.pop() > 0, line
    assert "Involuntary full rematerialization" not in sharded_twins["stderr"]
    assert "[SPMD]" not in sharded_twins["stderr"]


def test_copies_that_do_not_divide_by_the_devices_are_padded(sharded_twins):
    """3 copies on 4 devices: one padding copy; the states equal one device's bit for bit, and each device
    made the same calls (a reset and 4 steps of 2 calls each)."""
    padded = sharded_twins["padded"]
    assert padded["equal"]
    assert padded["calls"] == {str(device): 9 for device in range(4)}


def test_checkpoints_resume_on_the_other_layout(sharded_twins):
    assert sharded_twins["meshes"][2:] == [
        "mesh of 1 cpu device: seeds 1 x tasks 1",
        sharded_twins["meshes"][0],
    ]
    assert sharded_twins["steps_per_task"] == [60, 60], "per body: 3 iterations of 2 copies x 10 steps"
    assert sharded_twins["after_resume"]["integers_equal"]
    assert sharded_twins["after_resume"]["relative"] < 1e-3


def test_variants_are_split_with_the_copies_and_kept_by_each(sharded_twins):
    """The twins' equality above covers the variant rows (part of the environment state); here: they are variants."""
    assert sharded_twins["copies_differ"], "copy 0 and copy 1 run different variants of the body"
    assert sharded_twins["seeds_share_variants"], "every seed trains on the same variants"


def test_a_sharded_run_evaluates_and_exports(sharded_twins):
    returns = sharded_twins["eval_returns"]
    assert len(returns) == 2 and all(len(seed_returns) == 2 for seed_returns in returns), "2 bodies x 2 seeds"
    assert sharded_twins["actions_shape"] == [3, 4] and sharded_twins["actions_finite"]


def test_more_devices_than_the_machine_has_is_refused_before_anything_is_built(tmp_path, hopper_folder):
    with pytest.raises(
        ConfigError, match=r"--devices 2: this machine has 1 cpu device; give 1 to 1, or 0 for all"
    ):
        train(tiny_train_config(tmp_path / "run", hopper_folder), devices=2, progress=False)
    assert not (tmp_path / "run").exists()
