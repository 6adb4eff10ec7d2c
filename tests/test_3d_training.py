"""Training on 3D bodies: three actions per limb through the networks, the environments, exploration and
a whole (tiny) run, evaluated with its targets recorded for a video."""

from __future__ import annotations

import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MORPHOLOGIES, tiny_train_config

from swat_jax.envs import MultiTaskEnv
from swat_jax.morphology import get_set, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.networks.policies import action_mask

HOPPERS = get_set("3d_hopper").train
FEATURES = 41
LIMBS = 6
"""One more than the largest 3D hopper: a padded limb in every body."""


@pytest.fixture(scope="module")
def structures():
    return jax.tree.map(jnp.asarray, pad_structures([load(name) for name in HOPPERS], LIMBS))


@pytest.mark.parametrize("name", ["swat", "amorpheus", "smp"])
def test_networks_act_and_judge_each_hinge_of_a_3d_limb(name, structures):
    """The actor writes [batch, limbs, 3] in [-1, 1], 0 for the torso and padding; the critic's Q of a limb
    moves with each of that limb's three actions."""
    actor, critic = make_actor_critic(network_config(name, width=16, feedforward=32), FEATURES, motors=3)
    actor_params = jax.jit(actor.init)(jax.random.key(0))
    critic_params = jax.jit(critic.init)(jax.random.key(1))
    one = jax.tree.map(lambda leaf: leaf[2], structures)  # 3d_hopper_5_full: 5 limbs, 1 padded
    observation = jax.random.normal(jax.random.key(2), (4, LIMBS, FEATURES))
    actions = jax.jit(actor.apply)(actor_params, observation, one)
    assert actions.shape == (4, LIMBS, 3)
    assert np.all(np.abs(actions) <= 1) and np.any(actions != 0)
    np.testing.assert_array_equal(actions[:, 0], 0.0)  # the torso
    np.testing.assert_array_equal(actions[:, 5], 0.0)  # padding
    np.testing.assert_array_equal(action_mask(one), np.asarray(one.motor_mask))

    def limb_q(action_of_limb_1: jax.Array) -> jax.Array:
        q1, _ = critic.apply(critic_params, observation[:1], actions[:1].at[0, 1].set(action_of_limb_1), one)
        return q1.sum()

    sensitivity = jax.jit(jax.grad(limb_q))(jnp.zeros(3))
    assert np.all(np.abs(np.asarray(sensitivity)) > 0), "every hinge's action reaches the critic"


def test_multi_task_env_steps_3d_bodies_with_three_actions_per_limb():
    """[K, n, L, 3] actions: each body reads its own limbs' slots; a padded limb's and the torso's are
    ignored (the same state follows from any values there)."""
    env = MultiTaskEnv(HOPPERS, copies=2, physics="c", max_limbs=LIMBS)
    assert env.action_shape == (2, LIMBS, 3) and env.observation_features == FEATURES
    state = jax.jit(env.reset)(jax.random.key(0))
    action = jax.random.uniform(jax.random.key(1), (3, *env.action_shape), minval=-1.0, maxval=1.0)
    step = jax.jit(env.step)
    stepped, result = step(state, action)
    noisy = action.at[:, :, 0].set(0.7).at[:, :, LIMBS - 1].set(-0.3)
    again, _ = step(state, noisy)
    np.testing.assert_array_equal(stepped.observation, again.observation)
    assert result.reward.shape == (3, 2) and np.all(np.isfinite(result.reward))
    assert stepped.bodies[0].target.shape == (2, 2)


@pytest.fixture(scope="module")
def hopper_3d_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hopper_3d")
    shutil.copy(MORPHOLOGIES / "3d_hopper_3_shin.xml", folder)
    shutil.copytree(MORPHOLOGIES / "assets", folder / "assets")
    return folder


@pytest.mark.slow
def test_a_3d_run_trains_and_its_evaluation_records_the_targets(hopper_3d_folder, tmp_path):
    """A tiny run on a folder holding one 3D body: the policy it saves acts with three values per limb (as
    loaded, and exported to a file), and a recorded evaluation keeps the target of every pose."""
    from swat_jax.eval import evaluate
    from swat_jax.export import export_policy
    from swat_jax.runs.trained import load_policy
    from swat_jax.serving import load as load_exported
    from swat_jax.train import train

    run_dir = tmp_path / "run"
    train(tiny_train_config(run_dir, hopper_3d_folder, steps=200, seeds=1, eval_interval=0), progress=False)
    policy = load_policy(run_dir)
    assert policy.info.motors_per_limb == 3 and policy.info.observation_features == FEATURES
    body = str(hopper_3d_folder / "3d_hopper_3_shin.xml")
    (result,) = evaluate(policy, [body], episodes=1, record=True)
    assert result.qpos.shape[0] == result.lengths[0, 0] == result.targets.shape[0] > 1
    np.testing.assert_array_equal(result.targets, np.broadcast_to(result.targets[0], result.targets.shape))
    assert np.linalg.norm(result.targets[0]) == pytest.approx(10_000, rel=1e-5), "a far target stays put"

    export_policy(run_dir, tmp_path / "policy.npz", platforms=("cpu",))
    exported = load_exported(tmp_path / "policy.npz")
    observation = np.random.default_rng(0).normal(size=(2, 3, FEATURES)).astype(np.float32)
    one = jax.tree.map(lambda leaf: leaf[0], policy.task_set([body]).structure)
    actions = np.asarray(exported(observation, one))
    assert actions.shape == (2, 3, 3)
    np.testing.assert_allclose(actions, policy.act(jnp.asarray(observation), one), atol=1e-6)
