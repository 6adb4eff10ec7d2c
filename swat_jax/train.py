"""Train one policy on every body of an environment set: ``python -m swat_jax.train --env hopper``.

The host loop only calls the jitted iteration (collect a chunk in every copy of every body, then the
chunk's TD3 updates, see :mod:`swat_jax.td3.iteration`), one at a time, writes metrics every
``log_interval`` steps (by default a twentieth of the budget, at most 10,000) and checkpoints every ``checkpoint_interval`` steps. Ctrl-C or SIGTERM finishes
the running iteration, writes a checkpoint and exits (a second one aborts at once); ``--resume RUN_DIR``
continues from the newest checkpoint, and on the same machine the continued run equals an
uninterrupted one exactly.

Run directory::

    RUN_DIR/config.json        the resolved TrainConfig (flags + preset)
    RUN_DIR/metrics.csv        one row per log interval: returns and lengths per body, losses, steps/s
    RUN_DIR/tensorboard/       the same scalars for TensorBoard
    RUN_DIR/checkpoints/<N>/   Orbax checkpoints named by environment steps (all bodies)
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
import tyro
from tqdm import tqdm

from swat_jax.cli import ERROR_STATUS
from swat_jax.compilation_cache import CacheSettingError, enable_caches, program_cache_limit
from swat_jax.networks import param_count
from swat_jax.runs import formats
from swat_jax.runs.checkpoint import CheckpointError, CheckpointInfo, Checkpoints
from swat_jax.runs.config import CONFIG_FILE, PRESETS, ConfigError, TrainConfig, flag_values, load_config
from swat_jax.runs.experiment import Experiment
from swat_jax.runs.metrics import MetricsWindow, MetricsWriter, evaluation_columns
from swat_jax.runs.trained import network_items
from swat_jax.td3.evaluation import Episodes
from swat_jax.td3.iteration import TrainState
from swat_jax.td3.replay import check_buffer_fits, free_memory_bytes
from swat_jax.td3.sharding import all_processes_reach, fetch

INTERRUPTED_STATUS = 128 + signal.SIGINT
"""Exit status after a Ctrl-C that left nothing to checkpoint (the shell's convention: 130)."""
RESUMABLE_FLAGS = ("--steps", "--counted-steps", "--run-dir")
"""Flags ``--resume`` may change; every other value is the run's own."""


@dataclasses.dataclass(frozen=True)
class TrainCommand(TrainConfig):
    """Train one policy on every body of an environment set with TD3 (SWAT, Hong et al. 2022).

    Flags override the preset's values (--preset paper|intended|fast), or those of a config file (--config
    FILE: a run's config.json, or one a grid wrote); --help after either shows those defaults. Metrics,
    config and checkpoints go to the run directory.
    """

    config: str = ""
    """Take every value this config.json file gives (a run's, or one written with TrainConfig.to_json) as the defaults that flags override, instead of a preset's."""
    resume: str = ""
    """Continue the run in this directory from its newest checkpoint (with its saved config; --steps may raise the budget)."""
    overwrite: bool = False
    """Delete an existing run directory of the same name and start over."""
    progress: bool = True
    """Show a progress bar (steps, steps/s, mean return)."""
    devices: int = 0
    """Train on the first N devices (0: every device): seeds, then bodies, are split over a device mesh."""
    distributed: bool = False
    """Several hosts: call jax.distributed.initialize() first (Slurm, Open MPI and TPU pods are detected; elsewhere give the three flags below)."""
    coordinator_address: str = ""
    """Several hosts: HOST:PORT of process 0's coordinator (implies --distributed)."""
    num_processes: int = 0
    """Several hosts: how many processes take part (one per host), with --coordinator-address."""
    process_id: int = 0
    """Several hosts: this process's index, 0 .. num_processes - 1, with --coordinator-address."""

    def start_distributed(self) -> None:
        """Join the other hosts' processes (``jax.distributed.initialize``) when asked to; before any JAX work.

        Raises:
            ConfigError: --num-processes or --process-id without --coordinator-address (the process would
                train alone), or a --process-id outside 0 .. --num-processes - 1.
        """
        if (self.num_processes or self.process_id) and not self.coordinator_address:
            raise ConfigError(
                "--num-processes and --process-id go with --coordinator-address HOST:PORT (process 0's); "
                "under Slurm or Open MPI give --distributed alone"
            )
        if self.coordinator_address:
            if not 0 <= self.process_id < self.num_processes:
                raise ConfigError(
                    f"--coordinator-address needs --num-processes N (how many processes take part) and "
                    f"--process-id 0 to N - 1; got --num-processes {self.num_processes} "
                    f"--process-id {self.process_id}"
                )
            jax.distributed.initialize(self.coordinator_address, self.num_processes, self.process_id)
        elif self.distributed:
            jax.distributed.initialize()

    def train_config(self) -> TrainConfig:
        """The run's TrainConfig: this command's values less the command's own options."""
        return TrainConfig(
            **{field.name: getattr(self, field.name) for field in dataclasses.fields(TrainConfig)}
        )


class RunExistsError(ConfigError):
    """A run directory would be overwritten."""


class StopRequest:
    """SIGINT / SIGTERM while training, as a context manager that installs the handlers and restores the
    previous ones: the loop checkpoints after the running iteration and returns once :attr:`requested` is
    set. A second signal aborts at once, without a checkpoint: the process exits with 128 + the signal's
    number (130 for Ctrl-C) without waiting for the computation in flight.

    Python runs a handler in the main thread between bytecodes, once for every signal that arrived while
    it was pending: two Ctrl-C while the main thread waits inside XLA or Orbax would be one. So the
    handler only sets :attr:`requested` (at once where the main thread itself raised the signal), and the
    signals are counted by a thread that reads the byte each one writes to Python's wakeup file
    descriptor (``signal.set_wakeup_fd``).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.requested = False
        self._reader, self._writer = socket.socketpair()
        self._writer.setblocking(False)
        self._counter = threading.Thread(target=self._count, name="swat_jax_stop_request", daemon=True)
        self._previous: dict[int, Any] = {}
        self._previous_fd = -1

    def __enter__(self) -> StopRequest:
        self._previous = {sig: signal.signal(sig, self._request) for sig in self.SIGNALS}
        self._previous_fd = signal.set_wakeup_fd(self._writer.fileno(), warn_on_full_buffer=False)
        self._counter.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        signal.set_wakeup_fd(self._previous_fd)
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._writer.close()
        self._counter.join()
        self._reader.close()

    def _request(self, signum: int, frame: Any) -> None:
        """The Python-level handler: the stop is requested (the counting thread tells the user)."""
        self.requested = True

    def _count(self) -> None:
        """Each signal's byte, until the writing end closes: the first asks for the stop, the next aborts."""
        seen = 0
        while received := self._reader.recv(64):
            for signum in received:
                if signum not in self.SIGNALS:
                    continue
                name = signal.Signals(signum).name
                seen += 1
                if seen > 1:
                    print(f"\n{name} again: aborted without a checkpoint", file=sys.stderr, flush=True)
                    sys.stdout.flush()
                    os._exit(128 + signum)
                self.requested = True
                print(
                    f"\n{name}: stopping after this iteration and writing a checkpoint "
                    "(Ctrl-C again aborts without one)",
                    file=sys.stderr,
                    flush=True,
                )


@dataclasses.dataclass
class RunResult:
    """How a call to :func:`train` ended."""

    run_dir: Path
    env_steps: int
    interrupted: bool


def _chosen_devices(count: int) -> list[jax.Device]:
    """The first ``count`` devices (every device for 0); ConfigError if there are fewer."""
    devices = jax.devices()
    if count < 0 or count > len(devices):
        raise ConfigError(
            f"--devices {count}: this machine has {len(devices)} {devices[0].platform} device"
            f"{'s' * (len(devices) > 1)}; give 1 to {len(devices)}, or 0 for all"
        )
    return devices[: count or len(devices)]


def prepare_run_dir(config: TrainConfig, *, resume: bool, overwrite: bool) -> Path:
    """Create (or reuse, when resuming) the run directory and write ``config.json``."""
    run_dir = config.directory()
    existing = run_dir.exists() and any(run_dir.iterdir())
    if resume:
        if not (run_dir / CONFIG_FILE).exists():
            raise ConfigError(f"{run_dir}: no {CONFIG_FILE}; not a run directory to resume")
    elif existing and not overwrite:
        raise RunExistsError(
            f"run directory {run_dir} exists; continue it with --resume {run_dir}, start over with "
            "--overwrite, or pick another --run-dir"
        )
    # Several hosts share the directory: every process checks it before process 0 alone changes it, and
    # none goes on before it has.
    all_processes_reach("swat_jax run directory checked")
    if jax.process_index() == 0:
        if existing and not resume:
            shutil.rmtree(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / CONFIG_FILE).write_text(config.to_json())
    all_processes_reach("swat_jax run directory written")
    return run_dir


def train(
    config: TrainConfig,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    devices: int = 0,
    after_iteration: Callable[[int], None] | None = None,
) -> RunResult:
    """Run (or continue) training until ``config.steps``, ``config.counted_steps`` (when set) or a stop signal;
    returns where it ended.

    Args:
        config: the run's configuration (for ``resume``, the saved one with any new budget).
        resume: continue from the newest checkpoint in ``config.directory()``.
        overwrite: replace an existing run directory (otherwise RunExistsError).
        progress: show a progress bar.
        devices: train on the first ``devices`` devices (0: all of them).
        after_iteration: called with the iteration count after each iteration (tests use it to interrupt).

    Raises:
        ConfigError, CheckpointError, CacheSettingError, MemoryError: with a message that says what to change.
    """
    program_cache_limit()
    experiment = Experiment.build(config, _chosen_devices(devices))
    _print_start(experiment)
    run_dir = prepare_run_dir(config, resume=resume, overwrite=overwrite)
    checkpoints = Checkpoints(run_dir, config.keep_checkpoints)
    try:
        state, info = _start_state(experiment, checkpoints, resume)
        # Several hosts: every process trains and checkpoints its shards; process 0 writes the metrics.
        primary = jax.process_index() == 0
        metrics = MetricsWriter(run_dir, resumed_at=info.env_steps if resume else None) if primary else None
        try:
            result = _loop(
                experiment, state, info, checkpoints, metrics, progress and primary, after_iteration
            )
            if experiment.env.shards is not None:
                print(_physics_calls_line(experiment.env.physics_calls()))
            return result
        finally:
            if metrics is not None:
                metrics.close()
    finally:
        checkpoints.close()


def _print_start(experiment: Experiment) -> None:
    """Print what the run trains (its network, bodies, copies and seeds), its limb buckets, its device mesh
    and its replay buffers' memory (MemoryError, before anything is written, if they cannot fit)."""
    config, env = experiment.config, experiment.env
    # Shapes only: initialising the actor eagerly compiles each of its operations.
    actor_parameters = param_count(jax.eval_shape(experiment.learner.actor.init, jax.random.PRNGKey(0)))
    print(
        f"run {config.directory()}: {config.algo} ({actor_parameters:,} "
        f"actor parameters) on {env.num_bodies} bodies of {config.env} x {config.envs.copies} copies, "
        f"{env.max_limbs} limbs max, seeds {', '.join(map(str, config.seed_values()))} in one program"
    )
    # The original schedule updates one body at a time, at the padded limb count.
    if experiment.learner.buckets and config.iteration.schedule == "all_tasks":
        sizes = ", ".join(f"{len(bucket.tasks)} x {bucket.limbs}" for bucket in experiment.learner.buckets)
        print(f"updates in {len(experiment.learner.buckets)} limb buckets (bodies x limbs): {sizes}")
    print(experiment.placement.describe())
    print(env.describe_physics())
    flag, flag_rows = _replay_rows_flag(config, env.num_bodies)
    print(
        check_buffer_fits(
            env.num_bodies,
            experiment.replay_rows,
            env.max_limbs,
            env.observation_features,
            free_memory_bytes(),
            seeds=config.seeds,
            flag=flag,
            flag_rows=flag_rows,
            why=_replay_rows_why(config, experiment.replay_rows, env.num_bodies),
            motors=env.motors_per_limb,
            episode_ends=config.td3.episode_ends,
        )
    )


def _physics_calls_line(calls: dict[int, int]) -> str:
    """One line: the MuJoCo C calls this process made in training, by device (:meth:`MultiTaskEnv.physics_calls`)."""
    counts = ", ".join(f"{count} on device {device}" for device, count in sorted(calls.items()))
    return f"physics calls of process {jax.process_index()} in training: {counts or 'none'}"


def _start_state(
    experiment: Experiment, checkpoints: Checkpoints, resume: bool
) -> tuple[TrainState, CheckpointInfo]:
    """The state the run starts from and its info: with ``resume``, the newest checkpoint's (damaged ones
    set aside first), else, or where there is none yet, a fresh one."""
    for line in checkpoints.set_aside_damaged() if resume else ():
        print(line)
    if resume and checkpoints.latest_step() is not None:
        state, info = experiment.restore_state(checkpoints)
        print(f"resumed from {checkpoints.directory / str(info.env_steps)}")
        return state, info
    if resume:
        print(f"no checkpoint in {checkpoints.directory} yet: starting the run from its saved config")
    return experiment.init_state(), experiment.checkpoint_info(0, 0, 0.0)


def _replay_rows_flag(config: TrainConfig, num_bodies: int) -> tuple[str, int]:
    """The flag that sets the replay rings' capacity on ``num_bodies`` bodies, and the rows of all of them
    that one of its units sets per row of each (:func:`~swat_jax.td3.replay.check_buffer_fits`)."""
    if config.iteration.rows_per_task(num_bodies) < config.iteration.capacity:
        return "--iteration.capacity-all", num_bodies
    return "--iteration.capacity", 1


def _replay_rows_why(config: TrainConfig, rows: int, num_bodies: int) -> str:
    """Why each replay ring has ``rows`` rows, for the start-up line."""
    capacity = config.iteration.rows_per_task(num_bodies)
    limit = (
        f"--iteration.capacity {capacity:,}"
        if _replay_rows_flag(config, num_bodies)[0] == "--iteration.capacity"
        else f"--iteration.capacity-all {config.iteration.capacity_all:,} over {num_bodies} bodies, {capacity:,} each"
    )
    if rows < capacity:
        return f": what {config.steps:,} steps store, rounded up to a power of two, below {limit}"
    return f": {limit}"


def _loop(
    experiment: Experiment,
    state: TrainState,
    info: CheckpointInfo,
    checkpoints: Checkpoints,
    metrics: MetricsWriter | None,
    progress: bool,
    after_iteration: Callable[[int], None] | None,
) -> RunResult:
    """Iterate from where ``info`` says the run is until it is finished or a stop is requested: a metrics row
    per seed every log interval (with the evaluation's columns), a checkpoint every checkpoint interval
    and one at the end. A finished run (resumed) ends at once, with nothing compiled."""
    config, env = experiment.config, experiment.env
    per_iteration = config.steps_per_iteration(env.num_bodies)
    total = config.iterations(env.num_bodies)
    log_every = max(1, round(config.metrics_interval() / per_iteration))
    checkpoint_every = max(1, round(config.checkpoint_interval / per_iteration))
    done, seconds, counted = info.iterations, info.seconds, fetch(state.counted)
    if _finished(config, done, total, counted):
        return _ended(config, checkpoints, done, total, per_iteration, counted)
    window = MetricsWindow(config.seeds, env.num_bodies, info.metrics_window, config.iteration.diagnostics)
    iteration, evaluation = _compiled_programs(experiment, state)
    saved = done
    with (
        StopRequest() as stop,
        tqdm(
            total=total * per_iteration,
            initial=done * per_iteration,
            unit="step",
            disable=not progress,
            smoothing=0.1,
        ) as bar,
    ):
        timed, window_start = 0, time.perf_counter()
        while not _finished(config, done, total, counted) and not stop.requested:
            state, step_metrics = iteration(state)
            # One iteration in flight: the bar counts finished work, and a stop waits for one iteration.
            fetched = fetch(step_metrics)
            window.add(fetched)
            counted = fetched["counted_steps"]
            done, timed = done + 1, timed + 1
            bar.update(per_iteration)
            if done % log_every == 0 or _finished(config, done, total, counted):
                now = time.perf_counter()
                seconds += now - window_start
                rate = timed * per_iteration / (now - window_start)
                rows = _write_metrics(experiment, window, evaluation, state, metrics, done, rate)
                bar.set_postfix(_progress_summary(rows))
                window.clear()
                timed, window_start = 0, now
            if done % checkpoint_every == 0:
                saved = _save(experiment, checkpoints, state, done, seconds, window)
            if after_iteration is not None:
                after_iteration(done)
        if saved != done:
            _save(experiment, checkpoints, state, done, seconds, window)
    return _ended(config, checkpoints, done, total, per_iteration, counted)


def _ended(
    config: TrainConfig,
    checkpoints: Checkpoints,
    done: int,
    total: int,
    per_iteration: int,
    counted: np.ndarray,
) -> RunResult:
    """The run's result after ``done`` iterations of ``per_iteration`` steps, saying so when the --steps cap
    came before the counted budget."""
    steps = done * per_iteration
    if done == total and not _counted_enough(config, counted):
        print(_short_of_counted(config, counted, steps))
    return RunResult(
        checkpoints.directory.parent, steps, interrupted=not _finished(config, done, total, counted)
    )


def _compiled_programs(
    experiment: Experiment, state: TrainState
) -> tuple[
    Callable[[TrainState], tuple[TrainState, dict[str, Any]]], Callable[[Any, jax.Array], Episodes] | None
]:
    """The training iteration compiled for ``state`` (saying how long that took), and with evaluations
    during training (``--eval-interval``) the evaluation, compiled at its first call."""
    start = time.perf_counter()
    print("compiling the training iteration (minutes on CPU the first time; cached afterwards)...")
    iteration = experiment.compiled_iteration(state)
    print(f"compiled in {time.perf_counter() - start:.1f} s")
    return iteration, experiment.compiled_evaluation() if experiment.config.eval_interval else None


def _write_metrics(
    experiment: Experiment,
    window: MetricsWindow,
    evaluation: Callable[[Any, jax.Array], Episodes] | None,
    state: TrainState,
    metrics: MetricsWriter | None,
    done: int,
    rate: float,
) -> list[dict[str, float]]:
    """The metrics rows of the log interval that ends after ``done`` iterations, one per seed, with the
    ``eval/*`` columns of an evaluation where one is due (with evaluations during training); written where
    ``metrics`` is (process 0) and returned. ``rate`` is one seed's environment steps/s."""
    config, env = experiment.config, experiment.env
    per_iteration = config.steps_per_iteration(env.num_bodies)
    rows = _log_rows(window, config, env.body_names, done, rate)
    if evaluation is not None:
        due = done == config.iterations(env.num_bodies) or _crossed(
            config.eval_interval, done, window.iterations, per_iteration
        )
        rows = _with_evaluation(rows, evaluation if due else None, state, env.body_names)
    for row in rows if metrics is not None else ():
        metrics.write(row)
    return rows


def _save(
    experiment: Experiment,
    checkpoints: Checkpoints,
    state: TrainState,
    done: int,
    seconds: float,
    window: MetricsWindow,
) -> int:
    """Checkpoint ``state`` after ``done`` iterations and ``seconds`` of training, with the metrics window
    it is in; returns ``done``, the iterations saved."""
    per_iteration = experiment.config.steps_per_iteration(experiment.env.num_bodies)
    info = experiment.checkpoint_info(done * per_iteration, done, seconds, metrics_window=window.to_json())
    checkpoints.save(state, network_items(state.learner), info)
    return done


def _counted_enough(config: TrainConfig, counted: np.ndarray) -> bool:
    """Every seed has counted ``config.counted_steps`` steps (True without a counted budget)."""
    return int(np.min(counted)) >= config.counted_steps


def _finished(config: TrainConfig, done: int, total: int, counted: np.ndarray) -> bool:
    """The run is over: ``total`` iterations (the --steps cap) done, or with a counted budget every seed
    has counted it."""
    return done >= total or (config.counted_steps > 0 and _counted_enough(config, counted))


def _short_of_counted(config: TrainConfig, counted: np.ndarray, steps: int) -> str:
    """The line that says a run reached its --steps cap before its counted budget, and how to go on."""
    seeds = ", ".join(
        f"seed {seed} {int(n):,}" for seed, n in zip(config.seed_values(), counted, strict=True)
    )
    return (
        f"stopped at the --steps cap ({steps:,} steps taken) before --counted-steps {config.counted_steps:,}: "
        f"counted {seeds}; continue with --resume {config.directory()} --steps N (a larger cap)"
    )


def _log_rows(
    window: MetricsWindow, config: TrainConfig, body_names: tuple[str, ...], iterations: int, rate: float
) -> list[dict[str, float]]:
    """The metrics rows of one log interval, one per seed; ``rate`` is one seed's environment steps/s."""
    steps = iterations * config.steps_per_iteration(len(body_names))
    return [
        {"env_steps": steps, "iterations": iterations, "steps_per_second": rate, **row}
        for row in window.rows(config.seed_values(), body_names)
    ]


def _crossed(interval: int, done: int, since: int, per_iteration: int) -> bool:
    """Whether a multiple of ``interval`` steps was passed in the last ``since`` of ``done`` iterations."""
    return (done * per_iteration) // interval > ((done - since) * per_iteration) // interval


def _with_evaluation(
    rows: list[dict[str, float]],
    evaluation: Callable[[Any, jax.Array], Episodes] | None,
    state: TrainState,
    body_names: tuple[str, ...],
) -> list[dict[str, float]]:
    """``rows`` with the ``eval/*`` columns of the current actors (NaN when ``evaluation`` is None).

    Every evaluation starts from the same initial states (key 0, as ``swat_jax.eval``'s default), so the
    curve's changes are the policy's, not the draws'.
    """
    if evaluation is None:
        nan = np.full((len(rows), len(body_names), 1), np.nan)
        columns = evaluation_columns(nan, nan, body_names)
    else:
        episodes = fetch(evaluation(state.learner.actor_params, jax.random.PRNGKey(0)))
        columns = evaluation_columns(episodes.returns, episodes.lengths, body_names)
    return [row | extra for row, extra in zip(rows, columns, strict=True)]


def _progress_summary(rows: list[dict[str, float]]) -> dict[str, str]:
    """The progress bar's postfix: mean return and critic loss, means over seeds."""
    returns = [row["mean_return"] for row in rows if math.isfinite(row["mean_return"])]
    return {
        "mean_return": f"{np.mean(returns):.1f}" if returns else "nan",
        "critic_loss": f"{np.mean([row['critic_loss'] for row in rows]):.3g}",
    }


def _option(argv: list[str], flag: str) -> str | None:
    """The value ``argv`` gives ``flag`` (``FLAG VALUE`` or ``FLAG=VALUE``; the last one), or None."""
    value = None
    for index, arg in enumerate(argv):
        if arg == flag and index + 1 < len(argv):
            value = argv[index + 1]
        elif arg.startswith(f"{flag}="):
            value = arg.split("=", 1)[1]
    return value


def _defaults(argv: list[str]) -> TrainCommand:
    """The defaults the command line's flags override: those of ``--config FILE``, or of the preset it names
    (``--preset NAME``; paper without one). ConfigError for both, or for a file that is not a config."""
    config_file, preset = _option(argv, "--config"), _option(argv, "--preset")
    if config_file is not None and preset is not None:
        raise ConfigError(
            f"--config {config_file} and --preset {preset} both give the defaults; give one of them"
        )
    base = (
        load_config(config_file)
        if config_file is not None
        else PRESETS.get(preset or "paper", PRESETS["paper"])
    )
    return TrainCommand(
        **{field.name: getattr(base, field.name) for field in dataclasses.fields(TrainConfig)},
        config=config_file or "",
    )


def resolve(command: TrainCommand, defaults: TrainCommand) -> TrainConfig:
    """The config to run: the command's, or for ``--resume`` the saved one with a new budget.

    Raises:
        ConfigError: ``--resume`` together with options that contradict the saved config.
    """
    if not command.resume:
        return command.train_config()
    if command.config:
        raise ConfigError(
            f"--resume {command.resume} continues with the run's own config.json; drop --config"
        )
    run_dir = Path(command.resume)
    saved = load_config(run_dir / CONFIG_FILE)
    given, preset, own = (
        flag_values(config) for config in (command.train_config(), defaults.train_config(), saved)
    )
    contradicting = [
        f"{flag} {value!r} (run has {own[flag]!r})"
        for flag, value in given.items()
        if flag not in RESUMABLE_FLAGS and value != preset[flag] and value != own[flag]
    ]
    if contradicting:
        raise ConfigError(
            f"--resume {run_dir} continues the run with its saved {CONFIG_FILE}; these options differ from it: "
            + ", ".join(contradicting)
            + ". Drop them, or start a new run in another --run-dir"
        )
    steps = command.steps if command.steps != defaults.steps else saved.steps
    return dataclasses.replace(saved, steps=steps, run_dir=str(run_dir))


def _interrupted_before_training(command: TrainCommand) -> str:
    """What a Ctrl-C before the first iteration (loading, tracing, compiling) leaves, and how to go on."""
    run_dir = Path(command.resume) if command.resume else command.train_config().directory()
    if (run_dir / CONFIG_FILE).exists():
        return (
            f"interrupted before training started; {run_dir} keeps its config. Start it with: "
            f"python -m swat_jax.train --resume {run_dir}"
        )
    return "interrupted before training started; nothing was written"


def parse_command(argv: list[str]) -> tuple[TrainCommand, TrainCommand]:
    """The command ``python -m swat_jax.train ARGV`` asks for, and its defaults (a preset's or a file's)."""
    defaults = _defaults(argv)
    try:
        argv, note = formats.with_loop_flag(argv, defaults.iteration.loop)
    except formats.FormatError as error:
        raise ConfigError(str(error)) from error
    if note:
        print(f"note: {note}", file=sys.stderr)
    return tyro.cli(TrainCommand, args=argv, default=defaults, prog="python -m swat_jax.train"), defaults


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and train; returns the exit status (2 for a bad option or run directory)."""
    enable_caches()
    try:
        command, defaults = parse_command(sys.argv[1:] if argv is None else argv)
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return ERROR_STATUS
    try:
        command.start_distributed()
        config = resolve(command, defaults)
        result = train(
            config,
            resume=bool(command.resume),
            overwrite=command.overwrite,
            progress=command.progress,
            devices=command.devices,
        )
    except (ConfigError, CheckpointError, CacheSettingError, MemoryError) as error:
        print(f"error: {error}", file=sys.stderr)
        return ERROR_STATUS
    except KeyboardInterrupt:
        print(f"\n{_interrupted_before_training(command)}", file=sys.stderr)
        return INTERRUPTED_STATUS
    if result.interrupted:
        print(
            f"stopped at {result.env_steps:,} steps; continue with: python -m swat_jax.train --resume {result.run_dir}"
        )
    else:
        print(
            f"done: {result.env_steps:,} steps in {result.run_dir}; evaluate with: python -m swat_jax.eval {result.run_dir}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
