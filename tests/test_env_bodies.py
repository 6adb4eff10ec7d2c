"""Every benchmark body resets and steps under jit, and its float32 MJX rollout tracks MuJoCo C.

One compiled rollout (reset + 10 steps in a ``lax.scan``) per body; 5-7 s of compile each on a 2-core
CPU with the suite's XLA flags (conftest.py; 11-12 s with XLA's defaults), so the module is marked slow
(it still runs in CI).
"""

from __future__ import annotations

import numpy as np
import pytest
from mujoco_reference import mjx_and_c_rollouts

from swat_jax.morphology import benchmark_names, load

STEPS = 10
FLOAT32_STATE_TOLERANCE = 1e-3
"""Max abs qpos difference from MuJoCo C (float64) over 10 env steps in float32. Rounding differences
grow chaotically once a body tumbles (cheetah_3_front: 4e-3 after 25 steps), so the float32 check is
kept short; the float64 test (test_env_against_mujoco.py) pins the physics over 100 steps."""
FLOAT32_OBSERVATION_TOLERANCE = 2e-2
"""Velocities amplify the state's rounding differences."""


def test_the_benchmark_has_43_bodies():
    assert len(benchmark_names()) == 43


@pytest.mark.slow
@pytest.mark.parametrize("name", benchmark_names())
def test_body_resets_and_steps_under_jit_like_mujoco_c(name):
    body = load(name)
    features = 15 + body.family.num_limb_types
    result = mjx_and_c_rollouts(name, STEPS)
    assert result["start_observation"].shape == (body.num_limbs, features)
    assert result["observation"].shape == (STEPS, body.num_limbs, features)
    assert result["observation"].dtype == np.float32
    assert np.isfinite(result["observation"]).all() and np.isfinite(result["reward"]).all()
    np.testing.assert_array_equal(result["episode_length"], np.arange(1, STEPS + 1))
    assert result["qpos_error"].max() < FLOAT32_STATE_TOLERANCE, result["qpos_error"]
    final_difference = np.abs(result["observation"][-1] - result["c_final_observation"]).max()
    assert final_difference < FLOAT32_OBSERVATION_TOLERANCE
