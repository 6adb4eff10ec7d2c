"""What a run's compiled programs are traced from: the key of the program cache (:func:`recipe`).

:func:`swat_jax.compilation_cache.compile_cached` keys a program by its name, its arguments and a
*recipe*: everything else its trace depends on, as values with a deterministic ``repr``. For a run's
programs (initial state, iteration, evaluation) the recipe is

- its config less the host-only fields (declared with :func:`~swat_jax.runs.config.host_only`: where and
  how long the run goes, its logging, its first seed; :func:`program_config`), and
- its environments (:func:`environments`): copies, padding, lock-step rounds, the reset keys, the
  observation's frame and, per body, its morphology and the SHA-256 of its compiled MuJoCo model (binary
  MJB: every size, parameter and asset, so an edited MJCF file is a new program under the same name).

Environments with Warp physics have no recipe: their programs call kernels that this process registers,
which another process cannot load. C physics programs call MuJoCo by name
(:mod:`swat_jax.envs.named_callback`), so another process that builds the same bodies loads them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from swat_jax.envs.controller import model_digest
from swat_jax.envs.multi_task import MultiTaskEnv
from swat_jax.runs.config import HOST_ONLY, TrainConfig


def recipe(config: TrainConfig, env: MultiTaskEnv, *extra: Any) -> tuple[Any, ...] | None:
    """The recipe of a program of a run with ``config`` on ``env`` (and ``extra``: the mesh, a switch of
    the program); None where the environments' programs cannot be cached."""
    described = environments(env)
    return None if described is None else (program_config(config), described, *extra)


def program_config(config: TrainConfig) -> TrainConfig:
    """``config`` with its host-only fields at their defaults: two configs that trace the same programs."""
    host = {
        field.name: field.default for field in dataclasses.fields(config) if field.metadata.get(HOST_ONLY)
    }
    return dataclasses.replace(config, **host)


def environments(env: MultiTaskEnv) -> tuple[Any, ...] | None:
    """What ``env``'s programs are traced from besides their arguments; None with Warp physics."""
    if any(body.simulator.implementation == "warp" for body in env.envs):
        return None
    return (
        env.copies,
        env.max_limbs,
        env.lock_step,
        env.shared_reset_key,
        *(
            (
                body.morphology,
                body.torso_relative_x,
                body.stale_kinematics,
                body.simulator.implementation,
                model_digest(body.mj_model),
            )
            for body in env.envs
        ),
    )
