"""swat_jax.export writes and swat_jax.serving reads: the exported file acts as the trained policy, for any
batch size and padding, without the training code; the command line and its errors."""

import contextlib
import dataclasses
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

from swat_jax import export, serving
from swat_jax.cli import ERROR_STATUS
from swat_jax.morphology import StructureBatch, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.runs.trained import load_policy

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
TINY_SWAT = network_config("swat", width=8, heads=1, layers=1, feedforward=8)
NEWER_JAX_POLICY = Path(__file__).parent / "data" / "policy_jax_0_11_2.npz"
"""``write_random_policy(path, TINY_SWAT, 3, export.PLATFORMS)`` run under jax 0.11.2 (the Python 3.12
pins): 24 KB."""
NEWER_JAX = "0.11.2"


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


def write_random_policy(
    path: Path, network, max_limbs: int, platforms: tuple[str, ...] = ("cpu",), **details
) -> tuple:
    """A randomly initialised actor of ``network`` for hopper_3 padded to ``max_limbs``, exported to
    ``path``; returns the actor, its parameters and hopper_3's structure slice."""
    actor, _ = make_actor_critic(network, FEATURES)
    params = jax.jit(actor.init)(jax.random.key(0))
    structures = pad_structures([load(BODY)], max_limbs)
    structure = jax.tree.map(lambda x: x[0], structures)
    program = export.serialize_actor(actor, params, structure, platforms)
    export.write_policy(path, program, structures, [BODY], FEATURES, **details)
    return actor, params, structure


def version(text: str) -> tuple[int, ...]:
    """ "0.10.2" -> (0, 10, 2)."""
    return tuple(int(part) for part in text.split(".")[:3])


def body_structure(hopper_folder: Path, max_limbs: int) -> StructureBatch:
    """hopper_3's StructureBatch slice padded to ``max_limbs``."""
    batch = pad_structures([load(hopper_folder / f"{BODY}.xml")], max_limbs)
    return jax.tree.map(lambda x: x[0], batch)


def test_command_line_writes_the_file(export_command):
    exported, printed = export_command
    assert printed.startswith(f"wrote {exported} (")
    assert (
        "amorpheus policy (seed 0) after 600 environment steps; max limbs 3, 19 observation features"
        in printed
    )
    assert printed.rstrip().endswith("bodies (1): hopper_3")
    metadata = json.loads(str(np.load(exported)["metadata"]))
    assert metadata["format"] == serving.FORMAT
    assert metadata["algo"] == "amorpheus"
    assert metadata["max_limbs"] == 3
    assert metadata["observation_features"] == FEATURES
    assert metadata["bodies"] == metadata["train_bodies"] == [BODY]
    assert metadata["env_steps"] == 600 and metadata["seed"] == 0
    assert metadata["platforms"] == list(export.PLATFORMS)
    assert tuple(metadata["structure_fields"]) == StructureBatch._fields


def test_properties_and_stored_structures(exported, hopper_folder):
    policy = serving.load(exported)
    assert (policy.max_limbs, policy.observation_features, policy.bodies) == (3, FEATURES, (BODY,))
    expected = body_structure(hopper_folder, 3)
    for name, array in policy.structure(BODY).items():
        np.testing.assert_array_equal(array, getattr(expected, name))


def test_matches_the_trained_policy_at_two_batch_sizes(exported, trained, hopper_folder):
    policy = serving.load(exported)
    structure = body_structure(hopper_folder, 3)
    for batch, by in ((1, BODY), (64, structure)):
        observation = observations(batch, 3, seed=batch)
        actions = policy(observation, by)
        assert actions.shape == (batch, 3)
        np.testing.assert_allclose(actions, trained.act(observation, structure), atol=1e-5)


def test_padded_limbs_do_not_change_actions_of_the_chosen_seed(
    trained_run, trained, hopper_folder, tmp_path, capsys
):
    path = tmp_path / "padded.npz"
    flags = ["--max-limbs", "5", "--platforms", "cpu", "--seed-index", "1"]
    assert export.main([str(trained_run), "-o", str(path), *flags]) == 0
    printed = capsys.readouterr().out
    assert "(seed 1)" in printed and "max limbs 5" in printed
    policy = serving.load(path)
    observation = observations(8, 5, real_limbs=5)  # junk, not zeros, on the padded limbs
    actions = np.asarray(policy(observation, BODY))
    structure = body_structure(hopper_folder, 3)
    expected = trained.act(observation[:, :3], structure, seed_index=1)
    np.testing.assert_allclose(actions[:, :3], expected, atol=1e-5)
    np.testing.assert_array_equal(actions[:, 3:], 0.0)
    assert not np.allclose(expected, trained.act(observation[:, :3], structure, seed_index=0), atol=1e-3)
    assert policy.metadata["platforms"] == ["cpu"] and policy.metadata["seed"] == 1
    assert export.main([str(trained_run), "-o", str(path), "--seed-index", "2"]) == 2
    assert "use an index from 0 to 1" in capsys.readouterr().err


@pytest.mark.parametrize("algo", ["swat", "amorpheus", "smp"])
def test_every_architecture_exports_with_a_symbolic_batch(algo, tmp_path):
    network = network_config(algo, width=8, heads=1, layers=1, feedforward=8)
    if algo == "smp":
        network = network_config(algo, message_width=4, up_hidden=(8,), down_hidden=(8,))
    actor, params, structure = write_random_policy(tmp_path / "random.npz", network, 4, algo=algo)
    policy = serving.load(tmp_path / "random.npz")
    assert policy.metadata["jax_version"] == jax.__version__
    for batch in (1, 5):
        observation = observations(batch, 4, seed=batch)
        expected = jax.jit(actor.apply)(params, observation, structure)
        np.testing.assert_allclose(policy(observation, BODY), expected, atol=1e-5)


def test_a_program_this_jax_cannot_read_is_refused_at_load(tmp_path):
    """Forged: the serialised StableHLO replaced by bytes that are not StableHLO, as a newer jax's are to an
    older one. The flatbuffer around it still reads, so only an eager load finds out."""
    valid = tmp_path / "valid.npz"
    write_random_policy(valid, TINY_SWAT, 3)
    exported = jax.export.deserialize(bytearray(np.load(valid)[serving.PROGRAM_KEY].tobytes()))
    forged = dataclasses.replace(exported, mlir_module_serialized=b"ML\xefR\x00 not StableHLO")
    path = tmp_path / "forged.npz"
    structures = pad_structures([load(BODY)], 3)
    export.write_policy(path, forged.serialize(), structures, [BODY], FEATURES, jax_version="0.99.0")
    with pytest.raises(serving.ExportError) as error:
        serving.load(path)
    message = str(error.value)
    assert message.startswith(
        f"{path}: its program was written by jax 0.99.0 and cannot be run by this jax {jax.__version__} ("
    )
    assert message.endswith(
        f"export the policy again with jax {jax.__version__} (python -m swat_jax.export RUN_DIR -o forged.npz)"
    )


def test_a_policy_written_by_jax_0_11_loads_only_where_jax_reads_it():
    """On jax 0.10 the file fails at load (it used to fail at its first call); on 0.11.2 it runs."""
    assert json.loads(str(np.load(NEWER_JAX_POLICY)[serving.METADATA_KEY]))["jax_version"] == NEWER_JAX
    if version(jax.__version__) < version(NEWER_JAX):
        with pytest.raises(
            serving.ExportError, match=f"written by jax {NEWER_JAX} and cannot be run by this jax"
        ):
            serving.load(NEWER_JAX_POLICY)
        return
    actions = serving.load(NEWER_JAX_POLICY)(observations(2, 3), BODY)
    assert actions.shape == (2, 3) and np.all(np.abs(actions) <= 1.0)


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
        import swat_jax.serving

        policy = swat_jax.serving.load({str(exported)!r})
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
        assert export.main(argv) == ERROR_STATUS
        error = capsys.readouterr().err
        assert error.startswith("error: ") and message in error
    assert not (tmp_path / "a.npz").exists()
    with pytest.raises(SystemExit):
        export.main([str(trained_run), "-o", str(tmp_path / "a.npz"), "--platforms", "gpu"])
    assert "invalid choice 'gpu' for argument '--platforms'" in capsys.readouterr().err


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
        with pytest.raises(serving.ExportError, match=str(path)) as error:
            serving.load(path)
        assert message in str(error.value)


def test_wrong_inputs_name_the_expected_shape(exported, hopper_folder):
    policy = serving.load(exported)
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
