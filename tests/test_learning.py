"""TD3 learns: small policies trained for a few minutes on CPU beat the random policy on hopper_3.

The run goes through the user's commands (``python -m swat_jax.train``, then ``swat_jax.eval --json``) in
subprocesses compiled with XLA's default optimisations, as a user's run is: whether a short run learns
depends on every rounding, and the suite's cheaper compilation (conftest.py) rounds differently.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import pytest
from conftest import USER_XLA_FLAGS, XLA_DEFAULTS, tiny_train_config, train_flags
from subprocesses import python_path_environment

from swat_jax.envs.body import BodyEnv
from swat_jax.td3.iteration import IterationConfig
from swat_jax.td3.learner import TD3Config

EPISODES = 10
RANDOM_RETURN_MEASURED = 78.3
"""Mean return of uniform random actions on hopper_3, 10 episodes, seed 0 (seeds 1 and 2: 28.2, 55.4)."""
LEARNED_RETURN_MEASURED = 669.1
"""Mean over 3 seeds of the deterministic return (10 episodes each) after 16K steps of the run below, on
MuJoCo C physics (the CPU's default): seeds 0 / 1 / 2 gave 766 / 1057 / 184 (lengths 461 / 1000 / 100),
trained in 80 s on 2 idle CPU cores (Intel Xeon). Batches of 100 took 125 s for 422 / 996 / 181, and at
12K steps 292 / 1065 / 181; batches of 50 at 12K gave 154 / 1058 / 182, and 50 updates per iteration
instead of 100, 695 / 178 / 159. One seed alone is a coin toss (seed 0 trained alone gave 180, with MJX
physics 367), so the test asks the mean over three seeds, trained in one program."""
LEARNED_LENGTH = 120
"""Episodes of the learned policies last longer than this on average: 1.5x the random policy's (about 80
steps), under the 520 steps measured."""


def random_policy_returns(env: BodyEnv, episodes: int, seed: int) -> jax.Array:
    """[episodes] returns of uniform random actions, each episode until its first termination or time limit
    (the loop stops when every episode has ended: random hoppers fall within a few hundred steps)."""

    def step(carry):
        states, returns, finished, action_keys, count = carry
        actions = jax.random.uniform(action_keys[count], (episodes, env.num_limbs), minval=-1.0, maxval=1.0)
        states = jax.vmap(env.step)(states, actions)
        returns = jnp.where(states.done & ~finished, states.episode_return, returns)
        return states, returns, finished | states.done, action_keys, count + 1

    @functools.partial(jax.jit, compiler_options=XLA_DEFAULTS)
    def run(key):
        reset_key, action_key = jax.random.split(key)
        states = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))
        action_keys = jax.random.split(action_key, env.morphology.family.max_episode_steps)
        carry = (states, jnp.zeros(episodes), jnp.zeros(episodes, bool), action_keys, 0)
        _, returns, _, _, _ = jax.lax.while_loop(
            lambda carry: ~carry[2].all() & (carry[4] < len(action_keys)), step, carry
        )
        return returns

    return run(jax.random.PRNGKey(seed))


@pytest.mark.slow
def test_td3_on_hopper_3_beats_the_random_policy(hopper_folder, tmp_path):
    random_return = float(random_policy_returns(BodyEnv("hopper_3", physics="c"), EPISODES, seed=0).mean())
    assert random_return == pytest.approx(RANDOM_RETURN_MEASURED, rel=0.5)

    config = tiny_train_config(
        tmp_path / "run",
        hopper_folder,
        steps=16_000,
        seeds=3,
        envs={"copies": 4},
        iteration=IterationConfig(
            chunk=50, updates=100, random_steps=1000, capacity=16_000, loop="per_body", reset_next_state=False
        ),
        td3=TD3Config(batch_size=50, learning_rate=1e-3),
        network={"width": 32, "feedforward": 64},
        log_interval=2000,
        checkpoint_interval=16_000,
        eval_interval=0,
    )
    environment = python_path_environment(XLA_FLAGS=USER_XLA_FLAGS)
    for command in (
        ["swat_jax.train", *train_flags(config), "--no-progress"],
        ["swat_jax.eval", config.run_dir, "--episodes", str(EPISODES), "--bodies", "hopper_3", "--json"],
    ):
        completed = subprocess.run(
            [sys.executable, "-m", *command], capture_output=True, text=True, env=environment, check=False
        )
        assert completed.returncode == 0, completed.stderr[-3000:]
    learned = json.loads(completed.stdout)["bodies"]["hopper_3"]
    assert learned["return_mean"] > 3 * random_return, (learned, random_return, LEARNED_RETURN_MEASURED)
    assert learned["length_mean"] > LEARNED_LENGTH, (learned, "random hoppers fall after about 80 steps")
