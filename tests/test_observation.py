"""The per-limb observation equals an independent NumPy computation from MuJoCo C data, in NumPy and in
jax.numpy alike."""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco_reference import numpy_observation

from swat_jax.envs.observation import data_observation, limb_observation, observation_layout
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


NAMESPACES = {"numpy": np, "jax": jnp}


def ours(body, model, data, xp=jnp, **kwargs) -> np.ndarray:
    layout = observation_layout(body, model)
    arrays = (data.qpos, data.xpos[1:], data.xquat[1:], data.cvel[1:], data.subtree_com[1])
    return np.asarray(limb_observation(layout, *arrays, xp=xp, **kwargs))


@pytest.mark.parametrize("namespace", NAMESPACES)
@pytest.mark.parametrize("name", BODIES)
def test_observation_matches_numpy_from_mujoco_c(name, namespace):
    body, model, data = simulate(name)
    expected = numpy_observation(body, model, data)
    features = 19 if body.family.num_limb_types == 4 else 21
    assert expected.shape == (body.num_limbs, features)
    np.testing.assert_allclose(ours(body, model, data, NAMESPACES[namespace]), expected, atol=2e-5, rtol=1e-5)
    assert np.abs(expected[:, 3:9]).max() > 0.1, "the test state should move"


@pytest.mark.parametrize("namespace", NAMESPACES)
def test_reference_x_convention_reads_absolute_x_below_the_torso(namespace):
    body, model, data = simulate("walker_4_main")
    reference = ours(body, model, data, NAMESPACES[namespace], torso_relative_x=False)
    np.testing.assert_allclose(
        reference, numpy_observation(body, model, data, torso_relative_x=False), atol=2e-5
    )
    np.testing.assert_allclose(reference[1:, 0], data.xpos[2 : body.num_limbs + 1, 0], atol=1e-6)
    assert reference[0, 0] == 0.0


@pytest.mark.parametrize(
    ("name", "options"),
    [
        ("walker_7_main", {"torso_relative_x": True}),
        ("walker_7_main", {"torso_relative_x": False}),
        ("3d_walker_5_foot", {"target": [3.0, -2.0]}),
    ],
)
def test_numpy_computes_the_observation_jax_computes(name, options):
    """data_observation in NumPy (what a controller without JAX runs) equals it in jax.numpy (what the
    environment runs), planar and 3D, from one MuJoCo state."""
    body, model, data = simulate(name)
    layout = observation_layout(body, model)
    gravity = np.asarray(model.opt.gravity, np.float32)
    numpy, jax = (data_observation(layout, data, gravity=gravity, xp=xp, **options) for xp in (np, jnp))
    assert isinstance(numpy, np.ndarray) and numpy.dtype == np.float32
    assert numpy.shape == (body.num_limbs, layout.features)
    np.testing.assert_allclose(numpy, np.asarray(jax), atol=1e-5, rtol=1e-5)
    assert np.abs(numpy).max() > 0.1


def test_exponential_map_folds_the_angle_into_zero_to_pi():
    body, model, data = simulate("cheetah_7_full", steps=200, seed=3)
    rotation = ours(body, model, data)[:, 9:12]
    assert np.linalg.norm(rotation, axis=-1).max() <= np.pi + 1e-6
