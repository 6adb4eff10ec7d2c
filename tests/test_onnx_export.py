"""python -m swat_jax.export --format onnx writes an ONNX model of the actor that onnxruntime runs, without
jax, to the JAX policy's actions on every body of a set; the command line and its errors."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from swat_jax import export, onnx_policy, serving
from swat_jax.cli import ERROR_STATUS
from swat_jax.morphology import StructureBatch, get_set, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.runs.trained import load_policy

FEATURES = 17
"""Observation values per limb of the walker family."""
WALKERS = get_set("walker").train
TOLERANCE = dict(atol=1e-5, rtol=1e-4)
"""The issue's bound on onnxruntime against the JAX policy."""


def observations(batch: int, limbs: int, features: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(batch, limbs, features)).astype(np.float32)


@pytest.mark.parametrize("name", ["swat", "amorpheus"])
def test_onnxruntime_acts_as_the_jax_policy_on_every_body_of_a_set(name, tmp_path):
    """A random actor over Walker++'s six bodies, written as an ONNX policy file: for each body, named or
    given as its structure arrays, and two batch sizes (the batch dimension is dynamic), onnxruntime's
    actions equal the JAX actor's."""
    actor, _ = make_actor_critic(network_config(name, width=16, heads=2, layers=1, feedforward=32), FEATURES)
    params = jax.jit(actor.init)(jax.random.key(1))
    bodies = [load(body) for body in WALKERS]
    structures = pad_structures(bodies, 7)
    model = export.onnx_actor(actor, params, jax.tree.map(lambda x: x[0], structures))
    path = tmp_path / "walkers.onnx"
    export.write_onnx_policy(path, model, structures, WALKERS, FEATURES, algo=name)
    policy = onnx_policy.load(path)
    assert policy.bodies == WALKERS and policy.max_limbs == 7 and policy.metadata["algo"] == name
    act = jax.jit(lambda observation, structure: actor.apply(params, observation, structure))
    for row, body in enumerate(WALKERS):
        structure = jax.tree.map(lambda x, row=row: np.asarray(x[row]), structures)
        for batch in (1, 5):
            observation = observations(batch, 7, FEATURES, seed=row)
            expected = np.asarray(act(observation, StructureBatch(*structure)))
            np.testing.assert_allclose(policy(observation, body), expected, **TOLERANCE, err_msg=body)
            np.testing.assert_allclose(policy(observation, structure._asdict()), expected, **TOLERANCE)


def test_a_set_actor_of_a_3d_body_exports_to_both_formats(tmp_path):
    """SET (3D only): the jax.export file and the ONNX model act as the JAX actor, [batch, L, 3] actions."""
    body, features = "3d_hopper_4_lower_shin", 41
    network = network_config("set", width=8, heads=2, layers=1, feedforward=8)
    actor, _ = make_actor_critic(network, features, motors=3)
    params = jax.jit(actor.init)(jax.random.key(0))
    structures = pad_structures([load(body)], 6)
    structure = jax.tree.map(lambda x: x[0], structures)
    observation = observations(5, 6, features)
    expected = np.asarray(jax.jit(actor.apply)(params, observation, structure))
    assert expected.shape == (5, 6, 3) and np.abs(expected).max() > 1e-3
    program = export.serialize_actor(actor, params, structure, ("cpu",))
    export.write_policy(tmp_path / "set.npz", program, structures, [body], features)
    np.testing.assert_allclose(serving.load(tmp_path / "set.npz")(observation, body), expected, **TOLERANCE)
    model = export.onnx_actor(actor, params, structure)
    export.write_onnx_policy(tmp_path / "set.onnx", model, structures, [body], features, algo="set")
    np.testing.assert_allclose(
        onnx_policy.load(tmp_path / "set.onnx")(observation, body), expected, **TOLERANCE
    )


def test_smp_is_refused_with_the_format_that_serves_it():
    actor, _ = make_actor_critic(network_config("smp", max_children=2), FEATURES)
    params = jax.jit(actor.init)(jax.random.key(0))
    structure = jax.tree.map(lambda x: x[0], pad_structures([load(WALKERS[0])], 7))
    with pytest.raises(export.ExportError, match="--format jax"):
        export.onnx_actor(actor, params, structure)


@pytest.fixture(scope="module")
def onnx_file(trained_run, tmp_path_factory):
    """The tiny AMORPHEUS run of hopper_3 exported by the command line with --format onnx, and its output."""
    path = tmp_path_factory.mktemp("onnx") / "hopper.onnx"
    status = export.main([str(trained_run), "--format", "onnx", "-o", str(path)])
    assert status == 0
    return path


def test_the_command_writes_the_trained_policy(onnx_file, trained_run):
    """The file's actions are the run's policy's (its first seed), and its metadata says what it is."""
    policy = onnx_policy.load(onnx_file)
    trained = load_policy(trained_run)
    assert policy.metadata["format"] == onnx_policy.FORMAT and policy.metadata["algo"] == "amorpheus"
    assert policy.bodies == ("hopper_3",) and policy.observation_features == 19
    observation = observations(4, policy.max_limbs, 19)
    task_set = trained.task_set([load("hopper_3")], max_limbs=policy.max_limbs)
    expected = trained.actor.apply(
        trained.seed_params(0), observation, jax.tree.map(lambda x: x[0], task_set.structure)
    )
    np.testing.assert_allclose(policy(observation, "hopper_3"), np.asarray(expected), **TOLERANCE)


def test_the_file_runs_without_jax(onnx_file, tmp_path):
    """swat_jax.onnx_policy loads and runs the file with jax (and the training code) unimportable."""
    observation = observations(3, 3, 19)
    np.save(tmp_path / "observation.npy", observation)
    np.save(tmp_path / "expected.npy", onnx_policy.load(onnx_file)(observation, "hopper_3"))
    script = textwrap.dedent(
        f"""
        import sys
        import numpy as np
        for name in ("jax", "jaxlib", "flax", "mujoco", "jax2onnx"):
            sys.modules[name] = None
        import swat_jax.onnx_policy

        policy = swat_jax.onnx_policy.load({str(onnx_file)!r})
        actions = policy(np.load({str(tmp_path / "observation.npy")!r}), "hopper_3")
        np.testing.assert_array_equal(actions, np.load({str(tmp_path / "expected.npy")!r}))
        print("ok")
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=os.environ, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


CONTROL_LOOP = """
import sys
import numpy as np
for name in ("jax", "jaxlib", "flax", "jax2onnx"):
    sys.modules[name] = None
import mujoco
import swat_jax.onnx_policy

policy = swat_jax.onnx_policy.load(sys.argv[1])
body, start = "hopper_3", np.load(sys.argv[2])
model = mujoco.MjModel.from_xml_path(sys.argv[3])
data = mujoco.MjData(model)
data.qpos[:], data.qvel[:] = start["qpos"], start["qvel"]
mujoco.mj_forward(model, data)
observations, controls, positions = [], [], []
for _ in range(int(sys.argv[4])):
    observation = policy.observe(body, data)
    data.ctrl[:] = policy.controls(body, policy(observation, body)[0])
    policy.simulate(body, model, data)
    observations.append(observation[0])
    controls.append(data.ctrl.copy())
    positions.append(data.qpos.copy())
np.savez(sys.argv[5], observation=observations, ctrl=controls, qpos=positions)
"""
"""The docs' control loop (docs/evaluation-and-export.md), in a process where jax cannot be imported."""


def test_a_control_loop_without_jax_steps_as_the_environment(onnx_file, trained_run, tmp_path):
    """From one start state, the control loop on MuJoCo C with NumPy observations and onnxruntime actions
    sees the observations, sets the controls and reaches the states of BodyEnv on C physics (with the run's
    observation switches: the paper preset's stale kinematics and absolute limb x) acting through the same
    file, step by step."""
    from swat_jax.envs import BodyEnv

    policy, switches = onnx_policy.load(onnx_file), load_policy(trained_run).config.envs
    assert switches.stale_kinematics and not switches.torso_relative_x, "the test should cover the quirks"
    env = BodyEnv(
        load("hopper_3"),
        physics="c",
        torso_relative_x=switches.torso_relative_x,
        stale_kinematics=switches.stale_kinematics,
    )
    state, steps = env.reset(jax.random.key(3)), 25
    np.savez(tmp_path / "start.npz", qpos=state.data.qpos, qvel=state.data.qvel)
    step = jax.jit(env.step)
    expected = {"observation": [], "ctrl": [], "qpos": []}
    for _ in range(steps):
        observation = np.asarray(state.observation)[None]
        state = step(state, policy(observation, "hopper_3")[0])
        for name, value in zip(expected, (observation[0], state.data.ctrl, state.data.qpos), strict=True):
            expected[name].append(np.asarray(value))
    assert not np.any(np.asarray(state.terminated)), "the episode should last the test's steps"
    arguments = [onnx_file, tmp_path / "start.npz", load("hopper_3").path, steps, tmp_path / "loop.npz"]
    result = subprocess.run(
        [sys.executable, "-c", CONTROL_LOOP, *map(str, arguments)],
        capture_output=True,
        text=True,
        env=os.environ,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    loop = np.load(tmp_path / "loop.npz")
    for name, values in expected.items():
        np.testing.assert_allclose(loop[name], np.stack(values), atol=2e-5, rtol=1e-5, err_msg=name)
    assert np.ptp(loop["qpos"][:, 1]) > 0.01, "the body should move"


def test_errors_name_the_file_and_the_fix(onnx_file, trained_run, tmp_path, capsys):
    assert export.main([str(trained_run), "--format", "onnx", "-o", str(tmp_path / "a.npz")]) == ERROR_STATUS
    assert "use the suffix .onnx" in capsys.readouterr().err
    policy = onnx_policy.load(onnx_file)
    with pytest.raises(ValueError, match="has no body 'walker_7_main'; it has hopper_3"):
        policy(observations(1, 3, 19), "walker_7_main")
    with pytest.raises(ValueError, match=r"observation must be \[batch, 3, 19\]"):
        policy(observations(1, 4, 19), "hopper_3")
    with pytest.raises(export.ExportError, match="no such file"):
        onnx_policy.load(tmp_path / "missing.onnx")
    foreign = tmp_path / "foreign.onnx"
    foreign.write_bytes(identity_model().SerializeToString())
    with pytest.raises(export.ExportError, match="an ONNX model, but not a swat_jax policy"):
        onnx_policy.load(foreign)
    (tmp_path / "garbage.onnx").write_bytes(b"not a model")
    with pytest.raises(export.ExportError, match="not an ONNX model onnxruntime can run"):
        onnx_policy.load(tmp_path / "garbage.onnx")


def identity_model():
    """An ONNX model that is not a policy: y = x."""
    from onnx import TensorProto, helper

    tensor = helper.make_tensor_value_info
    graph = helper.make_graph(
        [helper.make_node("Identity", ["x"], ["y"])],
        "identity",
        [tensor("x", TensorProto.FLOAT, [1])],
        [tensor("y", TensorProto.FLOAT, [1])],
    )
    return helper.make_model(graph, ir_version=10, opset_imports=[helper.make_opsetid("", 17)])
