"""Benchmark environments on MuJoCo MJX: observations, rewards, terminations, many bodies in one step.

- body.py: one body as a functional environment, ``reset(rng) -> state``, ``step(state, action) -> state``;
  with variants of the body, one program steps them all (``Variant``).
- tasks.py: what a body is asked to do (run forward; in 3D walk to a target): reward, termination and what an
  episode carries besides the physics, one object per body with the same methods for every kind.
- multi_task.py: K bodies x n copies in one jitted step, padded to one limb count, automatic resets.
- observation.py: the per-limb observation (the benchmark's table, docs/bodies-and-environments.md "Environments") as a pure function,
  in NumPy or jax.numpy (it imports no jax: a controller without JAX uses it).
- physics.py: one MJX timestep, with an RK4 integrator that compiles faster than ``mjx.step``'s.
"""

from __future__ import annotations

import importlib
from typing import Any

_HOMES = {
    "BodyEnv": "body",
    "EnvState": "body",
    "Variant": "body",
    "EpisodeStats": "multi_task",
    "MultiTaskEnv": "multi_task",
    "MultiTaskState": "multi_task",
    "StepResult": "multi_task",
}
"""Where each name of the package lives; imported on first use, so ``swat_jax.envs.observation`` alone
imports no jax."""

__all__ = list(_HOMES)


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
