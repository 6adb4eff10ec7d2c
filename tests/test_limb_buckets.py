"""Limb buckets: tasks of similar size updated at their own limb count give the padded update's result."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.morphology import bucket_structures, get_set, limb_buckets, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.runs.config import ConfigError, TrainConfig
from swat_jax.runs.experiment import Experiment
from swat_jax.td3.learner import Learner, TD3Config
from swat_jax.td3.replay import Transitions

FEATURES = 4
BATCH = 16
BODIES = ("hopper_3", "walker_7_main", "cheetah_4_front", "hopper_5")


def slots(buckets) -> int:
    return sum(len(bucket.tasks) * bucket.limbs for bucket in buckets)


def test_buckets_cover_every_task_once_with_the_fewest_slots():
    animal_walkers = [4, 7, 8, 9, 13]
    assert [(b.tasks, b.limbs) for b in limb_buckets(animal_walkers, 3)] == [
        ((0,), 4),
        ((1, 2, 3), 9),
        ((4,), 13),
    ]
    assert slots(limb_buckets(animal_walkers, 1)) == 65
    assert slots(limb_buckets(animal_walkers, 2)) == 49
    assert slots(limb_buckets(animal_walkers, 10)) == 41  # one bucket per size, no padding at all
    unsorted = [5, 2, 9, 2, 5]
    buckets = limb_buckets(unsorted, 3)
    assert sorted(task for bucket in buckets for task in bucket.tasks) == list(range(5))
    assert all(unsorted[task] <= bucket.limbs for bucket in buckets for task in bucket.tasks)
    assert slots(buckets) == 2 * 2 + 2 * 5 + 9
    with pytest.raises(ValueError, match="at least 1"):
        limb_buckets(unsorted, 0)


def test_a_bucket_of_structures_is_each_body_padded_to_the_bucket_alone():
    bodies = [load(name) for name in BODIES]
    padded = pad_structures(bodies, max_limbs=9)
    bucket = limb_buckets([body.num_limbs for body in bodies], 2)[0]
    alone = pad_structures([bodies[task] for task in bucket.tasks], max_limbs=bucket.limbs)
    for got, expected in zip(bucket_structures(padded, bucket), alone, strict=True):
        np.testing.assert_array_equal(got, expected)


def problem(buckets: int):
    bodies = [load(name) for name in BODIES]
    structure = jax.tree_util.tree_map(jnp.asarray, pad_structures(bodies, max_limbs=9))
    network = network_config("swat", width=16, heads=2, layers=1, feedforward=32)
    actor, critic = make_actor_critic(network, FEATURES)
    chosen = limb_buckets([body.num_limbs for body in bodies], buckets) if buckets > 1 else ()
    learner = Learner(actor, critic, TD3Config(batch_size=BATCH), chosen)
    keys = jax.random.split(jax.random.key(3), 4)
    mask = structure.limb_mask[:, None, :]
    shape = (len(bodies), BATCH, 9)
    batch = Transitions(
        observation=jnp.where(mask[..., None], jax.random.normal(keys[0], (*shape, FEATURES)), 0.0),
        action=jnp.where(mask, jax.random.uniform(keys[1], shape, minval=-1), 0.0),
        reward=jax.random.normal(keys[2], shape[:2]),
        next_observation=jnp.where(mask[..., None], jax.random.normal(keys[3], (*shape, FEATURES)), 0.0),
        terminated=jnp.zeros(shape[:2], bool),
    )
    return learner, batch, structure


def run_updates(learner: Learner, batch: Transitions, structure, updates: int = 4):
    def step(state, key):
        return learner.update(state, batch, structure, key)

    keys = jax.random.split(jax.random.key(5), updates)
    return jax.jit(lambda state: jax.lax.scan(step, state, keys))(learner.init(jax.random.key(0)))


@pytest.mark.slow
def test_the_bucketed_update_equals_the_padded_update():
    padded, batch, structure = problem(buckets=1)
    bucketed = problem(buckets=3)[0]
    assert len(bucketed.buckets) == 3
    (padded_state, padded_metrics), (bucketed_state, bucketed_metrics) = (
        run_updates(learner, batch, structure) for learner in (padded, bucketed)
    )
    for name in ("critic_loss", "actor_loss"):
        np.testing.assert_allclose(bucketed_metrics[name], padded_metrics[name], rtol=1e-4, atol=1e-6)
    for got, expected in zip(jax.tree.leaves(bucketed_state), jax.tree.leaves(padded_state), strict=True):
        np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)


def test_the_bucketed_update_does_fewer_flops():
    padded, batch, structure = problem(buckets=1)
    bucketed = problem(buckets=3)[0]
    state = padded.init(jax.random.key(0))

    def flops(learner: Learner) -> float:
        lowered = jax.jit(learner.update).lower(state, batch, structure, jax.random.key(1))
        return lowered.cost_analysis()["flops"]

    assert flops(bucketed) < 0.8 * flops(padded)


def test_a_run_updates_in_limb_buckets_by_default():
    hopper = [load(name).num_limbs for name in get_set("hopper").split("train")]
    assert Experiment.build(TrainConfig(env="hopper")).learner.buckets == limb_buckets(hopper, 3)
    assert Experiment.build(TrainConfig(env="hopper", limb_buckets=1)).learner.buckets == ()
    with pytest.raises(ConfigError, match="--limb-buckets must be a positive whole number"):
        TrainConfig(env="hopper", limb_buckets=0)
