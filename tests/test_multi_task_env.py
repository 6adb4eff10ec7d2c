"""Many bodies in one jitted step: padding, masks, automatic resets, episode statistics, no NaN.

Two bodies of different limb counts (hopper_3: 3 limbs, cheetah_4_front: 4) with 3 copies each share
one compiled reset and one compiled step for the whole module.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.envs.multi_task import lock_step_round

BODIES = ("hopper_3", "cheetah_4_front")
COPIES = 3
MAX_LIMBS = 5
"""One more than the largest body, so both bodies have padding."""


@functools.cache
def compiled():
    env = MultiTaskEnv(BODIES, COPIES, max_limbs=MAX_LIMBS)
    return env, jax.jit(env.reset), jax.jit(env.step)


def random_action(seed: int) -> jax.Array:
    return jax.random.uniform(jax.random.PRNGKey(seed), (len(BODIES), COPIES, MAX_LIMBS), minval=-1, maxval=1)


def with_body(state, body: int, **changes):
    """``state`` with fields of one body's EnvState replaced (``data`` changes go in ``data=dict(...)``)."""
    bodies = list(state.bodies)
    data_changes = changes.pop("data", {})
    bodies[body] = bodies[body].replace(data=bodies[body].data.replace(**data_changes), **changes)
    return state.replace(bodies=tuple(bodies))


def test_reset_pads_observations_and_masks_limbs():
    _, reset, _ = compiled()
    state = reset(jax.random.PRNGKey(0))
    assert state.observation.shape == (2, COPIES, MAX_LIMBS, 19)
    np.testing.assert_array_equal(state.observation[0, :, 3:], 0.0)
    np.testing.assert_array_equal(state.observation[1, :, 4:], 0.0)
    assert np.abs(np.asarray(state.observation[1, :, :4])).sum(axis=(1, 2)).min() > 0
    assert not np.allclose(state.observation[0, 0], state.observation[0, 1]), "copies draw their own noise"


def test_step_returns_padded_batches_and_ignores_padded_actions():
    _, reset, step = compiled()
    state = reset(jax.random.PRNGKey(0))
    action = random_action(1)
    next_state, result = step(state, action)
    assert result.next_observation.shape == (2, COPIES, MAX_LIMBS, 19)
    for field in (result.reward, result.terminated, result.truncated):
        assert field.shape == (2, COPIES)
    np.testing.assert_array_equal(result.next_observation[0, :, 3:], 0.0)
    garbage = action.at[0, :, 3:].set(7.0).at[1, :, 4:].set(-9.0)
    _, same = step(state, garbage)
    np.testing.assert_array_equal(same.next_observation, result.next_observation)
    np.testing.assert_array_equal(same.reward, result.reward)
    np.testing.assert_array_equal(next_state.bodies[0].episode_length, 1)


def test_copies_are_independent():
    _, reset, step = compiled()
    state = reset(jax.random.PRNGKey(0))
    action = random_action(2)
    _, result = step(state, action)
    _, other = step(state, action.at[:, 1].set(-action[:, 1]))
    np.testing.assert_array_equal(other.next_observation[:, 0], result.next_observation[:, 0])
    np.testing.assert_array_equal(other.next_observation[:, 2], result.next_observation[:, 2])
    assert not np.allclose(other.next_observation[:, 1], result.next_observation[:, 1])


def test_time_limit_truncates_bootstrappable_episode_and_resets_it():
    _, reset, step = compiled()
    state = reset(jax.random.PRNGKey(0))
    length = jnp.array([999, 5, 5], jnp.int32)
    state = with_body(state, 1, episode_length=length, episode_return=jnp.array([250.0, 1.0, 1.0]))
    next_state, result = step(state, random_action(3))
    np.testing.assert_array_equal(result.truncated[1], [True, False, False])
    np.testing.assert_array_equal(result.terminated[1], False)
    np.testing.assert_array_equal(next_state.bodies[1].episode_length, [0, 6, 6])
    assert next_state.episodes.count.tolist() == [0, 1]
    assert next_state.episodes.length_sum[1] == 1000
    assert next_state.episodes.return_sum[1] == pytest.approx(250.0 + float(result.reward[1, 0]))
    pre_reset, post_reset = result.next_observation[1, 0], next_state.observation[1, 0]
    assert np.abs(np.asarray(pre_reset - post_reset)).max() > 1e-3, "the buffer gets the pre-reset state"
    np.testing.assert_array_equal(result.next_observation[1, 1:], next_state.observation[1, 1:])


def test_termination_resets_the_copy_and_does_not_truncate():
    _, reset, step = compiled()
    state = reset(jax.random.PRNGKey(0))
    qpos = state.bodies[0].data.qpos.at[1, 1].set(0.3)
    next_state, result = step(with_body(state, 0, data=dict(qpos=qpos)), random_action(4))
    np.testing.assert_array_equal(result.terminated[0], [False, True, False])
    assert not np.asarray(result.truncated).any()
    np.testing.assert_array_equal(next_state.bodies[0].episode_length, [1, 0, 1])
    assert float(next_state.bodies[0].data.qpos[1, 1]) == pytest.approx(1.25, abs=0.006)


def test_nan_simulation_terminates_and_resets_without_nan_anywhere():
    _, reset, step = compiled()
    state = reset(jax.random.PRNGKey(0))
    qvel = state.bodies[1].data.qvel.at[2].set(jnp.nan)
    next_state, result = step(with_body(state, 1, data=dict(qvel=qvel)), random_action(5))
    assert bool(result.terminated[1, 2]) and float(result.reward[1, 2]) == 0.0
    for array in (
        result.next_observation,
        result.reward,
        next_state.observation,
        next_state.episodes.return_sum,
    ):
        assert np.isfinite(np.asarray(array)).all()
    assert np.isfinite(np.asarray(next_state.bodies[1].data.qvel)).all()
    next_state, result = step(next_state, random_action(6))
    assert np.isfinite(np.asarray(result.next_observation)).all()


def test_bodies_with_different_observation_widths_are_refused():
    with pytest.raises(ValueError, match=r"hopper_3 \(19 features\), nervenet_ostrich \(21 features\)"):
        MultiTaskEnv(["hopper_3", "nervenet_ostrich"], 1)
    with pytest.raises(ValueError, match="copies must be at least 1"):
        MultiTaskEnv(["hopper_3"], 0)
    with pytest.raises(ValueError, match="max_limbs"):
        MultiTaskEnv(["hopper_3", "cheetah_4_front"], 1, max_limbs=3)


def lock_step_episodes(lengths: list[list[list[int]]], steps: int) -> dict[str, np.ndarray]:
    """Drive :func:`lock_step_round` with copies whose episodes last the given numbers of steps.

    ``lengths[r][k]`` lists the lengths of body k's successive episodes in run r (one copy each); a
    restart starts the next length. Returns per step [T, R, K] the finished, restart, counted and logged flags.
    """
    runs, bodies = len(lengths), len(lengths[0])
    episode = np.zeros((runs, bodies), int)
    age = np.zeros((runs, bodies), int)
    round_ended = jnp.zeros((runs, bodies, 1), bool)
    record = {"finished": [], "restart": [], "counted": [], "logged": []}
    for _ in range(steps):
        age += 1
        lengths_now = np.array([[lengths[r][k][episode[r, k]] for k in range(bodies)] for r in range(runs)])
        finished = age == lengths_now
        step = lock_step_round(round_ended, jnp.asarray(finished)[..., None])
        restart, round_ended, counted, logged = step.restart, step.round_ended, step.counted, step.logged
        restart = np.asarray(restart)[..., 0]
        np.testing.assert_array_equal(step.round_over, restart.all(-1))
        episode += restart
        age[restart] = 0
        for name, value in (
            ("finished", finished),
            ("restart", restart),
            ("counted", counted[..., 0]),
            ("logged", logged[..., 0]),
        ):
            record[name].append(np.asarray(value))
    return {name: np.stack(values) for name, values in record.items()}


def test_lock_step_rounds_count_first_episodes_and_cut_the_others_at_the_round_end():
    """The original training loop: every body resets at a round's start; a round ends when every body
    has ended its first episode; early finishers keep stepping (auto-reset) and are cut at the round end;
    a body's steps count while its first episode goes on after them, so it counts its first episode's
    length less one, and the round stores max(lengths) steps per body."""
    # Run 0: round 1 lasts 4 steps (body 1's first episode); body 0 ends episodes at 2 and 4. Round 2
    # lasts 5 steps (body 0's 5-step episode); body 1 ends its 3-step episode and is cut 2 steps into
    # its next. Run 1 has its own rounds: 3 steps, then 2.
    lengths = [[[2, 2, 5, 9], [4, 3, 9, 9]], [[3, 2, 9], [1, 2, 1, 9, 9]]]
    flags = lock_step_episodes(lengths, steps=9)
    counted, restart = flags["counted"].astype(int), flags["restart"]
    np.testing.assert_array_equal(counted[:4, 0], [[1, 1], [0, 1], [0, 1], [0, 0]])
    assert counted[:4, 0].sum(0).tolist() == [2 - 1, 4 - 1]
    np.testing.assert_array_equal(restart[:4, 0], [[0, 0], [1, 0], [0, 0], [1, 1]])
    assert counted[4:9, 0].sum(0).tolist() == [5 - 1, 3 - 1]
    assert restart[4:9, 0, 1].tolist() == [0, 0, 1, 0, 1], "body 1 restarts at the round end..."
    assert not flags["finished"][8, 0, 1], "...cut mid-episode"
    np.testing.assert_array_equal(counted[:3, 1], [[1, 0], [1, 0], [0, 0]])
    np.testing.assert_array_equal(restart[:3, 1], [[0, 1], [0, 0], [1, 1]])
    np.testing.assert_array_equal(restart[3:5, 1], [[0, 1], [1, 1]])


def test_lock_step_rounds_log_only_each_copys_first_episode_of_a_round():
    """As the original logs them: run 0's body 0 does not log its second episode of round 1, run 1's body 1
    its second of round 1; every first episode of a round is logged."""
    lengths = [[[2, 2, 5, 9], [4, 3, 9, 9]], [[3, 2, 9], [1, 2, 1, 9, 9]]]
    flags = lock_step_episodes(lengths, steps=9)
    logged, finished = flags["logged"], flags["finished"]
    assert (logged <= finished).all()
    assert np.flatnonzero(finished[:, 0, 0]).tolist() == [1, 3, 8]
    assert np.flatnonzero(logged[:, 0, 0]).tolist() == [1, 8], "round 1's second episode, at index 3, is not"
    assert np.flatnonzero(logged[:, 0, 1]).tolist() == [3, 6]
    assert np.flatnonzero(finished[:, 1, 1]).tolist() == [0, 2, 3]
    assert np.flatnonzero(logged[:, 1, 1]).tolist() == [0, 3], "the episode ended at index 2 is its second"


def test_without_lock_step_every_step_counts_and_only_finished_copies_restart():
    env, reset, step = compiled()
    assert not env.lock_step
    _, result = step(reset(jax.random.PRNGKey(0)), random_action(7))
    np.testing.assert_array_equal(result.counted, True)


@pytest.mark.parametrize("shared", [False, True])
def test_a_shared_reset_key_starts_every_body_from_the_same_random_numbers(shared):
    """The original code seeds every body's environment with the run's seed (docs/fidelity.md, row 39): with
    ``shared_reset_key`` two bodies of one tree start, and restart at a round's end, in the same states; by
    default each body draws its own."""
    env = MultiTaskEnv(["hopper_3", "hopper_3"], 2, physics="c", lock_step=True, shared_reset_key=shared)
    state = env.reset(jax.random.PRNGKey(0))
    first, second = (np.asarray(body.data.qpos) for body in state.bodies)
    assert not np.array_equal(first[0], first[1]), "the copies of a body draw their own numbers"
    assert np.array_equal(first, second) == shared
    step = jax.jit(env.step)
    for _ in range(200):
        state, result = step(state, jnp.ones((2, 2, 3)))
        if bool(result.round_over):
            break
    assert bool(result.round_over), "the round ends within 200 steps: every copy restarts"
    first, second = (np.asarray(body.data.qpos) for body in state.bodies)
    assert np.array_equal(first, second) == shared
