"""``--physics warp``: MuJoCo Warp's kernels in place of MJX's JAX physics, same environment, same numbers.

Warp runs in float32 only, so it is held to the float32 tolerances of test_env_bodies.py against MuJoCo C
(one body per family), and to the C physics on a multi-task rollout with seeds and copies as nested vmap
axes and automatic resets (the shared contact buffers must survive both).
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from conftest import tiny_train_config
from mujoco_reference import mjx_and_c_rollouts
from test_env_against_mujoco import ONE_BODY_PER_FAMILY
from test_env_bodies import FLOAT32_OBSERVATION_TOLERANCE, FLOAT32_STATE_TOLERANCE

from swat_jax.envs import BodyEnv, MultiTaskEnv
from swat_jax.envs.physics import Simulator
from swat_jax.eval import evaluate
from swat_jax.morphology.mjcf import compile_model, load
from swat_jax.runs.metrics import read_metrics
from swat_jax.runs.trained import load_policy
from swat_jax.train import train

STEPS = 10
ROLLOUT_STEPS = 60
"""Long enough for random actions to end episodes of hopper_3 and trigger automatic resets."""
WARP_C_TOLERANCE = 1e-3
"""Max abs reward difference, Warp (float32) against MuJoCo C (measured: 8e-6 over 60 steps)."""


@pytest.mark.slow
@pytest.mark.parametrize("name", ONE_BODY_PER_FAMILY)
def test_warp_environment_tracks_mujoco_c(name):
    result = mjx_and_c_rollouts(name, STEPS, physics="warp")
    assert np.isfinite(result["observation"]).all()
    np.testing.assert_array_equal(result["episode_length"], np.arange(1, STEPS + 1))
    assert result["qpos_error"].max() < FLOAT32_STATE_TOLERANCE, result["qpos_error"]
    final_difference = np.abs(result["observation"][-1] - result["c_final_observation"]).max()
    assert final_difference < FLOAT32_OBSERVATION_TOLERANCE


def rollout(physics: str, seeds: int, copies: int):
    """Rewards, terminations and finished-episode counts [seeds, steps, K, n] of a random-action rollout."""
    env = MultiTaskEnv(["hopper_3", "walker_2_main"], copies, physics=physics, seeds=seeds)

    def run(key):
        def step(state, action_key):
            action = jax.random.uniform(
                action_key, (env.num_bodies, copies, env.max_limbs), minval=-1, maxval=1
            )
            state, result = env.step(state, action)
            return state, (result.reward, result.terminated | result.truncated)

        state, outputs = jax.lax.scan(
            step, env.reset(key), jax.random.split(jax.random.fold_in(key, 1), ROLLOUT_STEPS)
        )
        return outputs, state.episodes.count

    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    return jax.tree_util.tree_map(np.asarray, jax.jit(jax.vmap(run))(keys))


@pytest.mark.slow
def test_warp_multi_task_rollout_with_seeds_and_resets_equals_c_physics():
    (warp_rewards, warp_done), warp_episodes = rollout("warp", seeds=2, copies=3)
    (c_rewards, c_done), c_episodes = rollout("c", seeds=2, copies=3)
    assert c_done.any(), "the rollout must exercise automatic resets"
    np.testing.assert_array_equal(warp_done, c_done)
    np.testing.assert_array_equal(warp_episodes, c_episodes)
    np.testing.assert_allclose(warp_rewards, c_rewards, atol=WARP_C_TOLERANCE)


def test_warp_states_hold_no_shared_buffers_between_calls():
    simulator = Simulator(compile_model(load("hopper_3")), "warp", worlds=8)
    contacts = simulator.initial._impl.contact__dist
    assert contacts.shape == (0,), "states carry empty placeholders"
    stepped = jax.jit(jax.vmap(lambda data: simulator.advance(data, 2), axis_size=4, in_axes=None))(
        simulator.initial
    )
    assert stepped.qpos.shape == (4, 5)
    assert stepped._impl.contact__dist.shape == (0,)


def test_bad_physics_is_refused():
    with pytest.raises(ValueError, match="MJX runs physics 'jax' or 'warp', got 'cuda'"):
        Simulator(compile_model(load("hopper_3")), "cuda")
    with pytest.raises(ValueError, match="physics must be one of auto, jax, warp, c, got 'cuda'"):
        BodyEnv("hopper_3", physics="cuda")


@pytest.mark.slow
def test_a_warp_run_trains_and_evaluates_on_warp(tmp_path, hopper_folder):
    """Train (2 seeds, 2 iterations, evaluated after the second) and evaluate with --physics warp; the
    eval/* columns are what swat_jax.eval measures with the run's physics. Short: Warp steps slowly on the
    CPU (600 steps and two evaluations took 73 s here, 200 steps and one 27 s)."""
    run_dir = tmp_path / "warp"
    config = tiny_train_config(
        run_dir,
        hopper_folder,
        envs={"physics": "warp", "stale_kinematics": False},
        steps=200,
        eval_interval=200,
    )
    train(config, progress=False)
    policy = load_policy(run_dir)
    assert policy.config.envs.physics == "warp"
    [evaluation] = evaluate(policy, ["hopper_3"], episodes=2, seed=0)
    final = {int(row["seed"]): row for row in read_metrics(run_dir) if row["env_steps"] == 200}
    assert len(final) == 2
    for index, seed in enumerate(evaluation.seeds):
        assert np.isfinite(final[seed]["critic_loss"])
        assert final[seed]["eval/return/hopper_3"] == pytest.approx(
            evaluation.returns[index].mean(), rel=1e-4
        )
