"""The MJX environment against plain MuJoCo C: same actions, same states.

In float64 MJX and MuJoCo C run the same algorithm, so 100 environment steps (400 physics steps,
contacts included) agree to 1e-8; this pins the physics, including swat_jax's own RK4 integrator
(envs/physics.py). The float32 default drifts by rounding, chaotically once bodies tumble; its
agreement over 25 steps is checked for every body in test_env_bodies.py.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from subprocesses import python_path_environment

ONE_BODY_PER_FAMILY = [
    "hopper_3",
    "walker_7_main",
    "cheetah_7_full",
    "humanoid_2d_9_full",
    "nervenet_ostrich",
]
STEPS = 100
STATE_TOLERANCE = 1e-8
"""Max abs qpos/qvel difference over 100 env steps in float64 (measured: 1e-12 or less)."""
OBSERVATION_TOLERANCE = 1e-5
"""The observation is stored as float32."""

SCRIPT = """
import json, sys
from mujoco_reference import mjx_and_c_rollouts
errors = {}
for name in sys.argv[2:]:
    r = mjx_and_c_rollouts(name, int(sys.argv[1]))
    errors[name] = dict(
        qpos=float(r["qpos_error"].max()),
        qvel=float(r["qvel_error"].max()),
        observation=float(abs(r["observation"][-1] - r["c_final_observation"]).max()),
        moved=float(abs(r["observation"][-1][:, 3:9]).max()),
    )
print(json.dumps(errors))
"""


@pytest.fixture(scope="module")
def float64_errors() -> dict[str, dict[str, float]]:
    """Each body's largest differences between the float64 MJX and MuJoCo C rollouts, from one process
    (float64 is chosen when JAX starts; one process imports MJX once for every body)."""
    tests = Path(__file__).parent
    completed = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(STEPS), *ONE_BODY_PER_FAMILY],
        capture_output=True,
        text=True,
        env=python_path_environment(tests, JAX_ENABLE_X64="1"),
        check=False,
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    return json.loads(completed.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("name", ONE_BODY_PER_FAMILY)
def test_float64_mjx_environment_equals_mujoco_c_over_100_steps(float64_errors, name):
    errors = float64_errors[name]
    assert errors["qpos"] < STATE_TOLERANCE, errors
    assert errors["qvel"] < STATE_TOLERANCE, errors
    assert errors["observation"] < OBSERVATION_TOLERANCE, errors
    assert errors["moved"] > 0.1, "the rollout should move the body"
