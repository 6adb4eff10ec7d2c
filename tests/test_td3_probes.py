"""TD3 probes with known answers (in the style of rejax): the learner must find them in seconds.

Each probe draws fresh transitions from a tiny known process for two tasks with different limb counts
(padded to 5 limbs), runs the jitted update in a ``lax.scan``, and checks the critic's per-limb Q values
or the actor's actions against the exact answer.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import XLA_DEFAULTS

from swat_jax.morphology import load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.td3.learner import Learner, LearnerState, TD3Config, project
from swat_jax.td3.replay import Transitions

FEATURES = 3
BATCH = 64
STRUCTURE = pad_structures([load("hopper_3"), load("cheetah_4_front")], max_limbs=5)
MASK = np.asarray(STRUCTURE.limb_mask)


def learner(discount: float = 0.5, atoms: int = 0) -> Learner:
    """With ``atoms``: a distributional critic on [-2, 3] (every probe's values lie inside)."""
    config = network_config("amorpheus", width=32, heads=2, layers=1, feedforward=64)
    actor, critic = make_actor_critic(config, FEATURES, atoms)
    td3 = TD3Config(
        discount=discount, learning_rate=3e-3, max_grad_norm=10.0, batch_size=BATCH,
        atoms=atoms, value_min=-2.0, value_max=3.0,
    )  # fmt: skip
    return Learner(actor, critic, td3)


def random_batch(rng: jax.Array, *, reward: jax.Array, terminated: jax.Array) -> Transitions:
    """Observations uniform in [-1, 1], random actions; reward [T, B] from ``REWARDS[reward](obs, action)``."""
    keys = jax.random.split(rng, 3)
    shape = (2, BATCH, 5)
    mask = jnp.asarray(MASK)[:, None, :]
    observation = jnp.where(mask[..., None], jax.random.uniform(keys[0], (*shape, FEATURES), minval=-1), 0.0)
    action = jnp.where(mask, jax.random.uniform(keys[1], shape, minval=-1), 0.0)
    next_observation = jnp.where(
        mask[..., None], jax.random.uniform(keys[2], (*shape, FEATURES), minval=-1), 0.0
    )
    return Transitions(
        observation=observation,
        action=action,
        reward=jax.lax.switch(reward, REWARDS, observation, action),
        next_observation=next_observation,
        terminated=jnp.full(shape[:2], terminated),
    )


class ProbeRun(NamedTuple):
    initial: LearnerState
    """Before the first update."""
    state: LearnerState
    """After the last update."""
    metrics: dict[str, jax.Array]
    """Per update [updates]."""
    probe: Transitions
    """A fresh batch of the process to check the answer on."""


MAX_UPDATES = 2000


@functools.partial(jax.jit, static_argnums=(0,), compiler_options=XLA_DEFAULTS)
def train_program(td3: Learner, reward: jax.Array, terminated: jax.Array, updates: jax.Array) -> ProbeRun:
    """One program for every probe: the reward function (an index into REWARDS), termination and the number
    of updates (at most MAX_UPDATES; the scan skips the rest) are inputs, not constants."""

    def one_update(state, step_and_rng):
        step, rng = step_and_rng
        batch_key, noise_key = jax.random.split(rng)
        batch = random_batch(batch_key, reward=reward, terminated=terminated)
        return jax.lax.cond(
            step < updates,
            lambda s: td3.update(s, batch, STRUCTURE, noise_key),
            lambda s: (s, {"critic_loss": jnp.zeros(()), "actor_loss": jnp.zeros(())}),
            state,
        )

    initial = td3.init(jax.random.PRNGKey(0))
    steps = (jnp.arange(MAX_UPDATES), jax.random.split(jax.random.PRNGKey(1), MAX_UPDATES))
    state, metrics = jax.lax.scan(one_update, initial, steps)
    probe = random_batch(jax.random.PRNGKey(2), reward=reward, terminated=terminated)
    return ProbeRun(initial, state, metrics, probe)


def train(td3: Learner, reward_fn, terminated: bool, updates: int) -> ProbeRun:
    """``updates`` TD3 updates on fresh batches of the process with ``reward_fn``; metrics [updates]."""
    assert updates <= MAX_UPDATES
    run = train_program(td3, jnp.int32(REWARDS.index(reward_fn)), jnp.bool_(terminated), jnp.int32(updates))
    return run._replace(metrics=jax.tree_util.tree_map(lambda leaf: leaf[:updates], run.metrics))


def critic_values(td3: Learner, state, batch: Transitions) -> np.ndarray:
    """Per-limb Q1 on real limbs [T, B, L] (NaN on padding); a distributional critic's mean."""
    q1, _ = jax.vmap(td3._q_values, in_axes=(None, 0, 0, 0))(
        state.critic_params, batch.observation, batch.action, STRUCTURE
    )
    return np.where(MASK[:, None, :], np.asarray(q1), np.nan)


def constant_reward(observation, action):
    return jnp.ones(action.shape[:2])


def limb_mean_reward(observation, action):
    """The mean over real limbs of the first feature (a permutation-invariant value any network can read)."""
    mask = jnp.asarray(MASK)[:, None, :]
    return jnp.where(mask, observation[..., 0], 0.0).sum(-1) / mask.sum(-1)


def matching_reward(observation, action):
    """-mean over real limbs of (a - obs[..., 0] * 0.8)^2: the best action is 0.8 * the first feature."""
    mask = jnp.asarray(MASK)[:, None, :]
    error = jnp.where(mask, (action - 0.8 * observation[..., 0]) ** 2, 0.0)
    return -error.sum(-1) / mask.sum(-1)


REWARDS = (constant_reward, limb_mean_reward, matching_reward)


@pytest.mark.slow
@pytest.mark.parametrize("terminated, expected", [(True, 1.0), (False, 2.0)])
def test_critic_learns_the_value_of_a_constant_reward(terminated, expected):
    """Terminal: Q = 1. Truncated (bootstrapping), discount 0.5: Q = 1 / (1 - 0.5) = 2."""
    td3 = learner()
    _, state, metrics, probe = train(td3, constant_reward, terminated, 1500)
    q = critic_values(td3, state, probe)
    assert np.nanmean(np.abs(q - expected)) < 0.1, np.nanmean(q)
    assert float(metrics["critic_loss"][-100:].mean()) < float(metrics["critic_loss"][:100].mean())


@pytest.mark.slow
def test_a_distributional_critic_learns_the_values_and_the_actor_the_best_action_from_it():
    """C51 (21 atoms on [-2, 3]): the constant reward's bootstrapped Q (2: the atoms moved by the reward and
    shrunk by the discount), and the best action through the distribution's mean. The two runs share one
    program; the terminal case's mask is the plain critic's (test_critic_learns_the_value_of_a_constant_reward)."""
    td3 = learner(atoms=21)
    _, state, metrics, probe = train(td3, constant_reward, False, 1500)
    q = critic_values(td3, state, probe)
    assert np.nanmean(np.abs(q - 2.0)) < 0.1, np.nanmean(q)
    assert float(metrics["critic_loss"][-100:].mean()) < float(metrics["critic_loss"][:100].mean())
    _, state, _, probe = train(td3, matching_reward, True, 2000)
    action = jax.vmap(td3.actor.apply, in_axes=(None, 0, 0))(state.actor_params, probe.observation, STRUCTURE)
    error = np.abs(np.asarray(action) - 0.8 * np.asarray(probe.observation[..., 0]))
    assert error[np.broadcast_to(MASK[:, None, :], error.shape)].mean() < 0.1


def test_the_projection_keeps_probability_and_mean_and_clips_to_the_support():
    support = jnp.linspace(-1.0, 1.0, 5)  # spacing 0.5
    probabilities = jnp.array([0.1, 0.2, 0.3, 0.25, 0.15])
    moved = 0.3 + 0.5 * support  # inside the support: r + discount * z
    projected = np.asarray(project(probabilities, moved, support))
    assert projected.min() >= 0 and projected.sum() == pytest.approx(1.0, abs=1e-6)
    assert projected @ np.asarray(support) == pytest.approx(float(probabilities @ moved), abs=1e-6)
    on_atoms = project(jnp.array([0.0, 1.0, 0.0, 0.0, 0.0]), support + 0.5, support)
    np.testing.assert_allclose(on_atoms, [0.0, 0.0, 1.0, 0.0, 0.0], atol=1e-6)
    between = project(jnp.array([1.0, 0.0, 0.0, 0.0, 0.0]), support + 0.1, support)
    np.testing.assert_allclose(between, [0.8, 0.2, 0.0, 0.0, 0.0], atol=1e-6)
    beyond = project(probabilities, support + 10.0, support)
    np.testing.assert_allclose(beyond, [0.0, 0.0, 0.0, 0.0, 1.0], atol=1e-6)


@pytest.mark.slow
def test_critic_learns_an_observation_dependent_value():
    td3 = learner()
    _, state, _, probe = train(td3, limb_mean_reward, True, 1500)
    q = critic_values(td3, state, probe)
    expected = np.asarray(limb_mean_reward(probe.observation, probe.action))[..., None]
    assert np.nanmean(np.abs(q - expected)) < 0.1


def test_actor_learns_the_best_action_per_limb():
    td3 = learner()
    _, state, _, probe = train(td3, matching_reward, True, 2000)
    action = jax.vmap(td3.actor.apply, in_axes=(None, 0, 0))(state.actor_params, probe.observation, STRUCTURE)
    best = 0.8 * np.asarray(probe.observation[..., 0])
    error = np.abs(np.asarray(action) - best)[np.broadcast_to(MASK[:, None, :], best.shape)]
    assert error.mean() < 0.1, error.mean()
    np.testing.assert_array_equal(np.asarray(action)[~np.broadcast_to(MASK[:, None, :], best.shape)], 0.0)


def unchanged(after, before) -> bool:
    """Every array equal to within 1e-6: XLA may compute the initial parameters twice in one program, in
    two fusions that round differently (1e-7 apart measured); one TD3 step moves a target 1.5e-5 (tau x
    Adam's first step, the learning rate) and the networks 3e-3."""
    close = jax.tree_util.tree_map(lambda a, b: np.allclose(a, b, rtol=0, atol=1e-6), after, before)
    return all(jax.tree_util.tree_leaves(close))


def test_actor_and_targets_update_every_second_step():
    td3 = learner()
    initial, state, _, _ = train(td3, constant_reward, True, 1)
    assert unchanged(state.actor_params, initial.actor_params), "after one update the actor has not moved"
    assert unchanged(state.target_critic_params, initial.target_critic_params)
    assert not unchanged(state.critic_params, initial.critic_params), "the critic moves at every update"
    _, state, _, _ = train(td3, constant_reward, True, 2)
    assert not unchanged(state.actor_params, initial.actor_params), "after two updates the actor has moved"
    assert not unchanged(state.target_critic_params, initial.target_critic_params)
    assert int(state.critic_steps) == 2


@pytest.mark.parametrize("pessimism", [1.0, 0.5, 0.0])
def test_the_target_bootstraps_from_the_lower_or_the_mean_of_the_two_target_critics(pessimism):
    """Pessimism 1 (clipped double Q): y = r + discount * min(Q1', Q2'); 0: r + discount * (Q1' + Q2') / 2;
    0.5 halfway between. The two critics' initial weights differ, so the three targets differ."""
    base = learner()
    td3 = Learner(base.actor, base.critic, dataclasses.replace(base.config, target_pessimism=pessimism))
    state = td3.init(jax.random.PRNGKey(0))
    batch = jax.tree.map(
        lambda leaf: leaf[0], random_batch(jax.random.PRNGKey(3), reward=0, terminated=False)
    )
    structure = jax.tree.map(lambda leaf: leaf[0], STRUCTURE)
    no_noise = jnp.zeros(batch.action.shape)
    loss = td3._task_critic_loss(
        state.critic_params, state.target_actor_params, state.target_critic_params, batch, structure, no_noise
    )
    next_action = jnp.where(
        structure.limb_mask,
        td3.actor.apply(state.target_actor_params, batch.next_observation, structure),
        0.0,
    )
    next1, next2 = td3._q_values(state.target_critic_params, batch.next_observation, next_action, structure)
    gap = np.abs(np.asarray(next1 - next2))[:, MASK[0]]
    assert gap.mean() > 1e-2, "the probe needs two target critics that disagree"
    lower, mean = jnp.minimum(next1, next2), (next1 + next2) / 2
    next_value = pessimism * lower + (1 - pessimism) * mean
    target = batch.reward[:, None] + td3.config.discount * next_value
    q1, q2 = td3._q_values(state.critic_params, batch.observation, batch.action, structure)
    squared = np.where(MASK[0], np.asarray((q1 - target) ** 2 + (q2 - target) ** 2), 0.0)
    assert float(loss) == pytest.approx(squared.sum() / (MASK[0].sum() * BATCH), rel=1e-5)


def limb_mean_action(observation, action):
    """The mean over real limbs of the action: every limb's best action is +1, tanh's bound."""
    mask = jnp.asarray(MASK)[:, None, :]
    return jnp.where(mask, action, 0.0).sum(-1) / mask.sum(-1)


REWARDS = (*REWARDS, limb_mean_action)


def penalised(action_penalty: float, action_penalty_from: float = 0.0) -> Learner:
    base = learner()
    td3 = dataclasses.replace(
        base.config, action_penalty=action_penalty, action_penalty_from=action_penalty_from
    )
    return Learner(base.actor, base.critic, td3)


@pytest.mark.parametrize("start", [0.0, 0.5])
def test_the_action_penalty_adds_the_mean_square_of_the_motors_pre_tanh_outputs(start):
    """Actor loss with penalty w from s = the loss without + w x the mean over the batch and the real motors
    (not the torso, not padding) of max(|u| - s, 0)^2, u the pre-tanh outputs; without one, TD3's
    -mean Q1(s, pi(s))."""
    plain, weighted = penalised(0.0), penalised(0.25, start)
    state = plain.init(jax.random.PRNGKey(0))
    batch = random_batch(jax.random.PRNGKey(3), reward=0, terminated=True)
    loss = plain._actor_loss(state.actor_params, state.critic_params, batch, STRUCTURE)
    with_penalty = weighted._actor_loss(state.actor_params, state.critic_params, batch, STRUCTURE)
    outputs = np.asarray(
        jax.vmap(plain.actor.apply, in_axes=(None, 0, 0, None))(
            state.actor_params, batch.observation, STRUCTURE, False
        )
    )
    motors = np.asarray(STRUCTURE.motor_mask[..., 0])
    assert motors.sum(-1).tolist() == [2, 3], "hopper_3 and cheetah_4_front: every limb but the torso"
    real = np.broadcast_to(motors[:, None, :], outputs.shape)
    assert 0.1 < np.mean(np.abs(outputs[real]) > 0.5) < 0.9, "outputs on both sides of 0.5"
    excess = np.maximum(np.abs(outputs) - start, 0.0)
    squares = np.where(real, excess**2, 0.0).sum((1, 2)) / (motors.sum(-1) * BATCH)
    assert float(with_penalty - loss) == pytest.approx(0.25 * squares.mean(), rel=1e-5)
    actions = np.tanh(outputs)
    q1, _ = jax.vmap(plain._q_values, in_axes=(None, 0, 0, 0))(
        state.critic_params, batch.observation, jnp.asarray(actions), STRUCTURE
    )
    values = np.where(MASK[:, None, :], np.asarray(q1), 0.0).sum((1, 2)) / (MASK.sum(-1) * BATCH)
    assert float(loss) == pytest.approx(-values.mean(), rel=1e-5)


@pytest.mark.slow
def test_the_action_penalty_holds_the_policy_off_its_bounds_where_the_critic_pushes_it():
    """Reward: the mean action over a body's L real limbs (terminal), so Q = that mean and each motor's best
    action is tanh's bound. Without a penalty the policy saturates; with weight w, each motor's output u
    settles where the gradients balance, (1 / L) (1 - tanh(u)^2) = 2 w u / M (M = L - 1 motors): tanh(u)
    0.81 on hopper_3, 0.83 on cheetah_4_front at w = 0.1 (the learned critic's slope is not exactly 1 / L:
    0.02-0.04 above measured)."""
    motors = np.asarray(STRUCTURE.motor_mask[..., 0])
    for action_penalty in (0.0, 0.1):
        td3 = penalised(action_penalty)
        _, state, _, probe = train(td3, limb_mean_action, True, 1500)
        outputs = np.asarray(
            jax.vmap(td3.actor.apply, in_axes=(None, 0, 0, None))(
                state.actor_params, probe.observation, STRUCTURE, False
            )
        )
        actions = np.tanh(outputs)
        if not action_penalty:
            assert np.mean(actions[np.broadcast_to(motors[:, None, :], actions.shape)] >= 0.99) > 0.9
            continue
        grid = np.linspace(0.01, 3.0, 30_000)
        for task, limbs in enumerate(MASK.sum(-1)):
            gap = np.abs((1 - np.tanh(grid) ** 2) / limbs - 2 * action_penalty * grid / (limbs - 1))
            balance = np.tanh(grid[np.argmin(gap)])
            assert actions[task][:, motors[task]].mean() == pytest.approx(balance, abs=0.1), (task, balance)
            assert actions[task][:, motors[task]].max() < 0.95
