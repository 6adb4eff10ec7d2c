"""scripts/offline_wheels.py (``make wheels``): the wheels' pins come from pyproject.toml, per Python."""

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "offline_wheels.py"


@pytest.fixture(scope="module")
def offline_wheels():
    spec = importlib.util.spec_from_file_location("offline_wheels", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pins_follow_the_python_version_markers(offline_wheels):
    names = ("jax", "flax", "numpy", "mujoco-mjx", "typeguard")
    assert offline_wheels.pinned_requirements(names, "3.11") == [
        "jax==0.10.2",
        "flax==0.12.8",
        "numpy==2.4.6",
        "mujoco-mjx==3.17.0",
        "typeguard==4.6.0",
    ]
    assert offline_wheels.pinned_requirements(names, "3.12")[:3] == [
        "jax==0.11.2",
        "flax==0.12.12",
        "numpy==2.5.2",
    ]


def test_every_wheel_the_image_lacks_is_pinned_to_one_version(offline_wheels):
    requirements = offline_wheels.pinned_requirements(offline_wheels.IMAGE_LACKS, "3.12")
    assert [requirement.split("==")[0] for requirement in requirements] == list(offline_wheels.IMAGE_LACKS)
    assert "mujoco==3.17.0" in requirements and "mujoco-mjx==3.17.0" in requirements


def test_a_package_without_a_single_pin_is_refused(offline_wheels, tmp_path):
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text('[project]\ndependencies = ["tyro>=1.0", "mujoco==3.17.0"]\n')
    assert offline_wheels.pinned_requirements(["mujoco"], "3.12", pyproject) == ["mujoco==3.17.0"]
    for name, pinned in (("tyro", ">=1.0"), ("trimesh", "nothing")):
        with pytest.raises(offline_wheels.PinError, match=f"pins {name} to {pinned} for Python 3.12"):
            offline_wheels.pinned_requirements([name], "3.12", pyproject)


def test_the_download_is_wheels_only_for_the_target_python(offline_wheels, tmp_path):
    command = offline_wheels.download_command(["mujoco==3.17.0"], "3.12", tmp_path)
    assert command[1:4] == ["-m", "pip", "download"]
    for flag in ("--no-deps", "--only-binary=:all:", "manylinux2014_x86_64", "mujoco==3.17.0"):
        assert flag in command
    assert command[command.index("--python-version") + 1] == "3.12"
    assert command[command.index("--dest") + 1] == str(tmp_path)
