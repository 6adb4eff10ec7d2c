"""Standard output holds only what a command means to print: ``--help`` starts with the usage line and
``--json`` parses, in fresh processes (third-party modules print at import, e.g. mujoco.mjx's Warp notices)."""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import inspect
import io
import itertools
import json
import re
import subprocess
import sys
import typing

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
    ("swat_jax.morphology", "variants"),
    ("swat_jax.plot",),
    ("swat_jax.plot", "curves"),
    ("swat_jax.plot", "embeddings"),
    ("swat_jax.plot", "relations"),
    ("swat_jax.convert",),
)
COMMANDS = {
    ("swat_jax.eval",): "swat_jax.eval:EvalCommand",
    ("swat_jax.export",): "swat_jax.export:ExportCommand",
    ("swat_jax.render",): "swat_jax.render:RenderCommand",
    ("swat_jax.morphology", "show"): "swat_jax.morphology.__main__:ShowCommand",
    ("swat_jax.morphology", "render"): "swat_jax.morphology.__main__:RenderCommand",
    ("swat_jax.morphology", "variants"): "swat_jax.morphology.__main__:VariantsCommand",
    ("swat_jax.plot", "curves"): "swat_jax.plot:CurvesCommand",
    ("swat_jax.plot", "embeddings"): "swat_jax.plot:EmbeddingsCommand",
    ("swat_jax.plot", "relations"): "swat_jax.plot:RelationsCommand",
    ("swat_jax.convert",): "swat_jax.convert:ConvertCommand",
}
"""The frozen dataclass each command line parses into (tyro, like train's TrainCommand)."""


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
    """Every command's --help: each module's in a fresh process (side by side), its subcommands' in this
    one (the module is the same, so are its imports)."""
    processes = {argv: command(*argv, "--help") for argv in HELP_COMMANDS if len(argv) == 1}
    outputs = {argv: finished(process) for argv, process in processes.items()}
    for module, subcommand in (argv for argv in HELP_COMMANDS if len(argv) == 2):
        entry = importlib.import_module(f"{module}.__main__" if module == "swat_jax.morphology" else module)
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed), pytest.raises(SystemExit) as exit_info:
            entry.main([subcommand, "--help"])
        assert exit_info.value.code == 0
        outputs[(module, subcommand)] = printed.getvalue()
    return outputs


@pytest.mark.parametrize("argv", HELP_COMMANDS, ids=" ".join)
def test_help_starts_with_its_usage_line(help_outputs, argv):
    module, *subcommand = argv
    assert help_outputs[argv].startswith(f"usage: python -m {' '.join([module, *subcommand])} ")


@pytest.mark.parametrize("argv", COMMANDS, ids=" ".join)
def test_help_explains_every_field_of_the_command(help_outputs, argv):
    """Every field is an option (or the positional argument) whose help line is the field's docstring."""
    module, name = COMMANDS[argv].split(":")
    command = getattr(importlib.import_module(module), name)
    help_text = " ".join(help_outputs[argv].replace("│", " ").split())
    hints = typing.get_type_hints(command, include_extras=True)
    for field in dataclasses.fields(command):
        positional = "Positional" in str(hints[field.name])
        assert positional or f"--{field.name.replace('_', '-')}" in help_text, field.name
    for docstring in field_docstrings(command):
        first_words = " ".join(docstring.split()[:4])
        assert first_words in help_text, f"{name}: {first_words!r} is not in --help"


MJX_PROBE = """
import sys
import swat_jax.eval, swat_jax.export, swat_jax.plot, swat_jax.train
from swat_jax.envs import BodyEnv
BodyEnv("hopper_3", physics="c").reset
print("mujoco.mjx" in sys.modules)
"""


def test_the_commands_and_c_physics_start_without_importing_mjx():
    """MJX's import (about 1.5 s with MuJoCo Warp's kernels) waits for its first use (every MJX test reads it
    through the same stand-in): the commands and a body on C physics start without it."""
    probe = subprocess.run([sys.executable, "-c", MJX_PROBE], capture_output=True, text=True, check=False)
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout == "False\n"


def field_docstrings(command: type) -> list[str]:
    """The docstring under each field of ``command`` and of the dataclasses it extends."""
    docstrings = []
    for cls in command.__mro__:
        if not dataclasses.is_dataclass(cls):
            continue
        lines = inspect.getsource(cls).splitlines()
        for line, following in itertools.pairwise(lines):
            if re.match(r"    \w+: ", line) and following.strip().startswith('"""'):
                docstrings.append(following.strip().strip('"'))
    assert docstrings, f"{command.__name__} documents no field"
    return docstrings


def test_json_outputs_parse(trained_run):
    show = command("swat_jax.morphology", "show", "walker_3_main", "--json")
    evaluation = command(
        "swat_jax.eval", str(trained_run), "--episodes", "2", "--bodies", "hopper_3", "hopper_4", "--json"
    )
    assert json.loads(finished(show))["limbs"] == ["torso", "left1", "right1"]
    assert set(json.loads(finished(evaluation))["bodies"]) == {"hopper_3", "hopper_4"}
