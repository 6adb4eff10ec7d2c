"""n-step returns (``--td3.n-step``): the replay sums each sampled row's next rewards of the same copy, cut
at the episode's end and at the newest row, and the critic bootstraps with discount^m."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.morphology import load, pad_structures
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.runs.config import PRESETS, ConfigError
from swat_jax.td3.iteration import IterationConfig, init_train_state, make_train_iteration, seed_keys
from swat_jax.td3.learner import Learner, TD3Config
from swat_jax.td3.replay import Transitions, init_buffer, insert, sample, sample_n_step

COPIES, CAPACITY, STEPS_TAKEN, LIMBS, FEATURES, DISCOUNT = 2, 9, 7, 2, 1, 0.5
TERMINATED_AT = {(2, 0)}
"""(step, copy) whose episode terminated there."""
TRUNCATED_AT = {(4, 1)}
"""(step, copy) whose episode hit the time limit there (ended, not terminated)."""


def code(step: int, copy: int) -> float:
    return 10.0 * step + copy


def reward(step: int, copy: int) -> float:
    return 1.0 + step + 0.1 * copy


def step_batch(step: int) -> Transitions:
    """One insert: every copy's step ``step`` of one task, its observation encoding (step, copy)."""
    codes = jnp.asarray([[code(step, copy) for copy in range(COPIES)]], jnp.float32)
    ended = [[(step, copy) in TERMINATED_AT | TRUNCATED_AT for copy in range(COPIES)]]
    return Transitions(
        observation=jnp.broadcast_to(codes[..., None, None], (1, COPIES, LIMBS, FEATURES)),
        action=jnp.zeros((1, COPIES, LIMBS)),
        reward=jnp.asarray([[reward(step, copy) for copy in range(COPIES)]], jnp.float32),
        next_observation=jnp.broadcast_to(-codes[..., None, None], (1, COPIES, LIMBS, FEATURES)),
        terminated=jnp.asarray([[(step, copy) in TERMINATED_AT for copy in range(COPIES)]]),
        ended=jnp.asarray(ended),
    )


def expected(step: int, copy: int, n: int) -> tuple[float, float, float, bool]:
    """(return, bootstrap, next observation code, terminated) of the row of (step, copy), by the definition."""
    total, scale = 0.0, 1.0
    for later in range(step, min(step + n, STEPS_TAKEN)):
        total += scale * reward(later, copy)
        scale *= DISCOUNT
        if (later, copy) in TERMINATED_AT | TRUNCATED_AT:
            break
    return total, scale, -code(later, copy), (later, copy) in TERMINATED_AT


@pytest.fixture(scope="module")
def buffer():
    """14 rows into a ring of 9 (not a multiple of the copies): the oldest five are overwritten."""
    buffer = init_buffer(1, CAPACITY, LIMBS, FEATURES, episode_ends=True)
    for step in range(STEPS_TAKEN):
        buffer = insert(buffer, step_batch(step))
    return buffer


@pytest.mark.parametrize("n", [1, 3])
def test_each_sampled_row_sums_its_copys_next_rewards_up_to_the_episodes_end_and_the_newest_row(buffer, n):
    sampled = jax.jit(sample_n_step, static_argnums=(2, 3, 4, 5))(
        buffer, jax.random.key(0), 256, n, DISCOUNT, COPIES
    )
    seen = set()
    for i, value in enumerate(np.asarray(sampled.observation[0, :, 0, 0])):
        step, copy = divmod(int(value), 10)
        seen.add((step, copy))
        total, bootstrap, next_code, terminated = expected(step, copy, n)
        assert float(sampled.reward[0, i]) == pytest.approx(total), (step, copy)
        assert float(sampled.bootstrap[0, i]) == pytest.approx(bootstrap), (step, copy)
        assert float(sampled.next_observation[0, i, 0, 0]) == next_code, (step, copy)
        assert bool(sampled.terminated[0, i]) == terminated, (step, copy)
    assert len(seen) == CAPACITY, "every stored row is drawn"
    assert sampled.ended is None


def test_one_step_sampling_equals_the_plain_sample(buffer):
    plain = sample(buffer, jax.random.key(1), 64)
    n_step = sample_n_step(buffer, jax.random.key(1), 64, 1, DISCOUNT, COPIES)
    for field in ("observation", "action", "reward", "next_observation", "terminated"):
        np.testing.assert_array_equal(getattr(n_step, field), getattr(plain, field))
    np.testing.assert_array_equal(n_step.bootstrap, np.full((1, 64), DISCOUNT, np.float32))


@pytest.mark.slow
def test_the_critic_bootstraps_with_the_sampled_discount():
    """A batch whose bootstrap is 0.9 everywhere gives the loss of a learner whose discount is 0.9."""
    structure = pad_structures([load("hopper_3"), load("cheetah_4_front")], max_limbs=5)
    config = network_config("amorpheus", width=16, heads=2, layers=1, feedforward=32)
    actor, critic = make_actor_critic(config, 3)
    keys = jax.random.split(jax.random.key(0), 4)
    shape = (2, 8, 5)
    mask = jnp.asarray(structure.limb_mask)[:, None, :]
    batch = Transitions(
        observation=jnp.where(mask[..., None], jax.random.normal(keys[0], (*shape, 3)), 0.0),
        action=jnp.where(mask, jax.random.uniform(keys[1], shape, minval=-1.0), 0.0),
        reward=jax.random.normal(keys[2], shape[:2]),
        next_observation=jnp.where(mask[..., None], jax.random.normal(keys[3], (*shape, 3)), 0.0),
        terminated=jnp.zeros(shape[:2], bool),
    )

    def critic_loss(discount: float, sampled: Transitions) -> float:
        learner = Learner(actor, critic, TD3Config(discount=discount, batch_size=8))
        state = learner.init(jax.random.key(1))
        _, metrics = learner.update(state, sampled, structure, jax.random.key(2))
        return float(metrics["critic_loss"])

    with_bootstrap = batch.replace(bootstrap=jnp.full(shape[:2], 0.9))
    assert critic_loss(0.5, with_bootstrap) == pytest.approx(critic_loss(0.9, batch), rel=1e-6)
    assert critic_loss(0.5, with_bootstrap) != pytest.approx(critic_loss(0.5, batch), rel=1e-3)


def test_n_step_needs_the_all_task_schedule():
    paper = PRESETS["paper"]
    with pytest.raises(ConfigError, match=r"--td3\.n-step 3 .*--iteration\.loop all_tasks"):
        dataclasses.replace(paper, td3=dataclasses.replace(paper.td3, n_step=3))
    with pytest.raises(ConfigError, match=r"--td3\.n-step must be a positive"):
        dataclasses.replace(paper, td3=dataclasses.replace(paper.td3, n_step=0))
    fast = PRESETS["fast"]
    assert dataclasses.replace(fast, td3=dataclasses.replace(fast.td3, n_step=3)).td3.n_step == 3


def test_a_training_run_stores_episode_ends_in_each_copys_consecutive_rows():
    """The iteration with n-step returns: each copy's step t + 1 is ``copies`` rows after its step t, which
    continues from the state that step reached unless the episode ended there (then a new episode starts);
    the updates run on n-step batches."""
    copies, chunk = 3, 40
    config = IterationConfig(chunk=chunk, updates=2, random_steps=1_000, capacity=256, loop="all_tasks")
    env = MultiTaskEnv(["hopper_3"], copies=copies, max_limbs=4, physics="c")
    network = network_config("amorpheus", width=8, layers=1, feedforward=16)
    actor, critic = make_actor_critic(network, 19)
    learner = Learner(actor, critic, TD3Config(batch_size=8, n_step=3))
    structure = task_set(["hopper_3"], network, max_limbs=4).structure
    state = init_train_state(env, learner, config, seed_keys(0, 1))
    step = jax.jit(make_train_iteration(env, structure, learner, config))
    for _ in range(2):
        state, metrics = step(state)
    data = jax.tree.map(lambda leaf: np.asarray(leaf[0, 0, : 2 * chunk * copies]), state.buffer.data)
    assert np.array_equal(data.ended, data.terminated), "random hoppers fall long before the time limit"
    assert 0 < data.ended.sum() < len(data.ended) // 4
    rows = np.arange(len(data.ended) - copies)
    continued = np.all(data.observation[rows + copies] == data.next_observation[rows], axis=(1, 2))
    np.testing.assert_array_equal(continued, ~data.ended[rows])
    assert np.isfinite(np.asarray(metrics["critic_loss"])).all()
