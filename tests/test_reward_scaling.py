"""Per-task reward scaling: the return statistics, the running discounted return, and an update that does not
depend on a body's reward units."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.runs.checkpoint import CheckpointInfo, Checkpoints, flatten
from swat_jax.runs.config import PRESETS, ConfigError
from swat_jax.td3.iteration import IterationConfig, init_train_state, make_train_iteration, seed_keys
from swat_jax.td3.learner import Learner, TD3Config
from swat_jax.td3.replay import Transitions
from swat_jax.td3.reward_scaling import RETURN_BOUND, ReturnStats, discounted_returns
from swat_jax.td3.schedules import make_update_phase

NETWORK = network_config("swat", width=16, layers=1, feedforward=32)
BODIES = ["hopper_3", "hopper_4"]
FEATURES = 19
"""A 2D limb's observation features."""


def test_discounted_returns_reset_at_episode_ends_and_hold_while_a_seed_waits():
    running = jnp.array([[[1.0, 2.0]], [[3.0, 4.0]]])  # [S=2, K=1, n=2]
    reward = jnp.array([[[0.5, 1.0]], [[1.0, 1.0]]])
    ended = jnp.array([[[False, True]], [[True, True]]])
    now, carried = discounted_returns(running, reward, ended, jnp.array([True, False]), 0.5)
    np.testing.assert_allclose(now, [[[1.0, 2.0]], [[3.0, 4.0]]])
    np.testing.assert_allclose(carried, [[[1.0, 0.0]], [[3.0, 4.0]]], err_msg="seed 1 waited: kept")


def test_return_stats_are_the_moments_and_peak_of_every_seen_return():
    rng = np.random.default_rng(0)
    first, second = rng.normal(3.0, 2.0, (5, 3, 4)), rng.normal(-1.0, 5.0, (6, 3, 4))  # [steps, K, n]
    seen = np.ones(6, bool)
    seen[2] = False
    stats = ReturnStats.zeros(3).merged(jnp.asarray(first), jnp.ones(5, bool))
    stats = stats.merged(jnp.asarray(second), jnp.asarray(seen))
    every = np.concatenate([first, second[seen]])  # [steps, K, n]
    np.testing.assert_allclose(stats.mean, every.mean(axis=(0, 2)), rtol=1e-5)
    np.testing.assert_allclose(stats.variance, every.var(axis=(0, 2)), rtol=1e-4)
    np.testing.assert_allclose(stats.peak, np.abs(every).max(axis=(0, 2)), rtol=1e-6)
    assert float(stats.count) == every.shape[0] * 4
    np.testing.assert_allclose(stats.divisor(), np.sqrt(every.var(axis=(0, 2))), rtol=1e-4)


def test_the_divisor_bounds_the_largest_scaled_return():
    stats = ReturnStats(
        mean=jnp.zeros(2), variance=jnp.array([4.0, 0.0]), count=jnp.ones(()), peak=jnp.array([5.0, 30.0])
    )
    np.testing.assert_allclose(stats.divisor(), [2.0, 30.0 / RETURN_BOUND], rtol=1e-6)
    np.testing.assert_allclose(ReturnStats.zeros(2).divisor(), [1.0, 1.0], rtol=1e-6)


@pytest.fixture(scope="module")
def two_bodies():
    tasks = task_set(BODIES, NETWORK, max_limbs=5)
    actor, critic = make_actor_critic(NETWORK, FEATURES)
    return tasks.structure, actor, critic


def _batch(key: jax.Array, structure) -> Transitions:
    tasks, limbs = structure.limb_mask.shape
    keys = jax.random.split(key, 5)
    observation = (
        jax.random.normal(keys[0], (tasks, 8, limbs, FEATURES)) * structure.limb_mask[:, None, :, None]
    )
    return Transitions(
        observation=observation,
        action=jax.random.uniform(keys[1], (tasks, 8, limbs), minval=-1.0, maxval=1.0),
        reward=jax.random.normal(keys[2], (tasks, 8)),
        next_observation=jax.random.normal(keys[3], observation.shape)
        * structure.limb_mask[:, None, :, None],
        terminated=jnp.zeros((tasks, 8)),
    )


def _critic_after_update(learner: Learner, returns: jax.Array, batch: Transitions, structure):
    state = learner.init(jax.random.key(0), tasks=2)
    state = learner.observe_returns(state, returns, jnp.ones(returns.shape[0], bool))
    updated, _ = jax.jit(learner.update)(state, batch, structure, jax.random.key(2))
    return updated.critic_params


@pytest.mark.parametrize("scaling", [True, False])
def test_a_body_in_other_reward_units_gets_the_same_update_with_scaling(two_bodies, scaling):
    """hopper_3's rewards (and so its returns) 40x larger: with reward scaling the TD targets the critic sees
    are the same, so is its update; without, they are not (the test can fail)."""
    structure, actor, critic = two_bodies
    learner = Learner(actor, critic, TD3Config(batch_size=8, reward_scaling=scaling))
    returns = jax.random.normal(jax.random.key(3), (30, 2, 4)) * 5.0 + 20.0  # [steps, K, n]
    batch = _batch(jax.random.key(1), structure)
    units = jnp.array([40.0, 1.0])
    base = _critic_after_update(learner, returns, batch, structure)
    louder = _critic_after_update(
        learner, returns * units[:, None], batch.replace(reward=batch.reward * units[:, None]), structure
    )
    close = jax.tree.map(lambda a, b: np.allclose(a, b, rtol=1e-4, atol=1e-6), base, louder)
    assert all(jax.tree.leaves(close)) == scaling


def test_statistics_of_another_number_of_tasks_are_refused(two_bodies):
    """Statistics of one task against a batch of two would divide both bodies' rewards by one divisor."""
    structure, actor, critic = two_bodies
    learner = Learner(actor, critic, TD3Config(batch_size=8, reward_scaling=True))
    state = learner.init(jax.random.key(0))
    with pytest.raises(ValueError, match=r"2 tasks against return statistics of 1: .*tasks=2"):
        learner.update(state, _batch(jax.random.key(1), structure), structure, jax.random.key(2))
    with pytest.raises(ValueError, match=r"2 tasks against return statistics of 1"):
        learner.observe_returns(state, jnp.ones((3, 2, 4)), jnp.ones(3, bool))


@pytest.fixture(scope="module")
def iterating(two_bodies):
    """The first state and the jitted iteration of 6 steps, 2 copies per body on MuJoCo C, with reward
    scaling."""
    structure, actor, critic = two_bodies
    env = MultiTaskEnv(BODIES, copies=2, max_limbs=5, physics="c")
    learner = Learner(actor, critic, TD3Config(batch_size=4, reward_scaling=True))
    config = IterationConfig(chunk=6, updates=2, random_steps=100, capacity=64, loop="all_tasks")
    return init_train_state(env, learner, config, seed_keys(0, 1)), make_train_iteration(
        env, structure, learner, config
    )


def test_the_iteration_keeps_the_statistics_of_every_copys_discounted_return(iterating):
    """One iteration from the start: the statistics hold every step's G of both copies, recomputed here from
    the iteration's rewards (no random-action hopper falls within 6 steps), and the state carries each copy's
    G on."""
    start, iteration = iterating
    state, metrics = iteration(start)
    assert int(metrics["episodes"].count.sum()) == 0, "no episode ended: G is never reset"
    reward = np.asarray(metrics["reward"][0])  # [chunk, K, n]
    returns = np.zeros_like(reward)
    for step in range(reward.shape[0]):
        returns[step] = reward[step] + (TD3Config().discount * returns[step - 1] if step else 0.0)
    stats = state.learner.returns
    np.testing.assert_allclose(stats.mean[0], returns.mean(axis=(0, 2)), rtol=1e-5)
    np.testing.assert_allclose(stats.variance[0], returns.var(axis=(0, 2)), rtol=1e-4)
    np.testing.assert_allclose(state.discounted_return[0], returns[-1], rtol=1e-5)
    assert float(stats.count[0]) == 12


@pytest.mark.slow
def test_a_checkpoint_carries_the_statistics_and_running_returns_on(iterating, tmp_path):
    """Saved after one iteration and restored into a fresh state, the run goes on as if uninterrupted: the
    return statistics and every copy's G so far come back (a fresh state's would scale the next rewards
    otherwise)."""
    start, iteration = iterating
    state, _ = iteration(start)
    checkpoints = Checkpoints(tmp_path)
    info = CheckpointInfo(
        env_steps=24,
        iterations=1,
        seconds=0.0,
        seeds=(0,),
        bodies=tuple(BODIES),
        max_limbs=5,
        observation_features=FEATURES,
    )
    checkpoints.save(state, {}, info)
    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    restored, _ = checkpoints.restore(start, jax.tree.map(lambda _: device, start))
    checkpoints.close()
    assert not np.array_equal(restored.learner.returns.mean, start.learner.returns.mean)
    uninterrupted, resumed = flatten(iteration(state)[0]), flatten(iteration(restored)[0])
    assert [key for key in uninterrupted if not np.array_equal(uninterrupted[key], resumed[key])] == []


def test_reward_scaling_needs_the_all_task_update(two_bodies):
    structure, actor, critic = two_bodies
    learner = Learner(actor, critic, TD3Config(batch_size=4, reward_scaling=True))
    with pytest.raises(ValueError, match=r"reward scaling .* needs the all_tasks schedule"):
        make_update_phase(structure, learner, "original", updates=2, seeds=1)
    paper, fast = PRESETS["paper"], PRESETS["fast"]
    with pytest.raises(ConfigError, match=r"--td3\.reward-scaling .* add --iteration\.loop all_tasks"):
        dataclasses.replace(paper, td3=dataclasses.replace(paper.td3, reward_scaling=True))
    assert dataclasses.replace(
        fast, td3=dataclasses.replace(fast.td3, reward_scaling=True)
    ).td3.reward_scaling
