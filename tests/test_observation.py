"""The per-limb observation equals an independent NumPy computation from MuJoCo C data."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mujoco_reference import numpy_observation

from swat_jax.envs.observation import limb_observation, observation_layout
from swat_jax.morphology import load

BODIES = [
    "hopper_3",
    "walker_7_main",
    "cheetah_6_front",
    "humanoid_2d_9_full",
    "nervenet_ostrich",
    "nervenet_halfcheetah",
]


def simulate(name: str, steps: int = 60, seed: int = 0):
    """A body after ``steps`` physics steps of random controls (so that every slot is nonzero),
    with every derived field (xpos, cvel, ...) computed from the final qpos and qvel."""
    body = load(name)
    model = mujoco.MjModel.from_xml_path(str(body.path))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    data.qvel[:] = rng.normal(0, 1.0, model.nv)
    for _ in range(steps):
        data.ctrl[:] = rng.uniform(-1, 1, model.nu)
        mujoco.mj_step(model, data)
    # After an RK4 step the derived fields belong to an intermediate stage; make them the state's.
    mujoco.mj_forward(model, data)
    return body, model, data


def ours(body, model, data, **kwargs) -> np.ndarray:
    layout = observation_layout(body, model)
    arrays = (data.qpos, data.xpos[1:], data.xquat[1:], data.cvel[1:], data.subtree_com[1])
    return np.asarray(limb_observation(layout, *arrays, **kwargs))


@pytest.mark.parametrize("name", BODIES)
def test_observation_matches_numpy_from_mujoco_c(name):
    body, model, data = simulate(name)
    expected = numpy_observation(body, model, data)
    features = 19 if body.family.num_limb_types == 4 else 21
    assert expected.shape == (body.num_limbs, features)
    np.testing.assert_allclose(ours(body, model, data), expected, atol=2e-5, rtol=1e-5)
    assert np.abs(expected[:, 3:9]).max() > 0.1, "the test state should move"


def test_reference_x_convention_reads_absolute_x_below_the_torso():
    body, model, data = simulate("walker_4_main")
    reference = ours(body, model, data, torso_relative_x=False)
    np.testing.assert_allclose(
        reference, numpy_observation(body, model, data, torso_relative_x=False), atol=2e-5
    )
    np.testing.assert_allclose(reference[1:, 0], data.xpos[2 : body.num_limbs + 1, 0], atol=1e-6)
    assert reference[0, 0] == 0.0


def test_exponential_map_folds_the_angle_into_zero_to_pi():
    body, model, data = simulate("cheetah_7_full", steps=200, seed=3)
    rotation = ours(body, model, data)[:, 9:12]
    assert np.linalg.norm(rotation, axis=-1).max() <= np.pi + 1e-6
