"""The training iteration (collect a chunk in every task, then update) is one program, traced once."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.td3.iteration import (
    IterationConfig,
    exploration_scales,
    init_seeded_train_state,
    init_train_state,
    make_seeded_train_iteration,
    make_train_iteration,
    seed_keys,
)
from swat_jax.td3.learner import Learner, TD3Config

CONFIG = IterationConfig(chunk=4, updates=3, random_steps=8, capacity=64, schedule="all_tasks")
"""Every update on a batch from every task (tests/test_update_schedule.py tests the original schedule)."""


NETWORK = network_config("amorpheus", width=16, layers=1, feedforward=32)
STRUCTURE = task_set(["hopper_3"], NETWORK, max_limbs=4).structure


def tiny_learner() -> tuple[MultiTaskEnv, Learner]:
    env = MultiTaskEnv(["hopper_3"], copies=2, max_limbs=4)
    actor, critic = make_actor_critic(NETWORK, 19)
    return env, Learner(actor, critic, TD3Config(batch_size=8))


@pytest.fixture(scope="module")
def single_seed_run():
    """Three iterations of the plain (seedless) iteration from seed 6, with its trace count: the initial
    actor, the final state and the last metrics."""
    env, learner = tiny_learner()
    iteration = make_train_iteration(env, STRUCTURE, learner, CONFIG)
    traces = []

    def counted(state):
        traces.append(1)
        return iteration(state)

    step = jax.jit(counted)
    state = jax.jit(lambda key: init_train_state(env, learner, CONFIG, key))(jax.random.PRNGKey(6))
    first_actor = state.learner.actor_params
    sizes = []
    for _ in range(3):  # past the random steps and the first updates, actor steps included
        state, metrics = step(state)
        sizes.append(int(state.buffer.size))
    return traces, sizes, first_actor, state, metrics


def test_iteration_traces_once_collects_inserts_and_learns(single_seed_run):
    traces, sizes, first_actor, state, metrics = single_seed_run
    assert sizes == [8, 16, 24]
    assert len(traces) == 1, "the iteration must compile once"
    assert int(state.env_steps) == 3 * CONFIG.chunk * 2
    assert int(state.learner.updates) == 3 * CONFIG.updates
    assert metrics["critic_loss"].shape == (CONFIG.updates,)
    assert metrics["reward"].shape == (CONFIG.chunk, 1, 2)
    assert np.isfinite(np.asarray(metrics["critic_loss"])).all() and float(metrics["critic_loss"][-1]) > 0
    moved = jax.tree_util.tree_map(np.array_equal, state.learner.actor_params, first_actor)
    assert not all(jax.tree_util.tree_leaves(moved))
    stored = np.asarray(state.buffer.data.observation[0, :24])
    assert np.abs(stored[:, :3]).sum(axis=(1, 2)).min() > 0 and not stored[:, 3:].any(), "padding stays 0"


def test_seed_k_of_a_multi_seed_run_is_the_single_seed_run_with_seed_k(single_seed_run):
    """The seeds' environments step as runs of one state, their copies folded into one physics batch."""
    *_, alone, alone_metrics = single_seed_run
    env, learner = tiny_learner()
    seeded = jax.jit(make_seeded_train_iteration(env, STRUCTURE, learner, CONFIG))
    init = jax.jit(lambda keys: init_seeded_train_state(env, learner, CONFIG, keys))
    state = init(seed_keys(5, 3))
    for _ in range(3):
        state, metrics = seeded(state)
    assert state.env_steps.shape == state.learner.updates.shape == (), "step counters are shared"
    assert metrics["critic_loss"].shape == (3, CONFIG.updates)
    per_seed = {
        "actor": (state.learner.actor_params, alone.learner.actor_params),
        "critic": (state.learner.critic_params, alone.learner.critic_params),
        "replay": (state.buffer.data, alone.buffer.data),
        "observation": (state.env.observation, alone.env.observation),
    }
    for name, (seeds, one) in per_seed.items():
        for a, b in zip(jax.tree_util.tree_leaves(seeds), jax.tree_util.tree_leaves(one), strict=True):
            np.testing.assert_allclose(a[1], b, rtol=1e-4, atol=1e-5, err_msg=name)
    np.testing.assert_allclose(metrics["critic_loss"][1], alone_metrics["critic_loss"], rtol=1e-4)
    losses = np.asarray(metrics["critic_loss"][:, -1])
    assert len(set(losses.tolist())) == 3, "every seed is its own run"


def test_a_one_seed_run_is_the_plain_iteration_with_a_seed_axis(single_seed_run):
    """One seed skips vmap (make_seeded_train_iteration): the plain iteration's run, to float32 rounding (the
    two programs compile separately; under the suite's load they differed by 6e-11 after 3 iterations)."""
    *_, alone, alone_metrics = single_seed_run
    env, learner = tiny_learner()
    seeded = jax.jit(make_seeded_train_iteration(env, STRUCTURE, learner, CONFIG))
    state = jax.jit(lambda keys: init_seeded_train_state(env, learner, CONFIG, keys))(seed_keys(6, 1))
    for _ in range(3):
        state, metrics = seeded(state)
    assert state.env_steps.shape == () and state.rng.shape[0] == 1
    for a, b in zip(
        jax.tree_util.tree_leaves(state.learner), jax.tree_util.tree_leaves(alone.learner), strict=True
    ):
        one = a[0] if a.shape != b.shape else a  # the step counter has no seed axis
        np.testing.assert_allclose(one, b, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(state.env.observation[0], alone.env.observation, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(metrics["critic_loss"][0], alone_metrics["critic_loss"], rtol=1e-5)


def test_each_copy_explores_with_its_own_noise_scale():
    """With exploration_noise_max, copy j's actions are the policy's plus noise of std spread evenly from
    exploration_noise (copy 0, here 0: the policy itself) to the maximum (FastTD3's per-environment noise)."""
    copies, chunk = 4, 40
    config = IterationConfig(
        chunk=chunk, updates=1, random_steps=0, capacity=256, schedule="all_tasks",
        exploration_noise=0.0, exploration_noise_max=0.3,
    )  # fmt: skip
    np.testing.assert_allclose(exploration_scales(config, copies), [0.0, 0.1, 0.2, 0.3], atol=1e-7)
    np.testing.assert_allclose(exploration_scales(CONFIG, 3), [CONFIG.exploration_noise] * 3)
    env = MultiTaskEnv(["hopper_3"], copies=copies, max_limbs=4)
    actor, critic = make_actor_critic(NETWORK, 19)
    learner = Learner(actor, critic, TD3Config(batch_size=1024))  # no update: the actor stays the initial one
    state = jax.jit(lambda key: init_train_state(env, learner, config, key))(jax.random.PRNGKey(2))
    state, _ = jax.jit(make_train_iteration(env, STRUCTURE, learner, config))(state)
    stored = jax.tree_util.tree_map(lambda x: np.asarray(x[0, : chunk * copies]), state.buffer.data)
    policy = np.asarray(
        actor.apply(
            state.learner.actor_params, stored.observation, jax.tree_util.tree_map(lambda x: x[0], STRUCTURE)
        )
    )
    residual = (stored.action - policy)[:, :3].reshape(chunk, copies, 3)  # rows: step-major, then copy
    np.testing.assert_allclose(residual[:, 0], 0.0, atol=1e-6)
    spread = np.sqrt(np.mean(residual**2, axis=(0, 2)))  # clipping to [-1, 1] only shrinks it
    np.testing.assert_allclose(spread[1:], [0.1, 0.2, 0.3], rtol=0.3)
    assert spread[1] < spread[2] < spread[3]
