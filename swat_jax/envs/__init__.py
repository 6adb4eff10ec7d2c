"""Benchmark environments on MuJoCo MJX: observations, rewards, terminations, many bodies in one step.

- body.py: one body as a functional environment, ``reset(rng) -> state``, ``step(state, action) -> state``;
  with variants of the body, one program steps them all (``Variant``).
- multi_task.py: K bodies x n copies in one jitted step, padded to one limb count, automatic resets.
- observation.py: the per-limb observation (the benchmark's table, docs/bodies-and-environments.md "Environments") as a pure function.
- physics.py: one MJX timestep, with an RK4 integrator that compiles faster than ``mjx.step``'s.
"""

from swat_jax.envs.body import BodyEnv, EnvState, Variant
from swat_jax.envs.multi_task import EpisodeStats, MultiTaskEnv, MultiTaskState, StepResult

__all__ = ["BodyEnv", "EnvState", "EpisodeStats", "MultiTaskEnv", "MultiTaskState", "StepResult", "Variant"]
