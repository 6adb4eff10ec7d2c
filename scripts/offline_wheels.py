"""Download the wheels a CUDA JAX image lacks, for an install without a package registry.

The GPU image swat_jax is measured on has Python, jax with its CUDA plugin, numpy, flax, optax,
orbax-checkpoint, tqdm and imageio, but not the packages of ``IMAGE_LACKS``. This downloads exactly
those wheels, at the versions pinned in pyproject.toml for the target Python (the one place they are
pinned), for x86-64 Linux, without their requirements (the image has the rest). The wheels already in
the folder are removed first, so it holds one set for one Python::

    make wheels PY=3.12            # python scripts/offline_wheels.py --python-version 3.12 --dest .whl
    pip install --no-index --no-deps --target /tmp/site .whl/*.whl   # on the GPU machine

Uses ``tomllib`` (Python 3.11+), ``packaging`` and ``pip`` of the Python that runs it.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tomllib
from collections.abc import Sequence
from pathlib import Path

from packaging.requirements import Requirement

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
IMAGE_LACKS = (
    "mujoco",
    "mujoco-mjx",
    "trimesh",
    "tyro",
    "docstring-parser",
    "typeguard",
    "tensorboardX",
    "flatbuffers",
)
"""What swat_jax needs and a CUDA JAX image lacks: mujoco and mujoco-mjx (which imports trimesh), tyro
(docstring-parser, typeguard), tensorboardX, and flatbuffers (jax.export)."""
LINUX_X86_64 = (
    "manylinux_2_28_x86_64",
    "manylinux_2_27_x86_64",
    "manylinux_2_17_x86_64",
    "manylinux2014_x86_64",
)
"""Wheel platform tags accepted, newest first (glibc 2.28 or newer on the target machine)."""


class PinError(ValueError):
    """pyproject.toml does not pin one of the packages to a single version for the target Python."""


def pinned_requirements(names: Sequence[str], python_version: str, pyproject: Path = PYPROJECT) -> list[str]:
    """``name==version`` for each of ``names``, from the dependencies of ``pyproject`` whose environment
    marker holds on Python ``python_version`` ("3.12"), in the order of ``names``."""
    dependencies = tomllib.loads(pyproject.read_text())["project"]["dependencies"]
    environment = {"python_version": python_version, "python_full_version": f"{python_version}.0"}
    pins: dict[str, str] = {}
    for line in dependencies:
        requirement = Requirement(line)
        if requirement.marker is None or requirement.marker.evaluate(environment):
            pins[requirement.name.lower()] = str(requirement.specifier)
    requirements = []
    for name in names:
        specifier = pins.get(name.lower(), "")
        if not specifier.startswith("==") or "," in specifier:
            raise PinError(
                f"{pyproject} pins {name} to {specifier or 'nothing'} for Python {python_version}; "
                f"an offline install needs one version (name==version)"
            )
        requirements.append(f"{name}{specifier}")
    return requirements


def download_command(requirements: Sequence[str], python_version: str, destination: Path) -> list[str]:
    """The ``pip download`` command line that fetches exactly ``requirements`` as CPython wheels for
    ``python_version`` on x86-64 Linux into ``destination``."""
    platforms = [flag for tag in LINUX_X86_64 for flag in ("--platform", tag)]
    return [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--only-binary=:all:",
        "--python-version",
        python_version,
        "--implementation",
        "cp",
        *platforms,
        "--dest",
        str(destination),
        *requirements,
    ]


def main(argv: Sequence[str] | None = None) -> int:
    """Download the wheels and print each with its size and the total; returns pip's exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--python-version", default="3.12", help="the target machine's Python (major.minor)")
    parser.add_argument("--dest", type=Path, default=Path(".whl"), help="folder the wheels are written to")
    args = parser.parse_args(argv)
    try:
        requirements = pinned_requirements(IMAGE_LACKS, args.python_version)
    except PinError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    args.dest.mkdir(parents=True, exist_ok=True)
    for stale in args.dest.glob("*.whl"):
        stale.unlink()
    status = subprocess.run(
        download_command(requirements, args.python_version, args.dest), check=False
    ).returncode
    if status != 0:
        return status
    wheels = sorted(args.dest.glob("*.whl"))
    for wheel in wheels:
        print(f"{wheel.stat().st_size / 2**20:6.1f} MiB  {wheel.name}")
    total = sum(wheel.stat().st_size for wheel in wheels) / 2**20
    print(f"{total:6.1f} MiB  in {len(wheels)} wheels in {args.dest}/ for Python {args.python_version}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
