"""``physics="c"``: MuJoCo's C library called from the jitted program, the same environment as on MJX.

Its state passes between environment steps exactly (float32 rounding plus two float32 remainders), so an
environment on C physics follows ``mujoco.mj_step`` alone bit for bit; no physics is traced or compiled,
so each of these tests compiles in about a second.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco_reference import float64_state, mjx_and_c_rollouts, mjx_and_c_variant_rollouts, numpy_observation
from subprocesses import printed_words
from test_env_bodies import FLOAT32_OBSERVATION_TOLERANCE, FLOAT32_STATE_TOLERANCE, ROLLOUT_BODIES

from swat_jax.envs import BodyEnv, MultiTaskEnv
from swat_jax.envs.physics import resolve_physics

STEPS = 200


@pytest.mark.parametrize("name", ROLLOUT_BODIES)
def test_c_physics_follows_mj_step_bit_for_bit(name):
    """200 environment steps (800 physics steps, contacts and falls included) from the environment's
    reset: every state equals plain ``mujoco.mj_step``'s exactly, and the last observation is the NumPy
    one of MuJoCo C's final state (float32 rounding)."""
    result = mjx_and_c_rollouts(name, STEPS, physics="c")
    assert result["qpos_error"].max() == 0.0 and result["qvel_error"].max() == 0.0
    np.testing.assert_allclose(result["observation"][-1], result["c_final_observation"], atol=2e-5, rtol=1e-5)
    assert np.isfinite(result["reward"]).all()


@pytest.mark.slow
def test_c_physics_is_the_mjx_environment():
    """On the same actions, the C and MJX environments give the observations, rewards and terminations
    that the MJX-against-MuJoCo-C comparison (test_env_bodies.py) requires."""
    c = mjx_and_c_rollouts("hopper_3", 10, physics="c")
    mjx = mjx_and_c_rollouts("hopper_3", 10, physics="jax")
    assert mjx["qpos_error"].max() < FLOAT32_STATE_TOLERANCE
    np.testing.assert_allclose(c["observation"], mjx["observation"], atol=FLOAT32_OBSERVATION_TOLERANCE)
    np.testing.assert_allclose(c["reward"], mjx["reward"], atol=1e-2)
    np.testing.assert_array_equal(c["terminated"], mjx["terminated"])


def test_c_physics_variants_follow_each_variants_own_model(tmp_path):
    """Three variants of one body in one vmapped C environment, each against ``mj_step`` on its own MJCF
    file: exactly equal states, and each variant's observation uses its own joint ranges."""
    errors = mjx_and_c_variant_rollouts("walker_2_flipped", 3, 30, str(tmp_path), physics="c")
    assert errors["qpos"] == 0.0 and errors["qvel"] == 0.0, errors
    assert errors["observation"] < 2e-5, errors
    assert errors["spread"] > 1e-2, "the variants moved alike: the variant index did not reach the physics"


def test_stale_kinematics_on_c_are_what_mj_step_leaves():
    """With ``stale_kinematics`` the observation reads the positions the last ``mj_step`` left, with the
    frame velocities of the new qvel at them (the original code's reads): for Euler integration (the
    cheetahs) the positions before the step."""
    import mujoco

    env = BodyEnv("cheetah_4_front", torso_relative_x=False, stale_kinematics=True, physics="c")
    action = np.random.default_rng(0).uniform(-1, 1, env.num_limbs).astype(np.float32)
    start = env.reset(jax.random.PRNGKey(0))
    start = start.replace(data=start.data.replace(qvel=jnp.full_like(start.data.qvel, 2.0)))  # a fast pose
    after = jax.jit(env.step)(start, jnp.asarray(action))
    model = env.mj_model
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = np.asarray(start.data.qpos), np.asarray(start.data.qvel)
    data.ctrl[:] = np.clip(action[env.motor_actions], -1, 1)
    for _ in range(env.morphology.frame_skip):
        mujoco.mj_step(model, data)
    mujoco.mj_comVel(model, data)
    expected = numpy_observation(env.morphology, model, data, torso_relative_x=False)
    np.testing.assert_allclose(np.asarray(after.observation), expected, atol=2e-5, rtol=1e-5)
    mujoco.mj_forward(model, data)
    fresh = numpy_observation(env.morphology, model, data, torso_relative_x=False)
    assert np.abs(fresh - expected).max() > 1e-3, "stale and fresh kinematics should differ after a step"


def test_an_exploding_copy_terminates_instead_of_being_reset_by_mujoco():
    """A copy whose joints pass EXPLOSION_SPEED stops stepping and terminates with reward 0 and a zero
    observation, as on MJX; MuJoCo's own check (which would reset the copy to its initial pose and print
    a warning) is never reached."""
    env = BodyEnv("hopper_3", physics="c")
    start = env.reset(jax.random.PRNGKey(0))
    blown = start.replace(data=start.data.replace(qvel=start.data.qvel.at[3].set(5e3)))
    after = jax.jit(env.step)(blown, jnp.zeros(env.num_limbs))
    assert bool(after.terminated) and float(after.reward) == 0.0
    assert not np.asarray(after.observation).any()


def test_multi_task_c_physics_runs_seeds_lock_step_and_resets():
    """Two bodies, 3 copies, 2 runs folded into one physics call, in lock-step rounds: a run on its own
    steps its physics exactly as beside another (its float32 observations to XLA's rounding of other
    batch shapes), and finished copies restart."""
    env = MultiTaskEnv(["hopper_3", "walker_2_flipped"], 3, physics="c", seeds=2, lock_step=True)
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    actions = jax.random.uniform(jax.random.PRNGKey(2), (40, 2, 2, 3, env.max_limbs), minval=-1, maxval=1)

    def rollout(environment, state, actions):
        def step(state, action):
            state, result = environment.step(state, action)
            return state, result

        return jax.lax.scan(step, state, actions)

    both, results = jax.jit(lambda k, a: rollout(env, env.reset(k), a))(keys, actions)
    alone_env = MultiTaskEnv(["hopper_3", "walker_2_flipped"], 3, physics="c", lock_step=True)
    alone, alone_results = jax.jit(lambda k, a: rollout(alone_env, alone_env.reset(k), a))(
        keys[1], actions[:, 1]
    )
    for body_both, body_alone in zip(both.bodies, alone.bodies, strict=True):
        for ours, theirs in zip(float64_state(body_both.data), float64_state(body_alone.data), strict=True):
            np.testing.assert_array_equal(ours[1], theirs)  # the physics: exactly
    np.testing.assert_array_equal(np.asarray(results.reward[:, 1]), np.asarray(alone_results.reward))
    np.testing.assert_allclose(np.asarray(both.observation[1]), np.asarray(alone.observation), atol=1e-6)
    assert np.asarray(results.terminated).any(), "no copy ended an episode in 40 steps"


ANOTHER_PROCESS = """
import jax, jax.numpy as jnp, numpy as np
from swat_jax.compilation_cache import compile_cached, enable_caches
from swat_jax.envs import MultiTaskEnv
from swat_jax.runs import programs
enable_caches()
env = MultiTaskEnv(["hopper_3", "walker_2_flipped"], 2, physics="c")
traces = []

def build():
    def rollout(key):
        traces.append(key)
        actions = jax.random.uniform(key, (30, 2, 2, env.max_limbs), minval=-1, maxval=1)
        step = lambda state, action: (env.step(state, action)[0], None)
        return jax.lax.scan(step, env.reset(key), actions)[0].observation

    return jax.jit(rollout)

key = jax.random.PRNGKey(3)
observation = np.asarray(compile_cached("rollout", build, (key,), programs.environments(env))(key))
calls = sum(sum(body.simulator.calls.values()) for body in env.envs)
print(observation.tobytes().hex(), len(traces), calls)
"""


def test_a_c_physics_program_compiled_in_one_process_runs_in_another(tmp_path):
    """The program names its simulator rather than holding this process's callback, so the program cache
    keeps it: a second process loads it without tracing, and its own simulators step the same states."""
    environment = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path)}
    compiled, loaded = (printed_words(ANOTHER_PROCESS, environment) for _ in range(2))
    assert compiled[1:] == ["1", "122"], "traces; calls: 2 bodies x (a reset, 30 x (a step, the resets))"
    assert loaded[1:] == ["0", "122"], "the second process traced the program again, or stepped no physics"
    assert loaded[0] == compiled[0]


EXIT_WHILE_RUNNING = """
import atexit, jax
from swat_jax.envs import MultiTaskEnv
env = MultiTaskEnv(["hopper_3", "walker_2_flipped"], 2, physics="c")

def rollout(key):
    actions = jax.random.uniform(key, (300, 2, 2, env.max_limbs), minval=-1, maxval=1)
    return jax.lax.scan(lambda state, action: (env.step(state, action)[0], None), env.reset(key), actions)[0]

key = jax.random.PRNGKey(0)
state = jax.jit(rollout).lower(key).compile()(key)
print("returned after", [body.simulator.calls[0] for body in env.envs], "calls")
atexit.register(lambda: print("at exit", [body.simulator.calls[0] for body in env.envs], "calls"))
"""


def test_a_process_that_exits_while_its_physics_runs_waits_for_it():
    """A C-physics program runs asynchronously; an interpreter that exits meanwhile first lets it end
    (else it calls into a stopped interpreter: errors from stopped thread pools, or a hung exit)."""
    finished = subprocess.run(
        [sys.executable, "-c", EXIT_WHILE_RUNNING], capture_output=True, text=True, timeout=120, check=True
    )
    assert "returned after [0, 0] calls" in finished.stdout, "the program ran to its end before returning"
    assert "at exit [601, 601] calls" in finished.stdout, finished.stdout
    assert "Error" not in finished.stderr, finished.stderr


def test_a_step_mujoco_rejects_names_the_body_and_the_fix(tmp_path):
    """A physics step MuJoCo refuses (here: an arena too small once the hopper touches the ground; the
    file loads) fails with the body's name, MuJoCo's message and what to change."""
    source = BodyEnv("hopper_3").morphology.path
    shutil.copytree(source.parent / "assets", tmp_path / "assets")
    small = tmp_path / "hopper_small.xml"
    small.write_text(re.sub(r"(<mujoco[^>]*>)", r'\1<size memory="5K"/>', source.read_text(), count=1))
    env = BodyEnv(str(small), physics="c")

    def hundred_steps(state):
        return jax.lax.scan(lambda s, _: (env.step(s, jnp.zeros(env.num_limbs)), None), state, None, 100)[0]

    with pytest.raises(Exception, match=r"hopper_small: MuJoCo rejected a physics step(.|\n)*<size memory"):
        jax.block_until_ready(jax.jit(hundred_steps)(env.reset(jax.random.PRNGKey(0))))


def test_auto_physics_is_c_on_the_cpu_and_bad_names_are_refused():
    assert jax.default_backend() == "cpu" and resolve_physics("auto") == "c"
    assert resolve_physics("jax") == "jax"
    with pytest.raises(ValueError, match="physics must be one of auto, jax, warp, c"):
        resolve_physics("mujoco")


def test_c_physics_is_refused_where_the_programs_run_on_an_accelerator(monkeypatch):
    """Its host function is registered for CPU programs; on a GPU the error says what to run instead."""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert resolve_physics("auto") == "jax"
    with pytest.raises(
        ValueError, match=r"physics 'c' runs MuJoCo C from programs on the CPU.*JAX_PLATFORMS=cpu"
    ):
        resolve_physics("c")
