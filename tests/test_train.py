"""The training command: run directory, metrics, checkpoints, interruption, exact resume, clear errors."""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import struct
import subprocess
import sys
import threading
import time
import typing
from pathlib import Path

import jax
import numpy as np
import pytest
from blocked_save_train import WRITE_BEGAN
from conftest import MORPHOLOGIES, tiny_train_config, train_flags
from subprocesses import python_path_environment
from tensorboardX.proto import event_pb2

from swat_jax.compilation_cache import lower_built_afresh
from swat_jax.eval import evaluate
from swat_jax.networks import NAMED_VARIANTS
from swat_jax.networks.initialisation import INITIALISATIONS
from swat_jax.runs.checkpoint import DAMAGED_DIR, CheckpointError, Checkpoints, flatten
from swat_jax.runs.config import (
    PRESETS,
    Algorithm,
    ConfigError,
    NetworkSizes,
    TrainConfig,
    fixed,
    load_config,
)
from swat_jax.runs.experiment import Experiment
from swat_jax.runs.metrics import read_metrics
from swat_jax.runs.trained import load_policy, network_items
from swat_jax.td3.iteration import IterationConfig
from swat_jax.train import RunExistsError, TrainCommand, main, parse_command, resolve, train

TIMING_COLUMNS = {"steps_per_second"}
STOPPING = "stopping after this iteration"
"""What the training command prints on stderr when it has counted a first stop signal."""


def final_state(run_dir: Path, config: TrainConfig | None = None):
    """The newest checkpoint of ``run_dir`` read by an Experiment of ``config`` (default: the run's own)."""
    config = config or load_config(run_dir / "config.json")
    checkpoints = Checkpoints(run_dir)
    try:
        return Experiment.build(config).restore_state(checkpoints)
    finally:
        checkpoints.close()


def tensorboard_tags(directory: Path) -> set[str]:
    """Scalar tags in the TensorBoard event files of ``directory`` (TFRecord framing read by hand)."""
    tags = set()
    for path in directory.glob("events.out.tfevents.*"):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset : offset + 8])
            event = event_pb2.Event.FromString(data[offset + 12 : offset + 12 + length])
            tags |= {value.tag for value in event.summary.value}
            offset += 12 + length + 4
    return tags


def test_run_directory_holds_config_metrics_tensorboard_and_checkpoints(trained_run):
    config = load_config(trained_run / "config.json")
    assert config == tiny_train_config(trained_run, Path(config.env))
    rows = read_metrics(trained_run)
    assert [(row["env_steps"], row["seed"]) for row in rows] == [
        (steps, seed) for steps in (200, 400, 600) for seed in (0, 1)
    ], "one row per seed per log interval"
    for column in ("return/hopper_3", "length/hopper_3", "episodes/hopper_3", "critic_loss", "actor_loss"):
        assert column in rows[0]
    assert all(row["steps_per_second"] > 0 for row in rows)
    for seed in (0, 1):
        seed_rows = [row for row in rows if row["seed"] == seed]
        assert sum(row["episodes/hopper_3"] for row in seed_rows) >= 3, "random episodes last ~80 steps"
    assert rows[-2]["critic_loss"] != rows[-1]["critic_loss"], "the seeds are independent runs"
    for seed in (0, 1):
        tags = tensorboard_tags(trained_run / "tensorboard" / f"seed{seed}")
        assert {"return/hopper_3", "length/hopper_3", "critic_loss", "steps_per_second"} <= tags
    steps = sorted(int(p.name) for p in (trained_run / "checkpoints").iterdir() if p.name.isdigit())
    assert steps == [400, 600]
    evaluated = [row["env_steps"] for row in rows if np.isfinite(row["eval/return/hopper_3"])]
    assert evaluated == [400, 400, 600, 600], "evaluations every --eval-interval steps and at the end"
    policy = load_policy(trained_run)
    assert policy.info.env_steps == 600 and policy.info.bodies == ("hopper_3",)
    assert policy.seeds == (0, 1)


def test_the_evaluation_during_training_is_the_eval_commands(trained_run):
    """The final row's eval/* columns are what swat_jax.eval measures on the final checkpoint."""
    final = {int(row["seed"]): row for row in read_metrics(trained_run) if row["env_steps"] == 600}
    [evaluation] = evaluate(load_policy(trained_run), ["hopper_3"], episodes=2, seed=0)
    for index, seed in enumerate(evaluation.seeds):
        row = final[seed]
        assert row["eval/return/hopper_3"] == pytest.approx(evaluation.returns[index].mean(), rel=1e-4)
        assert row["eval/length/hopper_3"] == pytest.approx(evaluation.lengths[index].mean())
        assert row["eval/mean_return"] == row["eval/return/hopper_3"], "one body"


def test_interrupted_and_resumed_run_equals_the_uninterrupted_one(trained_run, hopper_folder, tmp_path):
    config = tiny_train_config(tmp_path / "resumed", hopper_folder)

    def interrupt(iterations: int) -> None:
        if iterations == 3:
            signal.raise_signal(signal.SIGINT)

    handler = signal.getsignal(signal.SIGINT)
    stopped = train(config, progress=False, after_iteration=interrupt)
    assert stopped.interrupted and stopped.env_steps == 300
    assert signal.getsignal(signal.SIGINT) is handler, "the previous handler is restored"
    finished = train(config, resume=True, progress=False)
    assert not finished.interrupted and finished.env_steps == 600

    resumed, resumed_info = final_state(tmp_path / "resumed")
    uninterrupted, info = final_state(trained_run)
    assert resumed_info.iterations == info.iterations == 6
    a, b = flatten(resumed), flatten(uninterrupted)
    assert a.keys() == b.keys()
    differing = [key for key in a if not np.array_equal(np.asarray(a[key]), np.asarray(b[key]))]
    assert not differing, f"resumed run differs in {differing[:5]}"
    rows, reference = read_metrics(tmp_path / "resumed"), read_metrics(trained_run)
    assert [row["env_steps"] for row in rows] == [200, 200, 400, 400, 600, 600]
    for row, expected in zip(rows, reference, strict=True):
        assert {k: v for k, v in row.items() if k not in TIMING_COLUMNS} == pytest.approx(
            {k: v for k, v in expected.items() if k not in TIMING_COLUMNS}, nan_ok=True
        )


def test_a_counted_budget_stops_at_the_first_iteration_that_counts_it(
    trained_run, hopper_folder, tmp_path, capsys
):
    """--counted-steps 150 in the lock-step rounds: every seed stops at the first iteration after which it has
    counted 150 steps (one that counts fewer comes before it), short of --steps; with a counted budget past
    what --steps lets it take, the run stops at the cap and says how to go on."""
    config = tiny_train_config(tmp_path / "counted", hopper_folder, counted_steps=150, log_interval=100)
    result = train(config, progress=False)
    assert not result.interrupted and result.env_steps < config.steps
    rows = read_metrics(tmp_path / "counted")
    last = [row for row in rows if row["env_steps"] == result.env_steps]
    before = [row for row in rows if row["env_steps"] == result.env_steps - 100]
    assert min(row["counted_steps"] for row in last) >= 150 > min(row["counted_steps"] for row in before)
    assert all(row["stored_steps"] <= row["env_steps"] for row in rows)
    assert load_policy(tmp_path / "counted").info.env_steps == result.env_steps, "a checkpoint at the stop"
    capped = tiny_train_config(tmp_path / "capped", hopper_folder, counted_steps=5000)
    assert train(capped, progress=False).env_steps == 600, "the tiny run's program, whose rings fit 600"
    output = capsys.readouterr().out
    assert (
        "stopped at the --steps cap (600 steps taken) before --counted-steps 5,000: counted seed 0 " in output
    )
    assert f"--resume {tmp_path / 'capped'} --steps N" in output


def test_the_replay_holds_what_the_run_stores_and_grows_when_a_resume_raises_the_budget(
    trained_run, hopper_folder, tmp_path, capsys
):
    """Rings of the rows a budget stores, to the next power of two (100 steps of 2 copies: 100 per task, 128
    rows, below the capacity of 1,000; the program of the other 100-step runs here); resumed with --steps 600
    they grow to the capacity and the run ends as the uninterrupted 600-step run did."""
    config = tiny_train_config(tmp_path / "grown", hopper_folder, steps=100)
    train(config, progress=False)
    first = capsys.readouterr().out
    assert (
        "(2 seeds x 1 tasks x 128 transitions x 3 limbs x 19 features: what 100 steps store, rounded" in first
    )
    assert final_state(tmp_path / "grown")[0].buffer.data.reward.shape == (2, 1, 128)
    train(dataclasses.replace(config, steps=600), resume=True, progress=False)
    assert (
        "1 tasks x 1,000 transitions x 3 limbs x 19 features: --iteration.capacity 1,000)"
        in capsys.readouterr().out
    )
    grown, uninterrupted = flatten(final_state(tmp_path / "grown")[0]), flatten(final_state(trained_run)[0])
    differing = [key for key in grown if not np.array_equal(grown[key], uninterrupted[key])]
    assert not differing, f"the grown run differs in {differing[:5]}"
    with pytest.raises(
        CheckpointError,
        match=r"holds 600 transitions per task, more than the 256-row replay rings of --steps 200 take: resume with --steps 600 or more",
    ):
        final_state(tmp_path / "grown", dataclasses.replace(config, steps=200))


def test_existing_run_directory_is_not_overwritten(trained_run):
    config = load_config(trained_run / "config.json")
    with pytest.raises(RunExistsError, match="--resume"):
        train(config, progress=False)


def test_resume_refuses_options_that_contradict_the_saved_config(trained_run):
    defaults = TrainCommand()
    wider = dataclasses.replace(defaults.network, width=64)
    command = dataclasses.replace(defaults, resume=str(trained_run), network=wider, steps=1200)
    with pytest.raises(ConfigError, match=r"--network\.width 64 \(run has 16\)"):
        resolve(command, defaults)
    resumed = resolve(dataclasses.replace(defaults, resume=str(trained_run), steps=1200), defaults)
    assert resumed.steps == 1200 and resumed.network.width == 16 and resumed.run_dir == str(trained_run)


def copy_run(trained_run: Path, tmp_path: Path) -> Path:
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    config = load_config(run_dir / "config.json")
    (run_dir / "config.json").write_text(dataclasses.replace(config, run_dir=str(run_dir)).to_json())
    return run_dir


def test_a_checkpoint_with_one_replay_position_for_all_seeds_resumes_with_a_copy_per_seed(
    trained_run, tmp_path
):
    """Checkpoints written before each seed had its own replay write position (every seed wrote its
    replay at one position, []) are read with that position given to every seed."""
    run_dir = copy_run(trained_run, tmp_path)
    state, info = final_state(run_dir)
    shared = state.buffer.replace(position=state.buffer.position[0], size=state.buffer.size[0])
    shutil.rmtree(run_dir / "checkpoints")
    checkpoints = Checkpoints(run_dir)
    try:
        checkpoints.save(state.replace(buffer=shared), network_items(state.learner), info)
    finally:
        checkpoints.close()
    restored, _ = final_state(run_dir)
    assert restored.buffer.position.tolist() == [int(shared.position)] * 2
    assert restored.buffer.size.tolist() == [int(shared.size)] * 2
    expected = flatten(state)
    for key, value in flatten(
        restored.replace(
            buffer=restored.buffer.replace(position=state.buffer.position, size=state.buffer.size)
        )
    ).items():
        np.testing.assert_array_equal(value, expected[key], err_msg=key)


def test_mismatched_checkpoint_names_the_arrays(trained_run, tmp_path):
    run_dir = copy_run(trained_run, tmp_path)
    saved = load_config(run_dir / "config.json")
    config = dataclasses.replace(saved, network=dataclasses.replace(saved.network, width=32))
    with pytest.raises(CheckpointError, match=r"does not match this run: .*actor_params.*expected"):
        train(config, resume=True, progress=False)


def test_a_damaged_newest_checkpoint_is_set_aside_and_the_resume_equals_the_uninterrupted_run(
    trained_run, tmp_path, capsys
):
    """One byte flipped in the newest checkpoint's largest array file (the replay): the resume says so,
    moves it aside, continues from the checkpoint before it and ends where the uninterrupted run ended."""
    run_dir = copy_run(trained_run, tmp_path)
    newest = run_dir / "checkpoints" / "600"
    largest = max((p for p in (newest / "state").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    data = bytearray(largest.read_bytes())
    data[len(data) // 2] ^= 0x01
    largest.write_bytes(bytes(data))
    result = train(load_config(run_dir / "config.json"), resume=True, progress=False)
    assert not result.interrupted and result.env_steps == 600
    printed = capsys.readouterr().out.splitlines()
    refused = f"refused {newest}: the bytes of {largest.relative_to(newest)} changed after it was written"
    assert f"{refused}; moved to {run_dir / DAMAGED_DIR / '600'}" in printed
    assert f"resumed from {run_dir / 'checkpoints' / '400'}" in printed
    resumed, uninterrupted = flatten(final_state(run_dir)[0]), flatten(final_state(trained_run)[0])
    differing = [key for key in resumed if not np.array_equal(resumed[key], uninterrupted[key])]
    assert not differing, f"resumed run differs in {differing[:5]}"


def test_a_finished_run_resumed_ends_at_once_with_nothing_compiled(
    trained_run, tmp_path, capsys, monkeypatch
):
    run_dir = copy_run(trained_run, tmp_path)
    monkeypatch.setattr(Experiment, "compiled_iteration", lambda *args: pytest.fail("compiled the iteration"))
    result = train(load_config(run_dir / "config.json"), resume=True, progress=False)
    assert not result.interrupted and result.env_steps == 600
    assert "compiling" not in capsys.readouterr().out
    assert read_metrics(run_dir) == read_metrics(trained_run), "its metrics as they were"


def test_resume_without_checkpoint_starts_from_the_saved_config(trained_run, tmp_path):
    run_dir = copy_run(trained_run, tmp_path)
    shutil.rmtree(run_dir / "checkpoints")
    config = dataclasses.replace(load_config(run_dir / "config.json"), steps=100)
    result = train(config, resume=True, progress=False)
    assert not result.interrupted and result.env_steps == 100
    assert [row["env_steps"] for row in read_metrics(run_dir)] == [100, 100], "the old rows are dropped"


def test_a_resumed_run_compiles_the_fresh_runs_program(trained_run):
    """Fresh and restored states lower to the same program, so a resume hits the compilation cache."""
    experiment = Experiment.build(load_config(trained_run / "config.json"))
    checkpoints = Checkpoints(trained_run)
    try:
        restored, _ = experiment.restore_state(checkpoints)
    finally:
        checkpoints.close()
    fresh = experiment.init_state()
    iteration = experiment.iteration()
    assert iteration.lower(restored).as_text() == iteration.lower(fresh).as_text()


def test_a_second_run_in_one_process_lowers_the_first_runs_iteration(tmp_path):
    """Two runs of one config in one process (each builds its Experiment, initialises its state and lowers
    its iteration) lower the same program, so the second hits the first's persistent-cache entry. With
    plain ``lower``, two bodies' iteration gains a duplicated helper function the second time (JAX's
    in-memory trace caches)."""
    folder = tmp_path / "two_hoppers"
    folder.mkdir()
    for body in ("hopper_3", "hopper_4"):
        shutil.copy(MORPHOLOGIES / f"{body}.xml", folder)
    shutil.copytree(MORPHOLOGIES / "assets", folder / "assets")
    config = tiny_train_config(tmp_path / "run", folder)
    texts = []
    for _ in range(2):
        experiment = Experiment.build(config)
        state = experiment.init_state()
        texts.append(lower_built_afresh(experiment.iteration, state).as_text())
    assert texts[0] == texts[1]


def test_a_stop_request_is_honoured_within_one_iteration(trained_run, hopper_folder, tmp_path):
    """A signal sent by another thread while iterations run stops after the running one (none queued behind
    it). The signal is sent as the third iteration ends, so the run is interrupted however fast the machine."""
    steps = 6000  # 60 iterations, one metrics row: nothing else waits for the device
    config = tiny_train_config(
        tmp_path / "stopped", hopper_folder, steps=steps, log_interval=steps, checkpoint_interval=steps
    )
    finished: list[int] = []
    at_signal: list[int] = []

    def send_stop() -> None:
        at_signal.append(len(finished))
        os.kill(os.getpid(), signal.SIGINT)

    def record(iterations: int) -> None:
        finished.append(iterations)
        if iterations == 3:
            threading.Thread(target=send_stop).start()

    result = train(config, progress=False, after_iteration=record)
    assert at_signal, "the stop request was sent"
    assert result.interrupted and result.env_steps < steps
    assert len(finished) <= at_signal[0] + 2, (
        f"{at_signal[0]} iterations had finished when the stop was requested, {len(finished)} ran"
    )
    assert final_state(tmp_path / "stopped")[1].iterations == len(finished)


def run_training_command(
    flags: list[str],
    signal_on: str = "",
    signals: int = 0,
    script: tuple[str, ...] = ("-m", "swat_jax.train"),
):
    """``python SCRIPT FLAGS`` (``python -m swat_jax.train`` by default), sent a SIGINT on the first stdout line
    that contains ``signal_on``, and ``signals - 1`` more, each once the process has said on stderr that it
    counted the one before (signals sent together may arrive as one). A process still running 120 seconds
    after its start is killed (status -9), so a hang fails.

    Returns (exit status, stdout, stderr, seconds from the last SIGINT to the exit).
    """
    process = subprocess.Popen(
        [sys.executable, *script, *flags],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=python_path_environment(Path(__file__).parent, PYTHONUNBUFFERED="1"),
    )
    watchdog = threading.Timer(120, process.kill)
    watchdog.start()
    lines, errors, last_signal = [], [], None
    for line in process.stdout if signals else ():
        lines.append(line)
        if signal_on in line:
            break
    for sent in range(signals):
        process.send_signal(signal.SIGINT)
        last_signal = time.perf_counter()
        while sent + 1 < signals and (error := process.stderr.readline()):
            errors.append(error)
            if STOPPING in error:
                break
    status = process.wait()
    exit_time = time.perf_counter()
    watchdog.cancel()
    lines.append(process.stdout.read())
    errors.append(process.stderr.read())
    return status, "".join(lines), "".join(errors), exit_time - (last_signal or exit_time)


def test_a_second_ctrl_c_aborts_at_once(trained_run, hopper_folder, tmp_path):
    """Two SIGINTs while the main thread waits in a checkpoint write (one that never ends,
    tests/blocked_save_train.py), where Python would run one handler for both: each is counted, and the
    second aborts at once without a checkpoint. (``trained_run`` first puts the tiny run's program
    in the compilation cache.)"""
    config = tiny_train_config(
        tmp_path / "aborted", hopper_folder, steps=100_000, log_interval=100_000, checkpoint_interval=100
    )
    status, _, stderr, seconds = run_training_command(
        [*train_flags(config), "--no-progress"],
        WRITE_BEGAN,
        signals=2,
        script=(str(Path(__file__).parent / "blocked_save_train.py"),),
    )
    assert status == 130, stderr
    assert STOPPING in stderr and "aborted without a checkpoint" in stderr
    assert "Traceback" not in stderr and seconds < 5
    assert not (tmp_path / "aborted" / "checkpoints").exists() or not any(
        p.name.isdigit() for p in (tmp_path / "aborted" / "checkpoints").iterdir()
    )


def test_ctrl_c_while_compiling_exits_cleanly_and_the_run_can_be_started(
    trained_run, hopper_folder, tmp_path, monkeypatch, capsys
):
    """Ctrl-C while the iteration compiles: the KeyboardInterrupt Python raises there (raised here where the
    compile or the load from the cache starts, so the test does not race a compile that a loaded machine or
    the caches make short)."""
    config = tiny_train_config(tmp_path / "early", hopper_folder, steps=100)

    def compile_interrupted(experiment: Experiment, state):
        raise KeyboardInterrupt

    with monkeypatch.context() as patched:
        patched.setattr(Experiment, "compiled_iteration", compile_interrupted)
        assert main(train_flags(config)) == 130
    stderr = capsys.readouterr().err
    assert "Traceback" not in stderr
    assert f"--resume {tmp_path / 'early'}" in stderr
    result = train(config, resume=True, progress=False)
    assert not result.interrupted and result.env_steps == 100


def test_a_run_with_no_intact_checkpoint_gives_the_one_error_line_and_nothing_after(trained_run, tmp_path):
    """Both checkpoints truncated: ``train --resume`` exits 2 with one line naming each and why, having read
    nothing of them (before checkpoints were checked, what Orbax's abandoned reads printed after a failed
    restore made this flaky)."""
    run_dir = copy_run(trained_run, tmp_path)
    for steps in (400, 600):
        manifest = run_dir / "checkpoints" / str(steps) / "state" / "manifest.ocdbt"
        manifest.write_bytes(manifest.read_bytes()[: manifest.stat().st_size // 2])
    status, _, stderr, _ = run_training_command(["--resume", str(run_dir), "--no-progress"])
    [line] = stderr.splitlines()
    assert status == 2
    assert line.startswith(
        f"error: no intact checkpoint in {run_dir / 'checkpoints'} (600: state/manifest.ocdbt"
    )
    assert "; 400: state/manifest.ocdbt has" in line and line.endswith("start the run again with --overwrite")
    assert not (run_dir / DAMAGED_DIR).exists()


def test_config_file_errors_name_the_file_and_field(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"env": "hopper", "learning_rate": 0.1}')
    with pytest.raises(ConfigError, match=r"config.json: unknown TrainConfig fields \['learning_rate'\]"):
        load_config(path)
    path.write_text("{not json")
    with pytest.raises(ConfigError, match="not readable JSON"):
        load_config(path)
    with pytest.raises(ConfigError, match="--env: unknown environment set 'hoper'; valid sets: hopper"):
        TrainConfig(env="hoper")
    with pytest.raises(ConfigError, match=r"--iteration\.chunk must be a positive"):
        TrainConfig(iteration=dataclasses.replace(PRESETS["paper"].iteration, chunk=0))
    with pytest.raises(
        ConfigError, match=r"exploration-noise-max are standard deviations.*got 0.126 and -0.1"
    ):
        TrainConfig(iteration=dataclasses.replace(PRESETS["paper"].iteration, exploration_noise_max=-0.1))
    with pytest.raises(ConfigError, match=r"--td3\.target-pessimism must be in \[0, 1\].*got 1.5"):
        TrainConfig(td3=dataclasses.replace(PRESETS["paper"].td3, target_pessimism=1.5))
    for penalty, start in ((-0.01, 0.0), (float("nan"), 0.0), (0.1, -1.0)):
        with pytest.raises(ConfigError, match=r"--td3\.action-penalty .* must be 0 or positive; got"):
            td3 = dataclasses.replace(PRESETS["paper"].td3, action_penalty=penalty, action_penalty_from=start)
            TrainConfig(td3=td3)
    fast = PRESETS["fast"]
    with pytest.raises(ConfigError, match=r"--td3\.atoms needs .* got 0.25 .* add --td3\.target-pessimism 1"):
        dataclasses.replace(fast, td3=dataclasses.replace(fast.td3, atoms=51))


def test_every_named_network_is_an_algo_choice():
    assert typing.get_args(Algorithm) == tuple(NAMED_VARIANTS)


def test_smp_hidden_sizes_both_modules_and_is_checked():
    network = TrainConfig(env="hopper", algo="smp", network=NetworkSizes(smp_hidden=32)).network_config()
    assert (network.up_hidden, network.down_hidden) == ((32, 32), (32, 32))
    assert TrainConfig(env="hopper", algo="smp").network_config().down_hidden == (400, 300), "the paper's"
    with pytest.raises(ConfigError, match=r"--network\.smp-hidden must be a positive whole number, got 0"):
        TrainConfig(env="hopper", algo="smp", network=NetworkSizes(smp_hidden=0))


def test_presets_follow_the_budget_convention():
    paper, fast = PRESETS["paper"], PRESETS["fast"]
    assert paper == TrainConfig(), "the paper preset is the defaults, the base the others differ from"
    assert paper.envs.copies == 1 and paper.iteration.updates == paper.iteration.chunk, "1 update per step"
    assert paper.td3.batch_size == 100 and paper.iteration.capacity == 500_000
    assert fast.envs.copies > 1 and fast.iteration.loop == "all_tasks", "parallel copies, all-body updates"
    assert paper.steps_per_iteration(num_bodies=5) == 5 * 100, "steps count every body"


def test_the_intended_preset_is_the_paper_preset_with_every_quirk_fixed():
    paper, intended, fast = PRESETS["paper"], PRESETS["intended"], PRESETS["fast"]

    def quirks(config: TrainConfig) -> dict[str, bool]:
        return {
            "torso_relative_x": config.envs.torso_relative_x,
            "stale_kinematics": config.envs.stale_kinematics,
            "reference_inorder": config.network.reference_inorder,
        }

    original = {"torso_relative_x": False, "stale_kinematics": True, "reference_inorder": True}
    assert quirks(paper) == original
    assert quirks(intended) == quirks(fast) == {name: not value for name, value in original.items()}
    loop = dataclasses.replace(
        paper.iteration, loop="rounds_chunked", reset_next_state=False, capacity_all=None
    )
    assert intended.iteration == loop, "swat_jax's training loop where the original's has quirks"
    assert (
        dataclasses.replace(
            intended, preset="paper", envs=paper.envs, network=paper.network, iteration=paper.iteration
        )
        == paper
    )
    assert fixed(paper) == dataclasses.replace(intended, preset="paper")


@pytest.mark.parametrize(("preset", "initialisation"), [("paper", "original"), ("fast", "flax")])
def test_a_runs_networks_start_from_its_presets_initial_weights(
    preset, initialisation, hopper_folder, tmp_path
):
    """The paper preset draws the original code's initial weights (its two layers start equal), fast Flax's."""
    sizes = {"width": 16, "layers": 2, "feedforward": 32}
    network = dataclasses.replace(PRESETS[preset].network, **sizes)
    config = dataclasses.replace(
        PRESETS[preset], env=str(hopper_folder), network=network, run_dir=str(tmp_path)
    )
    assert config.network.initialisation == initialisation
    actor = Experiment.build(config).learner.actor
    layers = actor.init(jax.random.key(0))["params"]["policy"]
    first, second = (jax.tree.leaves(layers[name]) for name in ("layer_0", "layer_1"))
    equal = [np.array_equal(one, other) for one, other in zip(first, second, strict=True)]
    kernel = [layers[name]["feedforward_hidden"]["kernel"] for name in ("layer_0", "layer_1")]
    assert all(equal) if initialisation == "original" else not np.array_equal(*kernel)


def test_cli_help_documents_every_option_and_presets_set_defaults(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    options = [f.name for f in dataclasses.fields(TrainCommand)] + ["iteration.random_steps", "td3.tau"]
    for name in options:
        assert "--" + name.replace("_", "-") in text, name
    with pytest.raises(SystemExit):
        main(["--preset", "fast", "--help"])
    assert "(default: 4)" in capsys.readouterr().out, "--help shows the fast preset's copies"


def test_a_config_file_gives_the_defaults_that_flags_override(tmp_path, capsys):
    """train --config FILE: a grid writes TrainConfig JSON instead of flag strings; flags still override it."""
    written = dataclasses.replace(
        PRESETS["fast"], env="walker", steps=5000, network=NetworkSizes(width=24), run_dir=str(tmp_path / "r")
    )
    path = tmp_path / "grid.json"
    path.write_text(written.to_json())
    command, _ = parse_command(["--config", str(path), "--steps", "7000", "--envs.copies", "2"])
    expected = dataclasses.replace(written, steps=7000, envs=dataclasses.replace(written.envs, copies=2))
    assert command.train_config() == expected
    assert main(["--config", str(path), "--preset", "paper"]) == 2
    assert "give one of them" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="drop --config"):
        resolve(*parse_command(["--config", str(path), "--resume", str(tmp_path / "r")]))


def test_cli_reports_an_existing_run_directory(trained_run, capsys):
    assert main(["--env", "hopper", "--run-dir", str(trained_run)]) == 2
    assert "exists; continue it with --resume" in capsys.readouterr().err


def test_cli_names_a_bad_program_cache_limit_and_its_fix(tmp_path, hopper_folder, monkeypatch, capsys):
    monkeypatch.setenv("SWAT_JAX_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("SWAT_JAX_COMPILATION_CACHE", raising=False)
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("SWAT_JAX_PROGRAM_CACHE_GIB", "lots")
    config = tiny_train_config(tmp_path / "run", hopper_folder)
    assert main([*train_flags(config), "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("error: SWAT_JAX_PROGRAM_CACHE_GIB='lots' is not a size in GiB"), error
    assert "unset it for the default 2 GiB" in error
    assert not (tmp_path / "run").exists(), (
        "the run directory was written: the same command now says it exists"
    )


def test_make_train_passes_options_through():
    command = subprocess.run(
        ["make", "-n", "train", "ENV=walker", "ALGO=smp", "SEED=3", "SEEDS=5", "STEPS=1000", "PRESET=fast"],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[1],
    ).stdout
    for flag in ("--env walker", "--algo smp", "--seed 3", "--seeds 5", "--steps 1000", "--preset fast"):
        assert flag in command


def test_replay_too_large_stops_before_anything_is_written(hopper_folder, tmp_path):
    """Too large per body, or (the original's cap on all bodies, the paper preset's) in all: the flag to lower."""
    huge = IterationConfig(
        chunk=50, updates=20, random_steps=100, capacity=10**12, capacity_all=None, loop="per_body"
    )
    for iteration, flag in (
        (huge, "capacity"),
        (dataclasses.replace(huge, capacity_all=10**11), "capacity-all"),
    ):
        config = tiny_train_config(tmp_path / "huge", hopper_folder, iteration=iteration, steps=10**12)
        with pytest.raises(MemoryError, match=rf"lower --iteration\.{flag} to at most"):
            train(config, progress=False)
        assert not (tmp_path / "huge").exists()


def test_a_folder_environment_is_stored_absolute(hopper_folder, monkeypatch):
    monkeypatch.chdir(hopper_folder.parent)
    config = TrainConfig(env=hopper_folder.name)
    assert config.env == str(hopper_folder.resolve())
    assert config.training_bodies() == (str(hopper_folder.resolve() / "hopper_3.xml"),)
    assert TrainConfig(env="Hopper++").env == "Hopper++", "set names stay names"


def test_init_from_starts_every_seed_from_the_chosen_seed_of_another_run(
    trained_run, hopper_folder, tmp_path
):
    """Transfer (paper section 5.3): networks and targets from the source run, fresh optimizers and buffers."""
    config = tiny_train_config(
        tmp_path / "transfer",
        hopper_folder,
        bodies=("hopper_4",),
        init_from=str(trained_run),
        init_seed_index=1,
    )
    experiment = Experiment.build(config)
    assert experiment.env.body_names == ("hopper_4",)
    state = experiment.init_state()
    source = final_state(trained_run)[0].learner
    for name in ("actor_params", "critic_params", "target_actor_params", "target_critic_params"):
        ours, theirs = getattr(state.learner, name), getattr(source, name)
        for a, b in zip(jax.tree_util.tree_leaves(ours), jax.tree_util.tree_leaves(theirs), strict=True):
            for seed in range(config.seeds):
                np.testing.assert_array_equal(a[seed], b[1], err_msg=name)
    assert not np.any(state.buffer.size) and int(state.learner.critic_steps) == 0
    adam = state.learner.actor_optimizer[1][0]
    assert not any(np.any(leaf) for leaf in jax.tree_util.tree_leaves(adam.mu)), "a fresh optimizer"


def test_init_from_refuses_networks_that_do_not_fit_naming_both_runs(trained_run, hopper_folder, tmp_path):
    def config(**overrides):
        return tiny_train_config(
            tmp_path / "transfer", hopper_folder, init_from=str(trained_run), **overrides
        )

    with pytest.raises(
        ConfigError, match=rf"--init-from {trained_run} .*cannot start .*width 16 there, 32 here"
    ):
        Experiment.build(config(network={"width": 32}))
    with pytest.raises(ConfigError, match="observation_normalisation False there, True here"):
        Experiment.build(config(network={"observation_normalisation": True}))
    drawn = load_config(trained_run / "config.json").network.initialisation
    other = next(name for name in INITIALISATIONS if name != drawn)
    Experiment.build(config(network={"initialisation": other}))  # how fresh weights are drawn does not matter
    with pytest.raises(ConfigError, match="19 observation features per limb there, 21 here"):
        Experiment.build(config(bodies=("nervenet_hopper",)))
    with pytest.raises(ConfigError, match=r"--init-seed-index 2, but it has 2 seeds \(0, 1\)"):
        Experiment.build(config(init_seed_index=2))
    with pytest.raises(ConfigError, match="no such run directory"):
        Experiment.build(
            tiny_train_config(tmp_path / "t", hopper_folder, init_from=str(tmp_path / "nowhere"))
        )
    with pytest.raises(ConfigError, match="--split test: hopper has no test bodies"):
        TrainConfig(env="hopper", split="test")


@pytest.mark.parametrize(
    ("steps", "log_interval", "every"),
    [(20_000, 0, 1_000), (10_000_000, 0, 10_000), (30, 0, 1), (20_000, 300, 300)],
    ids=["short-run-20-rows", "long-run-capped", "tiny-run", "given"],
)
def test_the_default_log_interval_gives_a_short_run_twenty_metric_rows(steps, log_interval, every):
    config = TrainConfig(steps=steps, log_interval=log_interval)
    assert config.metrics_interval() == every
    with pytest.raises(ConfigError, match=r"--log-interval must be 0"):
        dataclasses.replace(config, log_interval=-1)
