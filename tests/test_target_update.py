"""The target networks follow their networks only on the delayed steps (every policy_delay-th critic step):
a critic step without the actor step neither touches the targets nor computes a soft update."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.morphology import load, pad_structures
from swat_jax.networks import Params, make_actor_critic, network_config
from swat_jax.td3.learner import Learner, LearnerState, TD3Config
from swat_jax.td3.replay import Transitions

FEATURES = 3
BATCH = 8
STRUCTURE = pad_structures([load("hopper_3"), load("cheetah_4_front")], max_limbs=5)
TARGETS = ("target_actor_params", "target_critic_params")


def tiny_learner() -> Learner:
    """A tiny AMORPHEUS learner with the paper's policy delay (2) and rate (0.046)."""
    config = network_config("amorpheus", width=16, heads=2, layers=1, feedforward=32)
    actor, critic = make_actor_critic(config, FEATURES)
    return Learner(actor, critic, TD3Config(batch_size=BATCH))


def random_batch(rng: jax.Array) -> Transitions:
    """[T=2, B, L=5, ...] random transitions, padding limbs 0."""
    keys = jax.random.split(rng, 4)
    shape = (2, BATCH, 5)
    mask = jnp.asarray(STRUCTURE.limb_mask)[:, None, :]
    return Transitions(
        observation=jnp.where(mask[..., None], jax.random.normal(keys[0], (*shape, FEATURES)), 0.0),
        action=jnp.where(mask, jax.random.uniform(keys[1], shape, minval=-1.0), 0.0),
        reward=jax.random.normal(keys[2], shape[:2]),
        next_observation=jnp.where(mask[..., None], jax.random.normal(keys[3], (*shape, FEATURES)), 0.0),
        terminated=jnp.zeros(shape[:2], bool),
    )


def negative_zero_targets(state: LearnerState) -> LearnerState:
    """``state`` with every target parameter -0.0: the one finite value that a soft update of rate 0
    (0 * new + 1 * old) does not give back bit for bit (0.0 + -0.0 is +0.0)."""
    return state.replace(
        **{
            name: jax.tree.map(lambda leaf: jnp.full_like(leaf, -0.0), getattr(state, name))
            for name in TARGETS
        }
    )


def bits(params: Params) -> list[np.ndarray]:
    """The parameters' leaves as their raw float32 bits."""
    return [np.asarray(leaf).view(np.uint32) for leaf in jax.tree.leaves(params)]


def same_bits(a: Params, b: Params) -> bool:
    """Whether two parameter trees hold the same bits, leaf by leaf."""
    return all(np.array_equal(x, y) for x, y in zip(bits(a), bits(b), strict=True))


@pytest.mark.parametrize("delayed", [None, False], ids=["first-update", "delayed-false"])
def test_a_critic_step_without_the_actor_step_leaves_the_targets_bit_identical(delayed):
    learner = tiny_learner()
    state = negative_zero_targets(learner.init(jax.random.PRNGKey(0)))
    given = () if delayed is None else (jnp.asarray(delayed),)
    update = jax.jit(learner.update)
    after, metrics = update(
        state, random_batch(jax.random.PRNGKey(1)), STRUCTURE, jax.random.PRNGKey(2), *given
    )
    assert float(metrics["actor_loss"]) == 0.0, "no actor step"
    assert not same_bits(after.critic_params, state.critic_params), "the critic stepped"
    for name in TARGETS:
        assert same_bits(getattr(after, name), getattr(state, name)), f"{name} touched without an actor step"

    delayed_step = () if delayed is None else (jnp.asarray(True),)
    moved, _ = update(
        after, random_batch(jax.random.PRNGKey(3)), STRUCTURE, jax.random.PRNGKey(4), *delayed_step
    )
    for name in TARGETS:
        assert not same_bits(getattr(moved, name), getattr(after, name)), (
            f"{name} follows on the delayed step"
        )


def test_the_soft_update_is_computed_only_in_the_delayed_branch():
    """In the update's program every target parameter is an output of its lax.cond, and the branch without
    the actor step hands the old targets through untouched (no arithmetic on them outside the branch)."""
    learner = tiny_learner()
    state = learner.init(jax.random.PRNGKey(0))
    batch = random_batch(jax.random.PRNGKey(1))
    noise = jnp.zeros(batch.action.shape)
    program = jax.make_jaxpr(learner.update_with_noise)(state, batch, STRUCTURE, noise, jnp.asarray(False))
    jaxpr = program.jaxpr
    producers = {id(var): eqn for eqn in jaxpr.eqns for var in eqn.outvars}
    next_state, _ = jax.eval_shape(
        learner.update_with_noise, state, batch, STRUCTURE, noise, jnp.asarray(False)
    )
    leaves = jax.tree_util.tree_flatten_with_path(next_state)[0]
    targets = [
        i for i, (path, _) in enumerate(leaves) if jax.tree_util.keystr(path[:1]).lstrip(".") in TARGETS
    ]
    assert len(targets) == len(jax.tree.leaves(state.target_actor_params)) + len(
        jax.tree.leaves(state.target_critic_params)
    )
    for index in targets:
        eqn = producers.get(id(jaxpr.outvars[index]))
        assert eqn is not None and eqn.primitive.name == "cond", (
            f"target leaf {index} computed outside the cond"
        )
        skipped = eqn.params["branches"][0].jaxpr
        output = skipped.outvars[eqn.outvars.index(jaxpr.outvars[index])]
        assert output in skipped.invars, f"target leaf {index} computed in the branch without the actor step"
