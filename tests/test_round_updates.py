"""The original's training loop in the paper preset (docs/fidelity.md rows 21, 26, 29, 30): a seed's updates
run when its lock-step round ends, with the round's policy frozen while it collects; time-limit transitions
bootstrap from the next episode's first observation; the replay rule of sets of more than 8 bodies."""

from __future__ import annotations

import dataclasses
import functools
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.envs.multi_task import lock_step_round
from swat_jax.morphology import load
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.runs.config import PRESETS
from swat_jax.td3.iteration import (
    IterationConfig,
    init_train_state,
    make_train_iteration,
    round_update_counts,
    seed_keys,
)
from swat_jax.td3.learner import Learner, TD3Config

NETWORK = network_config("amorpheus", width=8, layers=1, feedforward=16)
LIMBS = 4


def short_lived(name: str, time_limit: int):
    """Body ``name`` with episodes cut at ``time_limit`` steps, so that rounds stay short."""
    body = load(name)
    return dataclasses.replace(body, family=dataclasses.replace(body.family, max_episode_steps=time_limit))


def run_iterations(bodies, config: IterationConfig, seeds: int, iterations: int, batch_size: int = 64):
    """``iterations`` jitted iterations of a tiny AMORPHEUS on C physics, 2 copies per body, lock-step rounds:
    the state before the first and after each, with each iteration's metrics."""
    env = MultiTaskEnv(bodies, 2, max_limbs=LIMBS, physics="c", seeds=seeds, lock_step=config.rounds)
    actor, critic = make_actor_critic(NETWORK, env.observation_features)
    learner = Learner(actor, critic, TD3Config(batch_size=batch_size))
    structure = task_set([body.name for body in bodies], NETWORK, max_limbs=LIMBS).structure
    step = jax.jit(make_train_iteration(env, structure, learner, config))
    state = jax.jit(lambda keys: init_train_state(env, learner, config, keys))(seed_keys(3, seeds))
    states, metrics = [jax.device_get(state)], []
    for _ in range(iterations):
        state, out = step(state)
        states.append(jax.device_get(state))
        metrics.append(jax.device_get(out))
    return states, metrics


def critic_adam_steps(state) -> np.ndarray:
    """[S] the Adam steps each seed's critic has taken."""
    return np.asarray(optax.tree_utils.tree_get(state.learner.critic_optimizer, "count")).reshape(-1)


def actor_of(state, seed: int) -> list[np.ndarray]:
    return [np.asarray(leaf[seed]) for leaf in jax.tree.leaves(state.learner.actor_params)]


BODIES = (short_lived("hopper_3", 30), short_lived("walker_2_flipped", 30))
CHUNK = 25


@pytest.fixture(scope="module")
def rounds_run():
    """Two seeds, two bodies with a 30-step time limit (rounds of at most 30 steps) and chunks of 25: most
    iterations hold a round's end, some none. Random actions for the first 10 counted steps per body."""
    config = IterationConfig(chunk=CHUNK, updates=1, random_steps=10, capacity=4096, loop="rounds")
    assert config.loop == "rounds" and config.reset_next_state, "the defaults are the original's"
    return run_iterations(BODIES, config, seeds=2, iterations=10)


def test_a_seed_updates_only_when_its_round_ends_and_waits_for_the_chunk_end(rounds_run):
    """The original's loop: after a round, each body takes (the round's counted steps summed over bodies) // K
    updates, even with fewer rows than a batch (the first round stores about 40 of a 64 batch); the policy
    that collects a round does not change during it; a seed whose round ended stores nothing until the
    chunk's end (its rewards 0 there); one whose round goes on takes every step of the chunk."""
    states, metrics = rounds_run
    seen = {"ended": 0, "open": 0}
    for before, after, out in zip(states[:-1], states[1:], metrics, strict=True):
        stepped = (np.asarray(out["reward"]) != 0).any(axis=(-2, -1))  # [S, chunk]; hopper's alive bonus
        updates = critic_adam_steps(after) - critic_adam_steps(before)
        for seed in range(2):
            steps = int(stepped[seed].sum())
            assert stepped[seed, :steps].all() and not stepped[seed, steps:].any(), (
                "waits from the round's end on"
            )
            stored = (int(after.buffer.position[seed]) - int(before.buffer.position[seed])) % 4096
            assert stored == steps * 2, "each of 2 copies stores a row per step taken, none while waiting"
            ended = int(after.round_start[seed]) != int(before.round_start[seed])
            if ended:
                seen["ended"] += 1
                assert int(after.round_start[seed]) == int(after.counted[seed])
                round_counted = int(after.counted[seed]) - int(before.round_start[seed])
                assert updates[seed] == len(BODIES) * (round_counted // len(BODIES))
                assert updates[seed] > 0 and any(
                    not np.array_equal(a, b)
                    for a, b in zip(actor_of(before, seed), actor_of(after, seed), strict=True)
                )
            else:
                seen["open"] += 1
                assert steps == CHUNK and updates[seed] == 0
                for a, b in zip(actor_of(before, seed), actor_of(after, seed), strict=True):
                    np.testing.assert_array_equal(a, b)
    assert seen["ended"] >= 6 and seen["open"] >= 2, seen
    first_round = next(i for i in range(10) if (critic_adam_steps(states[i + 1]) > 0).any())
    assert int(states[first_round + 1].buffer.size.max()) < 64, "the first updates came before a full batch"


@pytest.mark.parametrize("reset_next_state", [True, False])
def test_time_limit_transitions_bootstrap_from_the_next_episode_as_the_original_stores_them(reset_next_state):
    """hopper_3 with a 5-step time limit, random actions: each round is one 5-step episode per copy, cut by
    the time limit. Its 5th transition's next state is the observation the next round starts from (the
    original's vectorised environment has already reset the copy), or with the switch off the one the step
    reached; every other transition's next state is the next transition's observation."""
    config = IterationConfig(
        chunk=12, updates=1, random_steps=1000, capacity=64, loop="rounds", reset_next_state=reset_next_state
    )
    states, _ = run_iterations((short_lived("hopper_3", 5),), config, seeds=1, iterations=2)
    data = states[-1].buffer.data
    assert int(states[-1].buffer.position[0]) == 2 * 5 * 2, "two rounds of 5 steps x 2 copies"
    observation = np.asarray(data.observation[0, 0, :20]).reshape(10, 2, LIMBS, -1)  # [row, copy, L, F]
    next_observation = np.asarray(data.next_observation[0, 0, :20]).reshape(10, 2, LIMBS, -1)
    assert not np.asarray(data.terminated[0, 0, :20]).any(), "5 random steps do not make hopper_3 fall"
    for row in (0, 1, 2, 3, 5, 6, 7, 8):
        np.testing.assert_array_equal(next_observation[row], observation[row + 1])
    at_limit = next_observation[4] == observation[5]
    assert at_limit.all() if reset_next_state else not at_limit.all()


def test_the_paper_preset_keeps_the_original_loop_and_the_others_do_not():
    paper = PRESETS["paper"].iteration
    assert paper.loop == "rounds" and paper.reset_next_state and paper.capacity_all == 4_000_000
    for name in ("intended", "fast"):
        other = PRESETS[name].iteration
        assert other.loop != "rounds" and not other.reset_next_state and other.capacity_all is None, name


@pytest.mark.parametrize("bodies, rows", [(8, 500_000), (12, 333_333), (13, 307_692), (25, 160_000)])
def test_sets_of_more_than_8_bodies_share_4m_replay_rows_as_the_original(bodies, rows):
    """The original's rb_max // K when K > rb_max // rb_per_env (Cheetah++ 333,333, WHH++ 307,692, CWHH++
    160K); swat_jax's own presets keep their rows per body (intended the paper's 500K, fast 50K)."""
    assert PRESETS["paper"].iteration.rows_per_task(bodies) == rows
    assert PRESETS["intended"].iteration.rows_per_task(bodies) == 500_000
    assert PRESETS["fast"].iteration.rows_per_task(bodies) == 50_000
    cheetah = dataclasses.replace(PRESETS["paper"], env="cheetah", steps=10_000_000)
    assert cheetah.replay_rows(12) == 333_333


ORIGINAL_RUNS = (
    Path(__file__).resolve().parents[1] / "experiments" / "results" / "time_to_return_presets" / "original"
)
"""The original trainer's runs at the small scale: its stat.json and its trainer log (run_trainer.py's lines)."""
ROUND_LINE = re.compile(r"round=(\d+) env_steps\(all envs\)=(\d+) updates=(\d+)")


def original_rounds(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per round of an original run: each body's counted steps [R, K] (stat.json's ``*_episode_len``), and,
    cumulative [R], the counted steps (its ``timestep``), and from the log the steps stored (all bodies)
    and the updates taken (every body's) when the round's training ended."""
    stats = json.loads((run / "stat.json").read_text())
    lengths = np.array([stats[key] for key in stats if key.endswith("_episode_len")], int).T
    lines = [
        tuple(map(int, match.groups())) for match in ROUND_LINE.finditer((run / "trainer.log").read_text())
    ]
    rounds = min(len(lengths), len(lines))
    assert [line[0] for line in lines[:rounds]] == list(range(1, rounds + 1))
    logged = np.array(lines[:rounds])
    return lengths[:rounds], np.array(stats["timestep"][:rounds]), logged[:, 1], logged[:, 2]


@functools.partial(jax.jit, static_argnames="limit")
def our_rounds(first_episodes: jax.Array, limit: int = 1000) -> tuple[jax.Array, jax.Array]:
    """swat_jax's lock-step bookkeeping of rounds [R] of K bodies whose first episode of the round lasts
    ``first_episodes`` [R, K] steps (a body's later episodes of the round last longer than the round):
    the steps counted and the steps the round lasts."""
    rounds, bodies = first_episodes.shape

    def step(carry, t):
        round_ended, over, counted, steps = carry
        taken = lock_step_round(round_ended, (t + 1 == first_episodes)[..., None])
        counted = counted + jnp.where(over, 0, taken.counted.sum((-2, -1)))
        return (taken.round_ended, over | taken.round_over, counted, steps + ~over), None

    start = (
        jnp.zeros((rounds, bodies, 1), bool),
        jnp.zeros(rounds, bool),
        jnp.zeros(rounds, int),
        jnp.zeros(rounds, int),
    )
    (_, _, counted, steps), _ = jax.lax.scan(step, start, jnp.arange(limit))
    return counted, steps


@pytest.mark.parametrize(
    "run", sorted(run.parent for run in ORIGINAL_RUNS.glob("*/stat.json")), ids=lambda run: run.name
)
def test_rounds_count_store_and_update_as_the_original_trainer_did(run):
    """Against the original main.py's own bookkeeping, round by round (its runs on Hopper++ and Walker++):
    with each body's first episode as long as in the original's round, swat_jax's lock-step rounds count
    the steps its ``timestep`` counted, store the steps its environments took, and take the updates its
    ``TD3.train`` took after the round (K x (counted // K), from the first round on)."""
    lengths, timestep, stored, updates = original_rounds(run)
    bodies = lengths.shape[1]
    counted, steps = our_rounds(jnp.asarray(lengths + 1))  # the step that ends an episode is not counted
    np.testing.assert_array_equal(counted, np.diff(timestep, prepend=0))
    np.testing.assert_array_equal(steps * bodies, np.diff(stored, prepend=0))
    counts, round_start = round_update_counts(
        timestep, np.concatenate([[0], timestep[:-1]]), np.ones(len(timestep), bool), bodies
    )
    np.testing.assert_array_equal(round_start, timestep)
    np.testing.assert_array_equal(counts * bodies, np.diff(updates, prepend=0))
