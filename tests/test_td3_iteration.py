"""The training iteration (collect a chunk in every task, then update) is one program, traced once."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from swat_jax import axes
from swat_jax.envs import MultiTaskEnv
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.td3.iteration import (
    IterationConfig,
    exploration_scales,
    init_train_state,
    make_train_iteration,
    seed_keys,
)
from swat_jax.td3.learner import Learner, TD3Config

CONFIG = IterationConfig(chunk=4, updates=3, random_steps=8, capacity=64, loop="all_tasks")
"""Every update on a batch from every task (tests/test_update_schedule.py tests the original schedule)."""


NETWORK = network_config("amorpheus", width=16, layers=1, feedforward=32)
STRUCTURE = task_set(["hopper_3"], NETWORK, max_limbs=4).structure


def tiny_learner() -> tuple[MultiTaskEnv, Learner]:
    env = MultiTaskEnv(["hopper_3"], copies=2, max_limbs=4, physics="c")
    actor, critic = make_actor_critic(NETWORK, 19)
    return env, Learner(actor, critic, TD3Config(batch_size=8))


@pytest.fixture(scope="module")
def single_seed_run():
    """Three iterations of a one-seed run from seed 6 (the seed's slice, no vmap), with its trace count: the
    initial actor, the final state and the last metrics."""
    env, learner = tiny_learner()
    iteration = make_train_iteration(env, STRUCTURE, learner, CONFIG)
    traces = []

    def counted(state):
        traces.append(1)
        return iteration(state)

    step = jax.jit(counted)
    state = jax.jit(lambda keys: init_train_state(env, learner, CONFIG, keys))(seed_keys(6, 1))
    first_actor = state.learner.actor_params
    sizes = []
    for _ in range(3):  # past the random steps and the first updates, actor steps included
        state, metrics = step(state)
        sizes.append(int(state.buffer.size[0]))
    return traces, sizes, first_actor, state, metrics


def test_iteration_traces_once_collects_inserts_and_learns(single_seed_run):
    traces, sizes, first_actor, state, metrics = single_seed_run
    assert sizes == [8, 16, 24]
    assert len(traces) == 1, "the iteration must compile once"
    assert int(state.steps_per_task) == 3 * CONFIG.chunk * 2
    assert int(state.learner.critic_steps) == 3 * CONFIG.updates
    assert metrics["critic_loss"].shape == (1, CONFIG.updates)
    assert metrics["reward"].shape == (1, CONFIG.chunk, 1, 2)
    assert np.isfinite(np.asarray(metrics["critic_loss"])).all() and float(metrics["critic_loss"][0, -1]) > 0
    moved = jax.tree_util.tree_map(np.array_equal, state.learner.actor_params, first_actor)
    assert not all(jax.tree_util.tree_leaves(moved))
    stored = np.asarray(state.buffer.data.observation[0, 0, :24])
    assert np.abs(stored[:, :3]).sum(axis=(1, 2)).min() > 0 and not stored[:, 3:].any(), "padding stays 0"


def test_seed_k_of_a_multi_seed_run_is_the_single_seed_run_with_seed_k(single_seed_run):
    """The seeds' environments step as seeds of one state, their copies folded into one physics batch, and the
    per-seed pieces are vmapped (three seeds) where one seed takes its slice: the same run, to float32
    rounding."""
    *_, alone, alone_metrics = single_seed_run
    env, learner = tiny_learner()
    seeded = jax.jit(make_train_iteration(env, STRUCTURE, learner, CONFIG))
    init = jax.jit(lambda keys: init_train_state(env, learner, CONFIG, keys))
    state = init(seed_keys(5, 3))
    for _ in range(3):
        state, metrics = seeded(state)
    assert state.steps_per_task.shape == state.learner.critic_steps.shape == (), "step counters are shared"
    assert metrics["critic_loss"].shape == (3, CONFIG.updates)
    per_seed = {
        "actor": (state.learner.actor_params, alone.learner.actor_params),
        "critic": (state.learner.critic_params, alone.learner.critic_params),
        "replay": (state.buffer.data, alone.buffer.data),
        "observation": (state.env.observation, alone.env.observation),
    }
    for name, (seeds, one) in per_seed.items():
        for a, b in zip(jax.tree_util.tree_leaves(seeds), jax.tree_util.tree_leaves(one), strict=True):
            np.testing.assert_allclose(a[1], b[0], rtol=1e-4, atol=1e-5, err_msg=name)
    np.testing.assert_allclose(metrics["critic_loss"][1], alone_metrics["critic_loss"][0], rtol=1e-4)
    losses = np.asarray(metrics["critic_loss"][:, -1])
    assert len(set(losses.tolist())) == 3, "every seed is its own run"


def test_each_copy_explores_with_its_own_noise_scale():
    """With exploration_noise_max, copy j's actions are the policy's plus noise of std spread evenly from
    exploration_noise (copy 0, here 0: the policy itself) to the maximum (FastTD3's per-environment noise)."""
    copies, chunk = 4, 40
    config = IterationConfig(
        chunk=chunk, updates=1, random_steps=0, capacity=256, loop="all_tasks",
        exploration_noise=0.0, exploration_noise_max=0.3,
    )  # fmt: skip
    np.testing.assert_allclose(exploration_scales(config, copies), [0.0, 0.1, 0.2, 0.3], atol=1e-7)
    np.testing.assert_allclose(exploration_scales(CONFIG, 3), [CONFIG.exploration_noise] * 3)
    env = MultiTaskEnv(["hopper_3"], copies=copies, max_limbs=4, physics="c")
    actor, critic = make_actor_critic(NETWORK, 19)
    learner = Learner(actor, critic, TD3Config(batch_size=1024))  # no update: the actor stays the initial one
    state = jax.jit(lambda keys: init_train_state(env, learner, config, keys))(seed_keys(2, 1))
    state, _ = jax.jit(make_train_iteration(env, STRUCTURE, learner, config))(state)
    stored = jax.tree_util.tree_map(lambda x: np.asarray(x[0, 0, : chunk * copies]), state.buffer.data)
    actor_params = jax.tree_util.tree_map(lambda x: x[0], state.learner.actor_params)
    policy = np.asarray(
        actor.apply(actor_params, stored.observation, jax.tree_util.tree_map(lambda x: x[0], STRUCTURE))
    )
    residual = (stored.action - policy)[:, :3].reshape(chunk, copies, 3)  # rows: step-major, then copy
    np.testing.assert_allclose(residual[:, 0], 0.0, atol=1e-6)
    spread = np.sqrt(np.mean(residual**2, axis=(0, 2)))  # clipping to [-1, 1] only shrinks it
    np.testing.assert_allclose(spread[1:], [0.1, 0.2, 0.3], rtol=0.3)
    assert spread[1] < spread[2] < spread[3]


def declared(state, prefix) -> list:
    """(array, axis) for every array of ``state``, ``axis`` from the axes prefix ``prefix`` of it."""
    full = jax.tree_util.tree_broadcast(prefix, state, is_leaf=lambda x: x is None)
    pairs = []
    jax.tree_util.tree_map(
        lambda leaf, axis: pairs.append((leaf, axis)) if leaf is not None else None,
        state,
        full,
        is_leaf=lambda x: x is None,
    )
    return pairs


def test_the_axes_declared_with_the_fields_are_the_arrays_axes():
    """swat_jax.axes reads the axes where the state's fields declare them: every seeded array leads with the
    4 seeds and the shared ones are counters; the task axes have the 2 bodies and the copy axes the 3 copies."""
    env = MultiTaskEnv(["hopper_3", "cheetah_4_front"], copies=3, max_limbs=5)
    _, learner = tiny_learner()
    state = jax.eval_shape(lambda keys: init_train_state(env, learner, CONFIG, keys), seed_keys(0, 4))
    seeds = declared(state, axes.seed_axes(state))
    assert all(leaf.shape[0] == 4 for leaf, axis in seeds if axis == 0)
    shared = [leaf for leaf, axis in seeds if axis is None]
    assert len(shared) == 2 and all(leaf.shape == () for leaf in shared), "the step counters"
    for tasks, copies, size, at_least in ((True, False, 2, 6), (False, True, 3, 20)):
        split = [
            (leaf, axis)
            for leaf, axis in declared(state, axes.split_axes(state, tasks, copies))
            if axis is not None
        ]
        assert len(split) >= at_least
        assert all(leaf.shape[1 + axis] == size for leaf, axis in split), (tasks, copies)
