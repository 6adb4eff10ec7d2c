"""Variants of a body stepped by one program: each as MuJoCo C steps its own MJCF file, and a program
whose size does not depend on the number of variants."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import tiny_train_config
from subprocesses import python_path_environment

from swat_jax.envs import BodyEnv, MultiTaskEnv
from swat_jax.eval import EvalOptions, evaluate_run
from swat_jax.morphology.variants import Variation, write_variants
from swat_jax.runs import Checkpoints, ConfigError, Experiment, load_config
from swat_jax.td3.iteration import IterationConfig
from swat_jax.train import train

SCRIPT = """
import json, sys
from mujoco_reference import mjx_and_c_variant_rollouts
errors = {name: mjx_and_c_variant_rollouts(name, 3, 20, f"{sys.argv[1]}/{name}") for name in sys.argv[2:]}
errors["hopper_3 alone"] = mjx_and_c_variant_rollouts("hopper_3", 1, 20, f"{sys.argv[1]}/alone", seed=5)
print(json.dumps(errors))
"""
BODIES = ("hopper_3", "walker_3_main", "cheetah_4_front")
"""One body of three families."""


@pytest.mark.slow
def test_each_variant_steps_as_mujoco_c_steps_its_own_file(tmp_path):
    """In float64 the stacked, vmapped step of 3 variants equals MuJoCo C on each variant's MJCF over 20
    environment steps (80 physics steps) to 1e-8, and each variant's observation uses its own joint ranges;
    so does one variant alone (its numbers differ from the nominal body's, not from other variants')."""
    environment = python_path_environment(Path(__file__).parent, JAX_ENABLE_X64="1")
    completed = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path), *BODIES],
        capture_output=True,
        text=True,
        env=environment,
        check=False,
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    for body, errors in json.loads(completed.stdout.strip().splitlines()[-1]).items():
        assert errors["qpos"] < 1e-8 and errors["qvel"] < 1e-8, (body, errors)
        assert errors["observation"] < 1e-5, (body, errors)
        assert errors["spread"] > 1e-3 or body == "hopper_3 alone", (body, "the variants should move apart")


@pytest.mark.slow
def test_the_program_does_not_grow_with_the_number_of_variants(tmp_path):
    """The step of 8 copies lowers to the same program whether they run 2 or 64 variants: the variants'
    numbers are inputs; the nominal body's are the constants. It traces once."""
    programs, traces = {}, []
    for count in (2, 64):
        variants = write_variants("hopper_3", count, Variation(0.2), tmp_path / str(count))
        env = BodyEnv("hopper_3", variants=variants)
        rows = np.arange(8) % count
        table = jax.tree_util.tree_map(lambda x, rows=rows: x[rows], env.variant_table())
        states = jax.eval_shape(jax.vmap(env.reset), jax.random.split(jax.random.PRNGKey(0), 8), table)

        def step(state, action, env=env):
            traces.append(1)
            return jax.vmap(env.step)(state, action)

        lowered = jax.jit(step).lower(states, jax.ShapeDtypeStruct((8, env.num_limbs), np.float32))
        programs[count] = lowered.as_text()
        assert set(env.variant_table().model) >= {".body_mass", ".body_pos", ".geom_size", ".actuator_gear"}
    assert len(traces) == 2, "one trace per environment"
    assert len(programs[2]) == len(programs[64])


def test_a_body_of_another_tree_is_not_a_variant(tmp_path):
    with pytest.raises(ValueError, match="not a variant of hopper_3"):
        BodyEnv("hopper_3", variants=["hopper_4"])
    with pytest.raises(ValueError, match="physics='jax'"):
        BodyEnv("hopper_3", variants=write_variants("hopper_3", 1, Variation(0.1), tmp_path), physics="warp")
    with pytest.raises(ValueError, match="has no variants"):
        BodyEnv("hopper_3").variant_table()


@pytest.mark.slow
def test_copies_of_a_body_run_its_variants_in_turn_and_keep_them_across_resets(tmp_path):
    """Copy j of every run runs variant j mod k, and still does after its episodes end and restart."""
    variants = write_variants("walker_2_main", 2, Variation(0.3), tmp_path)
    env = MultiTaskEnv(["walker_2_main"], copies=3, variants=[variants], seeds=2)
    table = env.envs[0].variant_table()
    state = env.reset(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(env.step)
    ended = np.zeros((2, 1, 3), bool)
    actions = np.random.default_rng(0).uniform(-1, 1, (200, 2, 1, 3, env.max_limbs))
    for action in actions:
        state, result = step(state, action)
        ended |= np.asarray(result.terminated | result.truncated)
    assert ended.all(), "every copy has restarted at least once"
    masses = np.asarray(state.bodies[0].variant.model[".body_mass"])
    expected = np.asarray(table.model[".body_mass"])[[0, 1, 0]]
    np.testing.assert_array_equal(masses, np.broadcast_to(expected, (2, *expected.shape)))


@pytest.mark.slow
def test_a_run_trains_on_variants_and_evaluates_on_held_out_ones(tmp_path, hopper_folder):
    """--variants 2 with 2 copies under the fast preset's settings (the paper preset's run on variants is
    tests/test_sharding.py's): each copy of the run's state holds its own variant (the same in both seeds),
    the run resumes from its checkpoint with them, and eval runs other variants (another seed)."""
    config = tiny_train_config(
        tmp_path / "run",
        hopper_folder,
        preset="fast",
        iteration=IterationConfig(chunk=50, updates=4, loop="all_tasks", random_steps=100, capacity=1000),
        envs={"variants": 2, "variation": 0.3, "torso_relative_x": True, "stale_kinematics": False},
        network={"reference_inorder": False},
        steps=200,
        eval_interval=0,
        log_interval=100,
    )
    train(config, progress=False)
    experiment = Experiment.build(load_config(tmp_path / "run" / "config.json"))
    checkpoints = Checkpoints(tmp_path / "run")
    try:
        state, info = experiment.restore_state(checkpoints)
    finally:
        checkpoints.close()
    assert info.env_steps == 200
    variants = np.asarray(state.env.bodies[0].variant.index)  # [seeds, copies]
    np.testing.assert_array_equal(variants, [[0, 1], [0, 1]])  # copy j runs variant j, in both seeds
    held_out = evaluate_run(tmp_path / "run", EvalOptions(episodes=2, variants=2, variant_seed=7))
    assert held_out.results[0].returns.shape == (2, 2) and np.all(np.isfinite(held_out.results[0].returns))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (dict(variants=3), "--envs.variants must be 0 \\(off\\) or a number up to --envs.copies \\(2\\)"),
        (dict(variants=2, variation=1.0), "--envs.variation must lie in \\[0, 1\\)"),
        (
            dict(variants=2, physics="warp", stale_kinematics=False),
            "--envs.variants runs on --envs.physics c, jax or auto",
        ),
    ],
)
def test_variant_options_that_cannot_run_are_refused(hopper_folder, tmp_path, overrides, message):
    with pytest.raises(ConfigError, match=message):
        tiny_train_config(tmp_path, hopper_folder, envs=overrides)
