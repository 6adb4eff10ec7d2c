"""swat_jax.export: the exported file acts as the trained policy, for any batch size and padding, without
the training code; the command line and its errors."""

import contextlib
import io
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from swat_jax import export
from swat_jax.morphology import StructureBatch, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.runs.experiment import load_policy

FEATURES = 19
"""Observation values per limb of the hopper family."""
BODY = "hopper_3"
TRAINING_CODE = (
    "flax",
    "optax",
    "orbax",
    "mujoco",
    "swat_jax.networks",
    "swat_jax.td3",
    "swat_jax.runs",
    "swat_jax.envs",
    "swat_jax.morphology",
)
"""Modules the loaded policy must run without."""


@pytest.fixture(scope="module")
def export_command(trained_run, tmp_path_factory) -> tuple[Path, str]:
    """The tiny run exported by the command line with the default max limbs (hopper_3's 3): the file and
    what the command printed."""
    path = tmp_path_factory.mktemp("export") / "policy.npz"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert export.main([str(trained_run), "-o", str(path)]) == 0
    return path, printed.getvalue()


@pytest.fixture(scope="module")
def exported(export_command) -> Path:
    return export_command[0]


@pytest.fixture(scope="module")
def trained(trained_run):
    return load_policy(trained_run)


def observations(batch: int, limbs: int, real_limbs: int = 3, seed: int = 0) -> np.ndarray:
    """[batch, limbs, F] float32 observations, zero beyond the first ``real_limbs`` limbs."""
    values = np.random.default_rng(seed).normal(size=(batch, limbs, FEATURES)).astype(np.float32)
    values[:, real_limbs:] = 0.0
    return values


def body_structure(hopper_folder: Path, max_limbs: int) -> StructureBatch:
    """hopper_3's StructureBatch slice padded to ``max_limbs``."""
    batch = pad_structures([load(hopper_folder / f"{BODY}.xml")], max_limbs)
    return jax.tree.map(lambda x: x[0], batch)


def test_command_line_writes_the_file(export_command):
    exported, printed = export_command
    assert printed.startswith(f"wrote {exported} (")
    assert "amorpheus policy after 600 environment steps; max limbs 3, 19 observation features" in printed
    assert printed.rstrip().endswith("bodies (1): hopper_3")
    metadata = json.loads(str(np.load(exported)["metadata"]))
    assert metadata["format"] == export.FORMAT
    assert metadata["algo"] == "amorpheus"
    assert metadata["max_limbs"] == 3
    assert metadata["observation_features"] == FEATURES
    assert metadata["bodies"] == metadata["train_bodies"] == [BODY]
    assert metadata["env_steps"] == 600
    assert metadata["platforms"] == list(export.PLATFORMS)
    assert tuple(metadata["structure_fields"]) == StructureBatch._fields


def test_properties_and_stored_structures(exported, hopper_folder):
    policy = export.load(exported)
    assert (policy.max_limbs, policy.observation_features, policy.bodies) == (3, FEATURES, (BODY,))
    expected = body_structure(hopper_folder, 3)
    for name, array in policy.structure(BODY).items():
        np.testing.assert_array_equal(array, getattr(expected, name))


def test_matches_the_trained_policy_at_two_batch_sizes(exported, trained, hopper_folder):
    policy = export.load(exported)
    structure = body_structure(hopper_folder, 3)
    for batch, by in ((1, BODY), (64, structure)):
        observation = observations(batch, 3, seed=batch)
        actions = policy(observation, by)
        assert actions.shape == (batch, 3)
        np.testing.assert_allclose(actions, trained.act(observation, structure), atol=1e-5)


def test_padded_limbs_do_not_change_actions(trained_run, trained, hopper_folder, tmp_path, capsys):
    path = tmp_path / "padded.npz"
    assert export.main([str(trained_run), "-o", str(path), "--max-limbs", "5", "--platforms", "cpu"]) == 0
    assert "max limbs 5" in capsys.readouterr().out
    policy = export.load(path)
    observation = observations(8, 5, real_limbs=5)  # junk, not zeros, on the padded limbs
    actions = np.asarray(policy(observation, BODY))
    expected = trained.act(observation[:, :3], body_structure(hopper_folder, 3))
    np.testing.assert_allclose(actions[:, :3], expected, atol=1e-5)
    np.testing.assert_array_equal(actions[:, 3:], 0.0)
    assert policy.metadata["platforms"] == ["cpu"]


@pytest.mark.parametrize("algo", ["swat", "amorpheus", "smp"])
def test_every_architecture_exports_with_a_symbolic_batch(algo, hopper_folder, tmp_path):
    network = network_config(algo, width=8, heads=1, layers=1, feedforward=8)
    if algo == "smp":
        network = network_config(algo, message_width=4, up_hidden=(8,), down_hidden=(8,))
    actor, _ = make_actor_critic(network, FEATURES)
    params = jax.jit(actor.init)(jax.random.key(0))
    structures = pad_structures([load(hopper_folder / f"{BODY}.xml")], 4)
    program = export.serialize_actor(actor, params, jax.tree.map(lambda x: x[0], structures), ("cpu",))
    export.write_policy(tmp_path / "random.npz", program, structures, [BODY], FEATURES, algo=algo)
    policy = export.load(tmp_path / "random.npz")
    for batch in (1, 5):
        observation = observations(batch, 4, seed=batch)
        expected = jax.jit(actor.apply)(params, observation, jax.tree.map(lambda x: x[0], structures))
        np.testing.assert_allclose(policy(observation, BODY), expected, atol=1e-5)


def test_runs_without_the_training_code(exported, trained, hopper_folder, tmp_path):
    observation = observations(4, 3)
    np.save(tmp_path / "observation.npy", observation)
    np.save(tmp_path / "expected.npy", trained.act(observation, body_structure(hopper_folder, 3)))
    script = textwrap.dedent(
        f"""
        import sys
        import numpy as np
        blocked = {TRAINING_CODE!r}
        for name in blocked:
            sys.modules[name] = None
        import swat_jax.export

        policy = swat_jax.export.load({str(exported)!r})
        actions = policy(np.load({str(tmp_path / "observation.npy")!r}), {BODY!r})
        np.testing.assert_allclose(actions, np.load({str(tmp_path / "expected.npy")!r}), atol=1e-5)
        loaded = [name for name in sys.modules if name.startswith(blocked) and sys.modules[name] is not None]
        assert not loaded, loaded
        print("ok")
        """
    )
    environment = {**os.environ, "SWAT_JAX_COMPILATION_CACHE": "0"}
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=environment, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


def test_command_line_errors(trained_run, tmp_path, capsys):
    cases = [
        ([str(tmp_path / "missing"), "-o", str(tmp_path / "a.npz")], "no such run directory"),
        ([str(trained_run), "-o", str(tmp_path / "a.zip")], "use the suffix .npz"),
        (
            [str(trained_run), "-o", str(tmp_path / "a.npz"), "--max-limbs", "2"],
            "below the 3 limbs of hopper_3",
        ),
    ]
    for argv, message in cases:
        assert export.main(argv) == export.ERROR_STATUS
        error = capsys.readouterr().err
        assert error.startswith("error: ") and message in error
    assert not (tmp_path / "a.npz").exists()
    with pytest.raises(SystemExit):
        export.main([str(trained_run), "-o", str(tmp_path / "a.npz"), "--platforms", "gpu"])
    assert "platforms must be drawn from cpu, cuda, rocm, tpu" in capsys.readouterr().err


def test_files_that_are_not_exported_policies(tmp_path):
    text = tmp_path / "notes.npz"
    text.write_text("hello")
    other = tmp_path / "other.npz"
    np.savez(other, weights=np.zeros(3))
    wrong_format = tmp_path / "wrong.npz"
    np.savez(wrong_format, program=np.zeros(3, np.uint8), metadata=np.array(json.dumps({"format": "x"})))
    cases = [
        (tmp_path / "absent.npz", "no such file"),
        (text, "not a NumPy .npz archive"),
        (other, "the archive has no program or metadata (it holds weights)"),
        (wrong_format, "its metadata format is not 'swat_jax.exported_policy'"),
    ]
    for path, message in cases:
        with pytest.raises(export.ExportError, match=str(path)) as error:
            export.load(path)
        assert message in str(error.value)


def test_wrong_inputs_name_the_expected_shape(exported, hopper_folder):
    policy = export.load(exported)
    with pytest.raises(ValueError, match=r"observation must be \[batch, 3, 19\].*got shape \(2, 4, 19\)"):
        policy(np.zeros((2, 4, FEATURES)), BODY)
    with pytest.raises(ValueError, match=r"observation must be \[batch, 3, 19\].*got shape \(2, 3, 18\)"):
        policy(np.zeros((2, 3, FEATURES - 1)), BODY)
    with pytest.raises(ValueError, match=r"has no body 'walker_2_main'; it has hopper_3"):
        policy(np.zeros((2, 3, FEATURES)), "walker_2_main")
    padded = body_structure(hopper_folder, 5)
    with pytest.raises(ValueError, match=r"structure.limb_mask must be \[3\] bool .* got shape \[5\]"):
        policy(np.zeros((2, 3, FEATURES)), padded)
    with pytest.raises(ValueError, match="structure has no field 'parents'"):
        policy(np.zeros((2, 3, FEATURES)), {"limb_mask": body_structure(hopper_folder, 3).limb_mask})
