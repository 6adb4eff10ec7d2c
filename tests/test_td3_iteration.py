"""The training iteration (collect a chunk in every task, then update) is one program, traced once."""

from __future__ import annotations

import jax
import numpy as np

from swat_jax.envs import MultiTaskEnv
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.td3.iteration import IterationConfig, init_train_state, make_train_iteration
from swat_jax.td3.learner import Learner, TD3Config

CONFIG = IterationConfig(chunk=4, updates=3, random_steps=8, capacity=64)


def test_iteration_traces_once_collects_inserts_and_learns():
    env = MultiTaskEnv(["hopper_3"], copies=2, max_limbs=4)
    actor, critic = make_actor_critic(network_config("amorpheus", width=16, layers=1, feedforward=32), 19)
    learner = Learner(actor, critic, TD3Config(batch_size=8))
    iteration = make_train_iteration(env, learner, CONFIG)
    traces = []

    def counted(state):
        traces.append(1)
        return iteration(state)

    step = jax.jit(counted)
    state = init_train_state(env, learner, CONFIG, jax.random.PRNGKey(0))
    first_actor = state.learner.actor_params
    for expected_size in (8, 16, 24):
        state, metrics = step(state)
        assert int(state.buffer.size) == expected_size
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
