"""One body's environment: reward, termination and reset noise as the benchmark defines them.

The expected values are written out here from the benchmark's definitions with literal numbers, independently
of swat_jax/morphology/families.py, and compared on random states of each body.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.envs import BodyEnv

SAMPLES = 96


def reference_alive(name: str, qpos: np.ndarray, qvel: np.ndarray, site_z: dict[str, float]) -> bool:
    """The benchmark's termination rules, row by row."""
    h, angle = qpos[1], qpos[2]
    bounded = bool(np.all(np.abs(qpos[2:]) < 100) and np.all(np.abs(qvel) < 100))
    upright = abs(angle) < 1
    if name.startswith("hopper_"):
        return bounded and upright and h > {"3": 0.45, "4": 0.6, "5": 0.95}[name.split("_")[1]]
    if name.startswith("walker_"):
        legs = int(name.split("_")[1])
        low, high = (0.54, 1.74) if legs <= 3 else (0.664, 1.864) if legs == 4 else (0.8, 2.0)
        return low < h < high and upright
    if name.startswith("humanoid_2d"):
        return 0.4 < h < 2.1 and upright
    if name.startswith("cheetah_"):
        return True
    if name == "nervenet_hopper":
        return bounded and h > 0.7 and abs(angle) < 0.2
    if name == "nervenet_halfhumanoid":
        return 0.8 < h < 2.0 and upright
    if name == "nervenet_ostrich":
        return 0.8 < h < 2.0 and upright and site_z["head"] > 1.1
    cheetah_alive = bounded and site_z["front"] > 0.7 and site_z["back"] > 0.7
    if name == "nervenet_fullcheetah":
        return cheetah_alive
    assert name == "nervenet_halfcheetah"
    return cheetah_alive and site_z["tip"] > 1.2


def reference_reward(name: str, x_before: float, x_after: float, control: np.ndarray) -> float:
    """The benchmark's reward; dt = 4 x timestep (0.002 s, cheetahs 0.01 s)."""
    if name.startswith("cheetah_"):
        return (x_after - x_before) / 0.04 - 0.1 * np.sum(control**2)
    if name in ("nervenet_fullcheetah", "nervenet_halfcheetah"):
        return (x_after - x_before) / 0.008 - 0.1 * np.sum(control**2) + 1
    return (x_after - x_before) / 0.008 + 1 - 0.001 * np.sum(control**2)


@functools.cache
def compiled(name: str, physics: str):
    """The body's environment on ``physics`` with a batched reset and a batched step-outcome, jitted once."""
    env = BodyEnv(name, physics=physics)
    reset = jax.jit(jax.vmap(env.reset))
    outcome = jax.jit(jax.vmap(lambda state, data: env.finish_step(state, env.kinematics(data))))
    return env, reset, outcome


def random_states(env: BodyEnv, rng: np.random.Generator):
    """qpos/qvel/ctrl spread widely around the initial pose: some alive, some terminated."""
    nq, nv, nu = env.mj_model.nq, env.mj_model.nv, env.mj_model.nu
    qpos = env.mj_model.qpos0 + rng.uniform(-0.8, 0.8, (SAMPLES, nq))
    qpos[:, 1] += rng.uniform(-0.9, 0.9, SAMPLES)
    qvel = rng.normal(0, 40, (SAMPLES, nv))
    control = rng.uniform(-1, 1, (SAMPLES, nu))
    return qpos.astype(np.float32), qvel.astype(np.float32), control.astype(np.float32)


TERMINATION_BODIES = [
    "hopper_3",
    "hopper_4",
    "hopper_5",
    "walker_2_main",
    "walker_4_main",
    "walker_7_main",
    "humanoid_2d_9_full",
    "cheetah_7_full",
    "nervenet_hopper",
    "nervenet_halfhumanoid",
    "nervenet_ostrich",
    "nervenet_fullcheetah",
    "nervenet_halfcheetah",
]
SITE_BODIES = ["nervenet_ostrich", "nervenet_fullcheetah", "nervenet_halfcheetah"]
"""The bodies whose termination reads site heights: checked on MJX as well. Every body's table is checked on
MuJoCo C (the CPU's physics, no MJX program to compile); MJX's states and observations equal C's per body
(test_env_bodies.py), and the reward and termination are the same code above either."""


@pytest.mark.parametrize(
    ("name", "physics"),
    [(name, "c") for name in TERMINATION_BODIES] + [(name, "jax") for name in SITE_BODIES],
)
def test_termination_and_reward_follow_the_benchmark_tables(name, physics):
    env, reset, outcome = compiled(name, physics)
    qpos, qvel, control = random_states(env, np.random.default_rng(len(name)))
    start = reset(jax.random.split(jax.random.PRNGKey(0), SAMPLES))
    data = start.data.replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel), ctrl=jnp.asarray(control))
    after = jax.tree_util.tree_map(np.asarray, outcome(start, data))
    site_names = [site for site, _ in env.morphology.family.termination.site_min_heights]
    expected_alive = [
        reference_alive(
            name,
            qpos[i],
            qvel[i],
            dict(zip(site_names, after.data.site_xpos[i, env.task.site_ids, 2], strict=True)),
        )
        for i in range(SAMPLES)
    ]
    np.testing.assert_array_equal(~after.terminated, expected_alive)
    if not name.startswith("cheetah_"):
        assert 0 < sum(expected_alive) < SAMPLES, "the samples should cover both outcomes"
    x_before = np.asarray(start.data.qpos[:, 0])
    expected_reward = [reference_reward(name, x_before[i], qpos[i, 0], control[i]) for i in range(SAMPLES)]
    np.testing.assert_allclose(after.reward, expected_reward, rtol=1e-4, atol=1e-3)
    assert not after.truncated.any()
    np.testing.assert_array_equal(after.episode_length, 1)


def test_an_unstable_simulation_terminates_with_zero_reward_and_no_nan():
    _, reset, outcome = compiled("hopper_3", "c")
    start = reset(jax.random.split(jax.random.PRNGKey(0), 3))
    qvel = np.asarray(start.data.qvel).copy()
    qvel[0, 1] = np.nan
    qvel[1, 2] = 5e3
    after = outcome(start, start.data.replace(qvel=jnp.asarray(qvel)))
    np.testing.assert_array_equal(after.terminated, [True, True, False])
    np.testing.assert_array_equal(after.reward[:2], 0.0)
    assert np.isfinite(np.asarray(after.observation)).all()
    np.testing.assert_array_equal(after.observation[:2], 0.0)


@pytest.mark.parametrize(
    "name, qpos_noise, qvel_std",
    [("hopper_3", 0.005, 0.005 / np.sqrt(3)), ("cheetah_7_full", 0.1, 0.1)],
)
def test_reset_noise_follows_the_family(name, qpos_noise, qvel_std):
    env, reset, _ = compiled(name, "c")
    start = reset(jax.random.split(jax.random.PRNGKey(1), 512))
    qpos_offset = np.asarray(start.data.qpos) - env.mj_model.qpos0
    assert np.abs(qpos_offset).max() <= qpos_noise
    assert np.abs(qpos_offset).max() > 0.95 * qpos_noise
    assert np.std(np.asarray(start.data.qvel)) == pytest.approx(qvel_std, rel=0.1)
    assert len({float(x) for x in np.asarray(start.data.qpos[:, 0])}) == 512, (
        "every reset draws its own noise"
    )
    np.testing.assert_array_equal(start.episode_length, 0)
    assert not np.asarray(start.done).any()


def test_reference_x_option_reads_absolute_x_below_the_torso():
    relative = BodyEnv("hopper_3", physics="c")
    absolute = BodyEnv("hopper_3", physics="c", torso_relative_x=False)
    rng = jax.random.PRNGKey(2)
    start, reference = jax.jit(relative.reset)(rng), jax.jit(absolute.reset)(rng)
    limb_x = np.asarray(start.data.xpos[1:4, 0])
    np.testing.assert_allclose(reference.observation[1:, 0], limb_x[1:], atol=1e-6)
    np.testing.assert_allclose(start.observation[:, 0], limb_x - limb_x[0], atol=1e-6)
    assert reference.observation[0, 0] == 0.0
