"""Observation normalisation (swat_jax/networks/observation_stats.py): the running statistics, the map the
actor and critic apply, training that accumulates them in all four networks without a gradient moving
them, and an exported policy that carries them."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax import export
from swat_jax.envs import MultiTaskEnv
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.networks.observation_stats import NORMALISER, STATS, STD_EPSILON, accumulate, with_stats
from swat_jax.td3.iteration import IterationConfig, init_train_state, make_train_iteration, seed_keys
from swat_jax.td3.learner import Learner, TD3Config

NETWORK = network_config("swat", width=16, layers=1, feedforward=32, observation_normalisation=True)
PLAIN = dataclasses.replace(NETWORK, observation_normalisation=False)
STRUCTURE = task_set(["hopper_3"], NETWORK, max_limbs=5).structure
"""hopper_3's 3 limbs padded to 5."""
BODY = jax.tree.map(lambda field: field[0], STRUCTURE)
LIMBS = 3


def test_the_padded_body_has_the_limbs_the_tests_assume():
    assert np.asarray(STRUCTURE.limb_mask).tolist() == [[True] * LIMBS + [False] * 2]


def test_the_statistics_are_the_mean_and_variance_of_every_real_limb_seen():
    rng = np.random.default_rng(0)
    first, second = rng.normal(3.0, 2.0, (5, 2, 4, 6)), rng.normal(-1.0, 0.5, (7, 2, 4, 6))
    mask = np.array([[True, True, True, False], [True, False, False, False]])  # [bodies, limbs]
    stats = {"mean": jnp.zeros(6), "variance": jnp.ones(6), "count": jnp.zeros(())}
    for chunk in (first, second):
        stats = accumulate(stats, jnp.asarray(chunk, jnp.float32), mask)
    real = np.concatenate([first[:, mask], second[:, mask]]).reshape(-1, 6)
    assert float(stats["count"]) == len(real) == 48, "padded limbs are not counted"
    np.testing.assert_allclose(stats["mean"], real.mean(0), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(stats["variance"], real.var(0), rtol=1e-4)
    unchanged = accumulate(stats, jnp.ones((3, 2, 4, 6)), np.zeros((2, 4), bool))
    assert jax.tree.all(jax.tree.map(np.array_equal, unchanged, stats)), "no real limb, no change"


def test_actor_and_critic_standardise_each_feature_with_their_statistics():
    actor, critic = make_actor_critic(NETWORK, 19)
    plain_actor, plain_critic = make_actor_critic(PLAIN, 19)
    rng = np.random.default_rng(1)
    stats = {
        "mean": jnp.asarray(rng.normal(size=19), jnp.float32),
        "variance": jnp.asarray(rng.uniform(0.5, 4.0, 19), jnp.float32),
        "count": jnp.float32(10),
    }
    actor_variables = actor.init(jax.random.key(0))
    assert set(actor_variables[STATS][NORMALISER]) == {"mean", "variance", "count"}
    assert jax.tree.structure(actor_variables["params"]) == jax.tree.structure(
        plain_actor.init(jax.random.key(0))["params"]
    ), "the normaliser has no parameters"
    actor_variables = with_stats(actor_variables, stats)
    critic_variables = with_stats(critic.init(jax.random.key(1)), stats)
    observation = np.asarray(rng.normal(size=(3, 5, 19)), np.float32)
    observation[:, LIMBS:] = 0.0
    mean, variance = np.asarray(stats["mean"]), np.asarray(stats["variance"])
    standardised = (observation - mean) / (np.sqrt(variance) + STD_EPSILON)
    standardised[:, LIMBS:] = 0.0
    actions = actor.apply(actor_variables, observation, BODY)
    np.testing.assert_allclose(
        actions, plain_actor.apply({"params": actor_variables["params"]}, standardised, BODY), atol=1e-6
    )
    q_values = critic.apply(critic_variables, observation, actions, BODY)
    expected = plain_critic.apply({"params": critic_variables["params"]}, standardised, actions, BODY)
    np.testing.assert_allclose(q_values, expected, rtol=1e-5, atol=1e-5)
    assert not np.allclose(
        actions, plain_actor.apply({"params": actor_variables["params"]}, observation, BODY)
    )


@pytest.mark.slow
def test_training_accumulates_the_statistics_in_all_four_networks_and_no_gradient_moves_them():
    """Two seeds, three iterations of 4 steps of 2 copies (the updates begin after the first): each seed's
    statistics are those of its replay's 24 rows, in actor, critic and both targets, after the last
    update moved the actor."""
    env = MultiTaskEnv(["hopper_3"], copies=2, max_limbs=5, physics="c")
    actor, critic = make_actor_critic(NETWORK, 19)
    learner = Learner(actor, critic, TD3Config(batch_size=8))
    config = IterationConfig(chunk=4, updates=3, random_steps=8, capacity=64, loop="all_tasks")
    iteration = jax.jit(make_train_iteration(env, STRUCTURE, learner, config))
    state = init_train_state(env, learner, config, seed_keys(0, 2))
    before = state.learner.actor_params["params"]
    for _ in range(3):
        state, _ = iteration(state)
    assert int(state.learner.critic_steps) > 0
    assert not jax.tree.all(jax.tree.map(np.array_equal, state.learner.actor_params["params"], before))
    networks = ("actor_params", "critic_params", "target_actor_params", "target_critic_params")
    for seed in range(2):
        stored = np.asarray(state.buffer.data.observation[seed, 0, :24, :LIMBS]).reshape(-1, 19)
        for network in networks:
            stats = getattr(state.learner, network)[STATS][NORMALISER]
            assert float(stats["count"][seed]) == 24 * LIMBS, network
            np.testing.assert_allclose(stats["mean"][seed], stored.mean(0), rtol=1e-4, atol=1e-5)
            np.testing.assert_allclose(stats["variance"][seed], stored.var(0), rtol=1e-3, atol=1e-5)


def test_an_exported_policy_carries_the_statistics():
    actor, _ = make_actor_critic(NETWORK, 19)
    stats = {"mean": jnp.full(19, 0.5), "variance": jnp.full(19, 4.0), "count": jnp.float32(3)}
    variables = with_stats(actor.init(jax.random.key(2)), stats)
    program = jax.export.deserialize(export.serialize_actor(actor, variables, BODY, ("cpu",)))
    observation = np.asarray(np.random.default_rng(3).normal(size=(2, 5, 19)), np.float32)
    np.testing.assert_allclose(
        program.call(observation, *BODY), actor.apply(variables, observation, BODY), atol=1e-6
    )
