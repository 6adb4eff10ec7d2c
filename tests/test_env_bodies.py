"""Every benchmark body resets and steps under jit, and its float32 MJX rollout tracks MuJoCo C.

One compiled rollout (reset + 10 steps in a ``lax.scan``) per body: 2 s of tracing and 5 s of compile
each on a 2-core CPU with the suite's XLA flags (conftest.py; 11-12 s with XLA's defaults), so it runs
on the bodies that can differ in MJX's physics: every hand-written body, and of the 34 the generator
derives from them (an intact body with limbs removed: the same geoms, joints and motors), the smallest of
each intact body's. Every one of the 43 bodies' observation, reward and termination is compared with the
original code's own numbers on MuJoCo C's state in tests/test_original_parity.py, and the generated
files with the generator's output in tests/test_morphologies.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from mujoco_reference import mjx_and_c_rollouts

from swat_jax.morphology import benchmark_names, load
from swat_jax.morphology.generate import VARIANTS

STEPS = 10
FLOAT32_STATE_TOLERANCE = 1e-3
"""Max abs qpos difference from MuJoCo C (float64) over 10 env steps in float32. Rounding differences
grow chaotically once a body tumbles (cheetah_3_front: 4e-3 after 25 steps), so the float32 check is
kept short; the float64 test (test_env_against_mujoco.py) pins the physics over 100 steps."""
FLOAT32_OBSERVATION_TOLERANCE = 2e-2
"""Velocities amplify the state's rounding differences."""


def rollout_bodies() -> list[str]:
    """The hand-written bodies, and for each the generated body with the fewest limbs (the most removed)."""
    hand_written = [name for name in benchmark_names() if name not in VARIANTS and not name.startswith("3d_")]
    smallest = {}
    for name, variant in sorted(VARIANTS.items()):
        kept = smallest.get(variant.source)
        if kept is None or len(variant.removed) > len(VARIANTS[kept].removed):
            smallest[variant.source] = name
    return hand_written + sorted(smallest.values())


ROLLOUT_BODIES = rollout_bodies()


def test_the_benchmark_has_43_planar_and_52_3d_bodies():
    assert len(benchmark_names()) == 95
    assert sum(name.startswith("3d_") for name in benchmark_names()) == 52


def test_the_rollouts_cover_every_hand_written_body_and_the_generators_smallest():
    assert ROLLOUT_BODIES == [
        "cheetah_7_full", "hopper_5", "humanoid_2d_9_full", "nervenet_fullcheetah", "nervenet_halfcheetah",
        "nervenet_halfhumanoid", "nervenet_hopper", "nervenet_ostrich", "walker_7_main",
        "cheetah_2_back", "hopper_3", "humanoid_2d_7_left_arm", "walker_2_flipped",
    ]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("name", ROLLOUT_BODIES)
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
