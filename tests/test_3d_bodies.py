"""The 3D-SGRL bodies: our MJCF compiles to the benchmark's numbers, and our environment's observation,
reward and termination equal those of SGRL's own environments, step by step, on every 3D body.

``tests/data/sgrl_3d.npz`` holds what SGRL's environment classes returned with random actions
(recorded with the benchmark's code on MuJoCo 2.3.3, 20 steps per body, a reset every 10; see
``tests/sgrl_fixture.py``); ``tests/data/reference_numbers_3d.json`` its compiled models.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference_numbers import assert_same_numbers, summarize
from sgrl_fixture import exact_data, recorded_bodies, recording

from swat_jax.envs import BodyEnv
from swat_jax.envs.walk_to_target import heading_pitch_roll, next_target
from swat_jax.morphology import benchmark_names, get_set, load
from swat_jax.morphology.families import FAR_TARGET, NEAR_TARGET
from swat_jax.morphology.paths import MORPHOLOGY_DIR

REFERENCE = json.loads((Path(__file__).parent / "data" / "reference_numbers_3d.json").read_text())
THREE_D = tuple(name for name in benchmark_names() if name.startswith("3d_"))
FIRST_TASK = tuple(name for name in THREE_D if "_v2_" not in name)
"""The 29 bodies of SGRL's first task; each _v2 body is one of them with near targets (the same file, the
same step), and their reset observations are checked on their own."""


def test_every_3d_body_of_the_benchmark_is_shipped():
    """29 bodies, and a _v2 body for each of the 23 that SGRL gives a _v2 file."""
    assert len(THREE_D) == 52 and set(recorded_bodies()) == set(THREE_D)
    assert {name.replace("_v2", "") for name in THREE_D} == set(REFERENCE)


@pytest.mark.parametrize("name", THREE_D)
def test_3d_body_compiles_to_the_benchmarks_numbers(name):
    """Tree, masses, inertias, joints, geoms, contacts, motors and options equal the numbers SGRL's file
    compiles to; a _v2 body is the same model."""
    import mujoco

    ours = summarize(mujoco.MjModel.from_xml_path(str(MORPHOLOGY_DIR / f"{name}.xml")))
    assert_same_numbers(ours, REFERENCE[name.replace("_v2", "")], name)


def test_load_describes_a_3d_body():
    body = load("3d_humanoid_9_full")
    assert body.family.name == "3d_humanoid" and body.family.three_d and body.motors_per_limb == 3
    assert body.limb_names[:3] == ("torso", "right_thigh", "right_shin")
    assert body.joint_names[0] == () and body.joint_names[2] == tuple(f"right_shin_joint_{a}" for a in "xyz")
    assert body.joint_ranges[2] == ((-1.0, 1.0), (-160.0, -2.0), (-1.0, 1.0))
    assert body.limb_motors[1] == (0, 1, 2) and body.limb_motors[8] == (21, 22, 23)
    mask = body.motor_mask()
    assert mask.shape == (9, 3) and not mask[0].any() and mask[1:].all()
    assert body.limb_type_name(2) == "shin" and body.limb_type_name(5) == "none"  # an arm
    assert load("3d_hopper_v2_3_shin").family.target == NEAR_TARGET
    assert load("3d_hopper_3_shin").family.target == FAR_TARGET
    assert load("3d_hopper_3_shin").family.termination.height == (0.45, math.inf)


def test_3d_sets():
    assert get_set("3D-Walker++").test == ("3d_walker_3_left_knee_right_knee", "3d_walker_6_right_foot")
    cwhh = get_set("3d_cwhh")
    assert len(cwhh.train) == 23 and len(cwhh.test) == 6
    assert all(
        name in THREE_D
        for s in ("3d_cwhh", "3d_hopper_v2", "3d_cheetah_v2")
        for name in get_set(s).split("all")
    )


def _action(env: BodyEnv, motors: np.ndarray) -> np.ndarray:
    """Actions [..., nu] in motor order -> [..., n, M] per limb and hinge slot."""
    action = np.zeros((*motors.shape[:-1], env.num_limbs * env.morphology.motors_per_limb), np.float32)
    action[..., env.motor_actions] = motors
    return action.reshape(*motors.shape[:-1], *env.action_shape)


def _sgrl_steps(env: BodyEnv, reset_data, reset_target, start, actions, fresh, target):
    """(reset observations, the states after each recorded step) of ``env`` from SGRL's recorded states:
    ``reset_data`` and ``start`` exact states, the rest the recording's arrays (float32)."""
    key = jnp.zeros(2, jnp.uint32)
    reset = jax.vmap(lambda data, target: env.start(data, None, (target, key)).observation)(
        reset_data, reset_target
    )
    # The positions SGRL's reward reads before a step are those the previous step left (or, after a
    # reset, those of the reset state): simulate every previous step from its recorded state.
    previous = jax.vmap(lambda data, action: env.step_kinematics(env.simulate(data, action)))(
        jax.tree.map(lambda leaf: jnp.roll(leaf, 1, axis=0), start), jnp.roll(actions, 1, axis=0)
    )
    before = jax.tree.map(
        lambda new, old: jnp.where(fresh.reshape(-1, *[1] * (new.ndim - 1)), new, old), start, previous
    )
    before = before.replace(qpos=start.qpos, qvel=start.qvel, remainder=start.remainder)
    after = jax.vmap(lambda data, target, action: env.step(env.start(data, None, (target, key)), action))(
        before, target, actions
    )
    return reset, after


@pytest.mark.parametrize("name", FIRST_TASK)
def test_observation_reward_and_done_equal_sgrls(name):
    """From SGRL's recorded states and actions (MuJoCo C, the state exact to float64, the positions the
    step leaves as SGRL reads them): every reset observation, and every step's next state, observation,
    reward and done (the hoppers' foot contacts included: their geoms carry half SGRL's margin, as MuJoCo 3
    adds a contact's two margins where SGRL's MuJoCo 2 took the larger)."""
    env = BodyEnv(name, physics="c", stale_kinematics=True)
    record = recording(name)
    reset, after = jax.jit(functools.partial(_sgrl_steps, env))(
        exact_data(env, record["reset_qpos"], record["reset_qvel"]),
        jnp.asarray(record["reset_target"], jnp.float32),
        exact_data(env, record["qpos"], record["qvel"]),
        jnp.asarray(_action(env, record["action"])),
        jnp.asarray(record["after_reset"]),
        jnp.asarray(record["target"], jnp.float32),
    )
    np.testing.assert_allclose(
        np.asarray(reset).reshape(len(reset), -1), record["reset_obs"], atol=1e-6, err_msg="reset"
    )
    steps = len(record["reward"])
    np.testing.assert_allclose(np.asarray(after.data.qpos), record["qpos_after"], atol=1e-4, err_msg="qpos")
    np.testing.assert_allclose(np.asarray(after.data.qvel), record["qvel_after"], atol=1e-4, err_msg="qvel")
    observation = np.asarray(after.observation).reshape(steps, -1)
    np.testing.assert_allclose(observation, record["obs"], atol=5e-5, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(after.reward), record["reward"], atol=2e-6)
    np.testing.assert_array_equal(np.asarray(after.terminated), record["done"])


@pytest.mark.parametrize("name", [name for name in THREE_D if name not in FIRST_TASK])
def test_near_target_reset_observations_equal_sgrls(name):
    """The _v2 bodies: every recorded reset observation (the direction to a target 10-20 m away)."""
    env = BodyEnv(name, physics="c")
    record = recording(name)
    key = jnp.zeros(2, jnp.uint32)
    observe = jax.jit(jax.vmap(lambda data, target: env.start(data, None, (target, key)).observation))
    reset = observe(
        exact_data(env, record["reset_qpos"], record["reset_qvel"]),
        jnp.asarray(record["reset_target"], jnp.float32),
    )
    np.testing.assert_allclose(np.asarray(reset).reshape(len(reset), -1), record["reset_obs"], atol=1e-6)
    assert np.all(np.linalg.norm(record["reset_target"], axis=1) < 20.0)


def _state(env: BodyEnv, qpos=None, qvel=None):
    state = env.reset(jax.random.key(0))
    data = state.data
    if qpos is not None:
        data = data.replace(qpos=jnp.asarray(qpos, jnp.float32))
    if qvel is not None:
        data = data.replace(qvel=jnp.asarray(qvel, jnp.float32))
    return state.replace(data=env.kinematics(data))


def _rotation(axis: str, angle: float) -> np.ndarray:
    quaternion = np.zeros(4)
    quaternion[0], quaternion["xyz".index(axis) + 1] = np.cos(angle / 2), np.sin(angle / 2)
    return quaternion


def test_3d_termination_conditions():
    """Each family's conditions, on states built to break one of them."""
    walker = BodyEnv("3d_walker_7_full", physics="c")
    upright = _state(walker)
    assert bool(walker.task.alive(upright.data, upright.data))
    for axis, breaks in (("y", True), ("x", True), ("z", False)):  # pitch, roll; heading is free
        qpos = np.asarray(upright.data.qpos).copy()
        qpos[3:7] = _rotation(axis, 1.05)
        tilted = _state(walker, qpos)
        assert bool(walker.task.alive(tilted.data, upright.data)) != breaks, "read at the step's start"
        assert bool(walker.task.alive(upright.data, tilted.data)), axis

    hopper = BodyEnv("3d_hopper_5_full", physics="c")
    standing = _state(hopper)
    qpos = np.asarray(standing.data.qpos).copy()
    qpos[3:7] = _rotation("x", 1.05)
    assert not bool(hopper.task.alive(standing.data, _state(hopper, qpos).data)), "tilted after the step"
    qpos[3:7], qpos[2] = _rotation("z", 2.0), 0.9
    assert not bool(hopper.task.alive(standing.data, _state(hopper, qpos).data)), "below 0.95"
    qpos[2] = 1.0
    assert bool(hopper.task.alive(standing.data, _state(hopper, qpos).data))

    cheetah = BodyEnv("3d_cheetah_14_full", physics="c")
    moving = _state(cheetah, qvel=np.full(cheetah.mj_model.nv, 0.3))
    assert bool(cheetah.task.alive(moving.data, moving.data))
    still = _state(cheetah, qvel=np.full(cheetah.mj_model.nv, 0.1))
    assert not bool(cheetah.task.alive(moving.data, still.data)), "sum(qvel^2) must stay above 1"
    qpos = np.asarray(moving.data.qpos).copy()
    qpos[2], qpos[3:7] = 0.35, _rotation("y", 0.4)  # low, nose down: a front thigh below 0.26, the torso not
    dipped = _state(cheetah, qpos, np.full(cheetah.mj_model.nv, 0.3))
    thigh = cheetah.morphology.limb_names.index("right_fthigh") + 1
    assert float(dipped.data.xpos[thigh, 2]) < 0.26 < float(dipped.data.qpos[2])
    assert not bool(cheetah.task.alive(moving.data, dipped.data))


def test_3d_reset_faces_a_random_heading_with_a_target_at_its_distance():
    for name, low, high in (("3d_hopper_3_shin", 1e4, 1e4), ("3d_hopper_v2_3_shin", 10.0, 20.0)):
        env = BodyEnv(name, physics="c")
        states = jax.vmap(env.reset)(jax.random.split(jax.random.key(1), 64))
        distance = np.linalg.norm(np.asarray(states.target), axis=1)
        assert np.all((distance >= low * 0.9999) & (distance <= high * 1.0001)), name
        headings = np.asarray(jax.vmap(lambda q: heading_pitch_roll(q)[0])(states.data.qpos[:, 3:7]))
        assert headings.min() < -2.5 and headings.max() > 2.5, "headings spread over the circle"
        direction = np.asarray(states.observation[:, 0, 6:8])
        expected = -np.asarray(states.data.xpos[:, 1, :2]) + np.asarray(states.target)
        np.testing.assert_allclose(
            direction, expected / np.linalg.norm(expected, axis=1, keepdims=True), atol=1e-5
        )


def test_a_reached_target_is_replaced():
    """Within 1 of the target: a new point, 10-20 from the torso (v2) or 10 km from the origin; the key
    advances only then."""
    key = jax.random.key_data(jax.random.key(3))
    position = jnp.array([5.0, 5.0])
    far = jnp.array([5.5, 5.0])
    for task, origin in ((NEAR_TARGET, position), (FAR_TARGET, jnp.zeros(2))):
        target, new_key = next_target(task, far, key, position)
        distance = float(jnp.linalg.norm(target - origin))
        assert task.distance[0] * 0.9999 <= distance <= task.distance[1] * 1.0001
        assert not np.array_equal(new_key, key)
    target, same_key = next_target(NEAR_TARGET, far + 2.0, key, position)
    np.testing.assert_array_equal(target, far + 2.0)
    np.testing.assert_array_equal(same_key, key)


@pytest.mark.slow
def test_3d_body_on_mjx_follows_mujoco_c():
    """Physics "jax" (MJX, ``mjx.step`` for the free torso) and "c" from the same reset, under the same
    random actions: observation, reward and termination agree in float32 over 5 steps."""
    name = "3d_hopper_3_shin"
    on_c, on_mjx = BodyEnv(name, physics="c"), BodyEnv(name, physics="jax")
    c_state, mjx_state = on_c.reset(jax.random.key(0)), jax.jit(on_mjx.reset)(jax.random.key(0))
    np.testing.assert_allclose(mjx_state.observation, c_state.observation, atol=1e-6)
    np.testing.assert_array_equal(mjx_state.target, c_state.target)
    actions = jax.random.uniform(jax.random.key(1), (5, *on_c.action_shape), minval=-1.0, maxval=1.0)
    step = jax.jit(on_mjx.step)
    for action in actions:
        c_state, mjx_state = on_c.step(c_state, action), step(mjx_state, action)
        np.testing.assert_allclose(mjx_state.observation, c_state.observation, atol=1e-4)
        np.testing.assert_allclose(mjx_state.reward, c_state.reward, atol=1e-5)
        assert bool(mjx_state.terminated) == bool(c_state.terminated)


def test_variants_of_a_3d_body_step_in_one_environment(tmp_path):
    """Drawn variants of a 3D body (three hinges per limb) run through the body's environment: each reads
    its own hinge ranges into the observation."""
    from swat_jax.morphology.variants import Variation, write_variants

    variants = write_variants("3d_hopper_3_shin", 2, Variation(0.2, seed=1), tmp_path)
    env = BodyEnv("3d_hopper_3_shin", physics="c", variants=variants)
    table = env.variant_table()
    assert table.joint_range.shape == (2, 3, 3, 2)
    for row, variant in enumerate(variants):
        state = env.reset(jax.random.key(0), jax.tree.map(lambda leaf, row=row: leaf[row], table))
        state = env.step(state, jnp.zeros(env.action_shape))
        ends = np.asarray(state.observation[1, 27:36]).reshape(3, 3)[:, 1:]  # the thigh's range ends
        np.testing.assert_allclose(ends, (180.0 + np.array(variant.joint_ranges[1])) / 360.0, atol=1e-6)
        assert variant.family == env.morphology.family, "a variant keeps its body's termination"


def test_a_folder_mixing_planar_and_3d_bodies_is_refused(tmp_path):
    """Both have four limb types, but 19 and 41 observation values per limb: the folder names both."""
    import shutil

    from swat_jax.morphology import MorphologyError

    for name in ("hopper_3", "3d_hopper_3_shin"):
        shutil.copy(MORPHOLOGY_DIR / f"{name}.xml", tmp_path)
    shutil.copytree(MORPHOLOGY_DIR / "assets", tmp_path / "assets")
    with pytest.raises(MorphologyError, match="planar and 3D") as error:
        get_set(tmp_path)
    assert "hopper_3.xml: family hopper, 4 limb types, planar" in str(error.value)
    assert "3d_hopper_3_shin.xml: family 3d_hopper, 4 limb types, 3D" in str(error.value)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            ('<joint name="root" type="free"', '<joint name="root" type="slide" axis="1 0 0"'),
            "needs exactly one joint, a free joint",
        ),
        (
            (
                '<joint name="thigh_joint_z"',
                '<joint name="thigh_joint_w" axis="1 1 0" range="-5 5"/>\n<joint name="thigh_joint_z"',
            ),
            "at most 3 hinges",
        ),
        (
            (
                'gear="200"/>\n    <motor joint="foot_joint_z" gear="200"',
                'gear="200"/>\n    <motor joint="foot_joint_z" gear="0"',
            ),
            None,
        ),
    ],
)
def test_3d_body_files_are_checked(tmp_path, edit, message):
    """A 3D family's body needs a free torso and at most three hinges per limb; gear-0 motors are allowed
    beside a driven hinge (the benchmark's own)."""
    import shutil

    from swat_jax.morphology import MorphologyError

    text = (MORPHOLOGY_DIR / "3d_hopper_3_shin.xml").read_text()
    assert edit[0] in text
    (tmp_path / "body.xml").write_text(text.replace(edit[0], edit[1]))
    shutil.copytree(MORPHOLOGY_DIR / "assets", tmp_path / "assets")
    if message is None:
        assert load(tmp_path / "body.xml").limb_motors[2] == (3, 4, 5)
    else:
        with pytest.raises(MorphologyError, match=message):
            load(tmp_path / "body.xml")
