"""Standard output holds only what a command means to print: ``--help`` starts with the usage line and
``--json`` parses, in fresh processes (third-party modules print at import, e.g. mujoco.mjx's Warp notices)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HELP_COMMANDS = (
    ("swat_jax.train",),
    ("swat_jax.eval",),
    ("swat_jax.export",),
    ("swat_jax.render",),
    ("swat_jax.morphology",),
    ("swat_jax.morphology", "list"),
    ("swat_jax.morphology", "show"),
    ("swat_jax.morphology", "render"),
)


def command(module: str, *args: str) -> subprocess.Popen:
    """``python -m module args`` started in the background, its standard output and error captured."""
    return subprocess.Popen(
        [sys.executable, "-m", module, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def finished(process: subprocess.Popen) -> str:
    """The standard output of a command that must succeed."""
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, err
    return out


@pytest.fixture(scope="module")
def help_outputs() -> dict[tuple[str, ...], str]:
    """Every command's --help, run side by side."""
    processes = {argv: command(*argv, "--help") for argv in HELP_COMMANDS}
    return {argv: finished(process) for argv, process in processes.items()}


@pytest.mark.parametrize("argv", HELP_COMMANDS, ids=" ".join)
def test_help_starts_with_its_usage_line(help_outputs, argv):
    module, *subcommand = argv
    assert help_outputs[argv].startswith(f"usage: python -m {' '.join([module, *subcommand])} ")


def test_json_outputs_parse(trained_run):
    show = command("swat_jax.morphology", "show", "walker_3_main", "--json")
    evaluation = command(
        "swat_jax.eval", str(trained_run), "--episodes", "2", "--bodies", "hopper_3", "hopper_4", "--json"
    )
    assert json.loads(finished(show))["limbs"] == ["torso", "left1", "right1"]
    assert set(json.loads(finished(evaluation))["bodies"]) == {"hopper_3", "hopper_4"}
