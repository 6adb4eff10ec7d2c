"""What machine a benchmark ran on, for the headers of BENCHMARKS.md (shared by the scripts here)."""

from __future__ import annotations

import importlib.metadata
import os
import platform


def cpu_model(cpuinfo: str = "/proc/cpuinfo") -> str:
    """The CPU model from ``cpuinfo``, with its family, model number and whether it has AVX-512: VMs sold under
    one name ("AMD EPYC") come in generations whose speed differs by up to 2x for the same code. The platform's
    processor string where there is no such file."""
    fields: dict[str, str] = {}
    try:
        with open(cpuinfo) as lines:
            for line in lines:
                if not line.strip():
                    break
                key, _, value = line.partition(":")
                fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    if "model name" not in fields:
        return platform.processor() or "unknown"
    avx512 = "yes" if "avx512f" in fields.get("flags", "").split() else "no"
    return (
        f"{fields['model name']} (family {fields.get('cpu family', '?')}, model {fields.get('model', '?')}, "
        f"AVX-512 {avx512})"
    )


def host_cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def host_memory_gib() -> float:
    """Physical memory of the host, GiB."""
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**30


SOFTWARE = (
    "jax",
    "jaxlib",
    "jax-cuda12-plugin",
    "jax-cuda13-plugin",
    "flax",
    "optax",
    "orbax-checkpoint",
    "numpy",
    "mujoco",
    "mujoco-mjx",
    "warp-lang",
)
"""Distributions whose versions a benchmark reports (those installed)."""


def software_versions() -> dict[str, str]:
    """Python's version and that of every installed distribution of ``SOFTWARE``, by name."""
    versions = {"python": platform.python_version()}
    for name in SOFTWARE:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return versions
