"""A swat_jax body as a MuJoCo Playground environment: its step is BodyEnv's, and Brax's own PPO and SAC
train on it through Playground's wrapper, unmodified."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as ppo
from brax.training.agents.sac import networks as sac_networks
from brax.training.agents.sac import train as sac
from mujoco_playground import wrapper

from swat_jax.adapters.playground import STATE_KEY, PlaygroundBody, restore_device_put_replicated
from swat_jax.envs import BodyEnv


@pytest.mark.parametrize(
    ("name", "switches"),
    [
        ("hopper_3", {"torso_relative_x": False, "stale_kinematics": True}),
        ("3d_hopper_3_shin", {}),
    ],
)
def test_the_adapters_step_is_body_envs(name, switches):
    """From one key and actions, the adapter's states are BodyEnv's: the flattened observation, the reward,
    the termination as done, the simulator state; its actions are the actuators' in MuJoCo's order."""
    env = PlaygroundBody(name, physics="c", **switches)
    body = BodyEnv(name, physics="c", **switches)
    nu, (limbs, features) = env.mj_model.nu, (body.num_limbs, body.observation_features)
    assert env.action_size == nu and env.observation_size == limbs * features
    state, expected = jax.jit(env.reset)(jax.random.key(2)), body.reset(jax.random.key(2))
    step, body_step = jax.jit(env.step), jax.jit(body.step)
    for key in jax.random.split(jax.random.key(5), 8):
        action = jax.random.uniform(key, (nu,), minval=-1.2, maxval=1.2)
        tokens = np.zeros(int(np.prod(body.action_shape)), np.float32)
        tokens[body.motor_actions] = action
        previous_x = expected.data.qpos[0]
        state, expected = step(state, action), body_step(expected, tokens.reshape(body.action_shape))
        np.testing.assert_array_equal(state.obs, np.asarray(expected.observation).reshape(-1))
        np.testing.assert_array_equal(state.data.qpos, expected.data.qpos)
        np.testing.assert_array_equal(state.data.ctrl, np.clip(action, -1, 1))
        assert state.reward == expected.reward and state.done == float(expected.terminated)
        assert state.metrics["reward"] == expected.reward
        assert state.metrics["distance"] == np.float32(expected.data.qpos[0] - previous_x)
        assert state.info[STATE_KEY].episode_length == expected.episode_length
    assert np.ptp(np.asarray(state.obs)) > 0.1


def finite(metrics: dict) -> bool:
    return all(np.all(np.isfinite(np.asarray(value))) for value in metrics.values())


BRAX_RUNS = {
    "ppo": (
        ppo.train,
        dict(
            num_timesteps=800,
            num_envs=4,
            batch_size=4,
            num_minibatches=2,
            unroll_length=10,
            num_updates_per_batch=1,
            network_factory=functools.partial(
                ppo_networks.make_ppo_networks,
                policy_hidden_layer_sizes=(16,),
                value_hidden_layer_sizes=(16,),
            ),
        ),
    ),
    "sac": (
        sac.train,
        dict(
            num_timesteps=400,
            num_envs=4,
            batch_size=16,
            min_replay_size=64,
            max_replay_size=400,
            grad_updates_per_step=1,
            network_factory=functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=(16,)),
        ),
    ),
}
"""Brax's trainers and the settings of a run of seconds each."""


@pytest.mark.parametrize("trainer", BRAX_RUNS)
def test_brax_trains_on_a_body(trainer):
    """Brax's PPO and SAC, unmodified, through Playground's wrapper: a short run on hopper_3 (MuJoCo C) ends
    with finite metrics and a policy that jits."""
    restore_device_put_replicated()
    env = PlaygroundBody("hopper_3", physics="c")
    train, settings = BRAX_RUNS[trainer]
    make_policy, params, metrics = train(
        environment=env,
        episode_length=50,
        num_evals=2,
        num_eval_envs=2,
        wrap_env_fn=wrapper.wrap_for_brax_training,
        seed=0,
        **settings,
    )
    assert metrics and finite(metrics) and "eval/episode_reward" in metrics
    policy = jax.jit(make_policy(params, deterministic=True))
    actions, _ = policy(jnp.zeros((1, env.observation_size)), jax.random.key(0))
    assert actions.shape == (1, env.action_size) and np.all(np.abs(actions) <= 1)
