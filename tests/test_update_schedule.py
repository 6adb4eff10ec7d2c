"""The original update schedule (IterationConfig.schedule, of every loop but all_tasks): after collecting, body after body takes its run of
updates on batches from its own replay ring, the actor stepping at updates 0, 2, ... of every run."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.morphology import limb_buckets, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.runs.config import PRESETS, ConfigError, TrainConfig
from swat_jax.td3.iteration import IterationConfig, init_train_state, make_train_iteration, seed_keys
from swat_jax.td3.learner import Learner, LearnerState, TD3Config
from swat_jax.td3.replay import ReplayBuffer, Transitions, init_buffer, sample
from swat_jax.td3.schedules import make_update_phase

BODIES = ("hopper_3", "cheetah_4_front")
LIMBS = 4
FEATURES = 19
STRUCTURE = pad_structures([load(body) for body in BODIES], max_limbs=LIMBS)
CONFIG = IterationConfig(chunk=4, updates=3, random_steps=8, capacity=64, loop="per_body")
UPDATES = len(BODIES) * CONFIG.updates
"""Updates per iteration: 3 per body."""
ACTOR_STEPS = [0, 2, 3, 5]
"""The updates of an iteration (task-major) with an actor step: it = 0 and 2 of each body's run of 3."""


def bucketed_learner() -> Learner:
    """A tiny AMORPHEUS learner with a limb bucket per body, as a run builds it (policy delay 2, batch 8)."""
    network = network_config("amorpheus", width=16, heads=2, layers=1, feedforward=32)
    actor, critic = make_actor_critic(network, FEATURES)
    buckets = limb_buckets([load(body).num_limbs for body in BODIES], 2)
    return Learner(actor, critic, TD3Config(batch_size=8), buckets)


LEARNER = bucketed_learner()
TASK_UPDATE = jax.jit(dataclasses.replace(LEARNER, buckets=()).update)
"""``Learner.update`` of one task at the padded limb count (limb buckets group tasks of an all-task batch)."""


def adam_steps(optimizer_state: optax.OptState) -> int:
    """The Adam step count of the first seed's optimizer state (clip, then Adam)."""
    return int(np.ravel(optax.tree_utils.tree_get(optimizer_state, "count"))[0])


@pytest.fixture(scope="module")
def env() -> MultiTaskEnv:
    """2 copies per body: the first iteration (4 steps) fills a batch of 8."""
    return MultiTaskEnv(BODIES, copies=2, max_limbs=LIMBS, physics="c")


@pytest.fixture(scope="module")
def single_seed_run(env):
    """Two iterations of a one-seed original-schedule run from seed 6: the initial learner, then the state and
    metrics after each."""
    step = jax.jit(make_train_iteration(env, STRUCTURE, LEARNER, CONFIG))
    state = jax.jit(lambda keys: init_train_state(env, LEARNER, CONFIG, keys))(seed_keys(6, 1))
    initial = state.learner
    after = []
    for _ in range(2):
        state, metrics = step(state)
        after.append((state, metrics))
    return initial, after


def test_an_iteration_trains_body_after_body_with_the_actor_first_in_every_run(single_seed_run):
    initial, after = single_seed_run
    for iteration, (state, metrics) in enumerate(after, start=1):
        assert state.buffer.size.tolist() == [8 * iteration]
        assert int(state.learner.critic_steps) == iteration * UPDATES, "bodies x updates per iteration"
        assert adam_steps(state.learner.critic_optimizer) == iteration * UPDATES
        assert adam_steps(state.learner.actor_optimizer) == iteration * len(ACTOR_STEPS)
        assert metrics["critic_loss"].shape == metrics["actor_loss"].shape == (1, UPDATES)
        assert np.all(np.asarray(metrics["critic_loss"]) > 0)
        stepped = np.flatnonzero(np.asarray(metrics["actor_loss"][0]))
        assert stepped.tolist() == ACTOR_STEPS, "it restarts at 0 for every body and every iteration"
    state, _ = after[0]
    for name in ("actor_params", "target_actor_params", "target_critic_params"):
        moved = jax.tree.map(np.array_equal, getattr(state.learner, name), getattr(initial, name))
        assert not all(jax.tree.leaves(moved)), f"{name} moved in the first iteration"


def random_buffer(rng: jax.Array, rows: int) -> ReplayBuffer:
    """A full buffer of ``rows`` random transitions per body, padding limbs 0."""
    keys = jax.random.split(rng, 5)
    buffer = init_buffer(len(BODIES), rows, LIMBS, FEATURES)
    mask = jnp.asarray(STRUCTURE.limb_mask)[:, None, :]
    shape = buffer.data.action.shape
    data = Transitions(
        observation=jnp.where(mask[..., None], jax.random.normal(keys[0], (*shape, FEATURES)), 0.0),
        action=jnp.where(mask, jax.random.uniform(keys[1], shape, minval=-1.0), 0.0),
        reward=jax.random.normal(keys[2], shape[:2]),
        next_observation=jnp.where(mask[..., None], jax.random.normal(keys[3], (*shape, FEATURES)), 0.0),
        terminated=jax.random.bernoulli(keys[4], 0.1, shape[:2]),
    )
    return ReplayBuffer(data=data, position=jnp.zeros((), jnp.int32), size=jnp.full((), rows, jnp.int32))


def one_task(tree: Any, task: int) -> Any:
    """The slice [1, ...] of task ``task`` of every array of ``tree``."""
    return jax.tree.map(lambda leaf: leaf[task : task + 1], tree)


def by_hand(
    state: LearnerState, buffer: ReplayBuffer, rng: jax.Array, count: int = CONFIG.updates
) -> tuple[LearnerState, list[float]]:
    """The reference code's TD3.train written out: for each body, its run of ``count`` updates on batches
    sampled from its ring alone, ``Learner.update`` on one-task batches with the actor stepping when
    it % policy_delay == 0; with the keys make_update_phase documents. Returns the state and the critic losses in order."""
    keys = jax.random.split(rng, (len(BODIES), CONFIG.updates))
    losses = []
    for task in range(len(BODIES)):
        ring, structure = buffer.replace(data=one_task(buffer.data, task)), one_task(STRUCTURE, task)
        for it in range(count):
            sample_key, noise_key = jax.random.split(keys[task, it])
            batch = sample(ring, sample_key, LEARNER.config.batch_size)
            delayed = jnp.bool_(it % LEARNER.config.policy_delay == 0)
            state, metrics = TASK_UPDATE(state, batch, structure, noise_key, delayed)
            losses.append(float(metrics["critic_loss"]))
    return state, losses


def stacked(trees: list[Any]) -> Any:
    """``trees`` stacked on a new leading (seed) axis."""
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *trees)


def seeded(learners: list[LearnerState], buffers: list[ReplayBuffer]) -> tuple[LearnerState, ReplayBuffer]:
    """One learner state and buffer per seed as a state with a seed axis (the step counters shared)."""
    learner = stacked(learners).replace(critic_steps=learners[0].critic_steps)
    return learner, stacked(buffers)


@pytest.mark.slow
def test_the_per_body_scan_is_the_reference_loop_of_one_task_updates():
    initial = LEARNER.init(jax.random.PRNGKey(0))
    buffer = random_buffer(jax.random.PRNGKey(1), rows=16)
    rng = jax.random.PRNGKey(2)
    update_phase = jax.jit(make_update_phase(STRUCTURE, LEARNER, "original", CONFIG.updates, seeds=1))
    state, metrics = update_phase(*seeded([initial], [buffer]), rng[None])
    expected, losses = by_hand(initial, buffer, rng)
    for got, want in zip(jax.tree.leaves(state), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(got if got.shape == want.shape else got[0], want, rtol=0, atol=1e-6)
    np.testing.assert_allclose(metrics["critic_loss"][0], losses, rtol=1e-5)

    learner, unfilled_buffer = seeded([initial], [buffer.replace(size=jnp.int32(7))])
    unfilled, skipped = update_phase(learner, unfilled_buffer, rng[None])
    assert int(unfilled.critic_steps) == 0 and not np.any(np.asarray(skipped["critic_loss"])), (
        "no update before the buffer holds a batch"
    )


def test_seed_k_of_two_seeds_is_the_reference_loop_of_seed_k():
    """The updates of a two-seed state (every array but the shared step counters has a seed axis;
    tests/test_td3_iteration.py checks the seed axis of collection) are each seed's own."""
    initial = [LEARNER.init(key) for key in jax.random.split(jax.random.PRNGKey(3), 2)]
    buffers = [random_buffer(key, rows=16) for key in jax.random.split(jax.random.PRNGKey(4), 2)]
    rngs = jax.random.split(jax.random.PRNGKey(5), 2)
    update_phase = jax.jit(make_update_phase(STRUCTURE, LEARNER, "original", CONFIG.updates, seeds=2))
    state, metrics = update_phase(*seeded(initial, buffers), rngs)
    assert metrics["critic_loss"].shape == (2, UPDATES) and state.critic_steps.shape == ()
    for seed in range(2):
        expected, losses = by_hand(initial[seed], buffers[seed], rngs[seed])
        for seeds, one in zip(jax.tree.leaves(state), jax.tree.leaves(expected), strict=True):
            one_seed = seeds[seed] if seeds.shape != one.shape else seeds
            np.testing.assert_allclose(one_seed, one, rtol=0, atol=1e-6)
        np.testing.assert_allclose(metrics["critic_loss"][seed], losses, rtol=1e-5)


def test_with_update_counts_each_seed_takes_its_own_number_of_updates_per_body():
    """Lock-step rounds: each seed's bodies take (its counted steps) / K updates, the first of the run's
    slots; the others leave its learner as it is (losses 0), whatever the other seed takes."""
    initial = [LEARNER.init(key) for key in jax.random.split(jax.random.PRNGKey(7), 2)]
    buffers = [random_buffer(key, rows=16) for key in jax.random.split(jax.random.PRNGKey(8), 2)]
    rngs = jax.random.split(jax.random.PRNGKey(9), 2)
    counts = jnp.array([CONFIG.updates, 1], jnp.int32)
    update_phase = make_update_phase(STRUCTURE, LEARNER, "original", CONFIG.updates, seeds=2, counted=True)
    state, metrics = jax.jit(update_phase)(*seeded(initial, buffers), rngs, counts)
    for seed, count in enumerate(counts.tolist()):
        expected, losses = by_hand(initial[seed], buffers[seed], rngs[seed], count)
        for name in ("critic_params", "actor_params", "target_critic_params", "critic_optimizer"):
            for seeds, one in zip(
                jax.tree.leaves(getattr(state, name)), jax.tree.leaves(getattr(expected, name)), strict=True
            ):
                np.testing.assert_allclose(seeds[seed], one, rtol=0, atol=1e-6)
        taken = np.asarray(metrics["critic_loss"][seed]).reshape(len(BODIES), CONFIG.updates)
        np.testing.assert_allclose(taken[:, :count].ravel(), losses, rtol=1e-5)
        assert not taken[:, count:].any(), "slots past the seed's count take no update"
    steps = optax.tree_utils.tree_get(state.critic_optimizer, "count")
    assert np.asarray(steps).tolist() == [len(BODIES) * CONFIG.updates, len(BODIES)]


def test_each_preset_trains_in_its_loop_on_its_schedule():
    loops = {name: preset.iteration for name, preset in PRESETS.items()}
    assert (loops["paper"].loop, loops["intended"].loop, loops["fast"].loop) == (
        "rounds",
        "rounds_chunked",
        "all_tasks",
    )
    assert TrainConfig().iteration == loops["paper"] and IterationConfig().loop == "rounds"
    schedules = {
        loop: IterationConfig(loop=loop).schedule
        for loop in ("rounds", "rounds_chunked", "per_body", "all_tasks")
    }
    assert schedules == {
        "rounds": "original",
        "rounds_chunked": "original",
        "per_body": "original",
        "all_tasks": "all_tasks",
    }
    assert [IterationConfig(loop=loop).rounds for loop in schedules] == [True, True, False, False]
    with pytest.raises(
        ConfigError, match=r"--iteration\.loop must be one of rounds, rounds_chunked, per_body, all_tasks"
    ):
        TrainConfig(iteration=IterationConfig(loop="original"))
