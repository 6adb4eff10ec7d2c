"""The two sides' runs at one scale, each seed its own process on one core: swat_jax's paper preset, and the
original trainer in its own virtual environment (``--original-tools``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, Protocol

from experiments.paper import (
    GridError,
    GridInterrupted,
    RunSpec,
    add_timing,
    progress,
    reached_budget,
)
from swat_jax.convert import SET_FOLDERS
from swat_jax.morphology import get_set
from swat_jax.runs.config import PAPER, PRESETS, TrainConfig

ORIGINAL = "original (PyTorch)"
OURS = "swat_jax (paper preset)"
ORIGINAL_SET_FLAGS: dict[str, tuple[str, ...]] = {
    **{name: ("--custom_xml", f"environments/{folder}") for folder, name in SET_FOLDERS.items()},
    "animal_walkers": ("--morphologies", "nervenet"),
}
"""How the original's main.py is told each set's train bodies: its folder of XMLs, or (Animal-Walkers,
which has no folder) the name its XML files share."""
CHUNK = 100
"""Steps per body of the paper preset's collection chunk (the original trains after each lock-step round)."""
STEPS_CAP = 6.0
"""swat_jax's ``--steps`` (the steps it may take) per step of the counted budget it stops at
(``--counted-steps``): a cap above any surplus seen, so that every seed stops at the counted budget, as the
original's ``--max_timesteps`` does. In lock-step rounds both implementations take more steps than they
count (the original's trainers 1.24-3.15x at the small scale, Animal-Walkers the most: its two cheetahs
never terminate and hold every round), and a swat_jax seed whose round ends inside a chunk of 100 steps
waits to the chunk's end (3.6-3.8x slots per counted step seen). The cap also sizes the replay rings, which
are never overfilled either way, so it changes no computation."""
ORIGINAL_WORK = Path(os.environ.get("ORIG_SWAT_DIR", "/tmp/swat-original"))
"""Where the original's tools copy its tree and where its main.py writes ``results/<expID>/``."""


@dataclasses.dataclass(frozen=True)
class Settings:
    """What both implementations train with: the same sizes, hyperparameters and budget."""

    name: str
    seeds: int
    steps: Mapping[str, int]
    """Environment steps per seed, summed over the set's bodies, by set."""
    width: int = 128
    heads: int = 2
    layers: int = 3
    feedforward: int = 256
    random_steps: int = 10_000
    """Steps per body with uniform random actions (the original's start_timesteps)."""
    learning_rate: float = 1e-4
    batch_size: int = 100
    capacity: int = 500_000
    """Replay rows per body (the original's rb_per_env)."""
    log_iterations: int = 5
    """Chunks of 100 steps per body between two points of the curves."""
    final_fraction: float = 0.2
    """The final return of a seed is its mean over the points in this last fraction of the budget."""

    def config(self, base: TrainConfig, environment_set: str, run_dir: Path, **fields: Any) -> TrainConfig:
        """``base`` (a preset) with these sizes and hyperparameters, SWAT, every seed in one program, in
        ``run_dir``, a checkpoint every 4 curve points; ``fields`` (the budget, the log interval, or one
        seed's ``seeds`` and ``seed``) on top."""
        fields = {"seeds": self.seeds, **fields}
        return dataclasses.replace(
            base,
            env=environment_set,
            algo="swat",
            run_dir=str(run_dir),
            network=dataclasses.replace(
                base.network,
                width=self.width,
                heads=self.heads,
                layers=self.layers,
                feedforward=self.feedforward,
            ),
            iteration=dataclasses.replace(
                base.iteration, random_steps=self.random_steps, capacity=self.capacity
            ),
            td3=dataclasses.replace(
                base.td3, learning_rate=self.learning_rate, batch_size=self.preset_batch(base)
            ),
            checkpoint_interval=self.log_interval(environment_set) * 4,
            **fields,
        )

    def given(self, seeds: int | None, steps: int | None, sets: Sequence[str]) -> Settings:
        """These settings with a command's ``--seeds`` and ``--steps`` (counted steps on every one of
        ``sets``), where given; GridError for fewer than one seed or step."""
        settings = self
        if seeds is not None:
            if seeds < 1:
                raise GridError(f"--seeds must be 1 or more, got {seeds}")
            settings = dataclasses.replace(settings, seeds=seeds)
        if steps is not None:
            if steps < 1:
                raise GridError(f"--steps must be 1 or more, got {steps}")
            settings = dataclasses.replace(settings, steps={name: steps for name in sets})
        return settings

    def preset_batch(self, base: TrainConfig) -> int:
        """The batch per body of ``base`` at this scale: the scale's (the original's) for a preset of the
        paper's batch, and in the same ratio for one of its own (the fast preset's 25 to the paper's 100)."""
        return max(1, round(self.batch_size * base.td3.batch_size / PAPER.td3.batch_size))

    def log_interval(self, environment_set: str) -> int:
        """Environment steps (all bodies) between two points of ``environment_set``'s curves."""
        return len(get_set(environment_set).train) * CHUNK * self.log_iterations

    def steps_cap(self, environment_set: str) -> int:
        """swat_jax's ``--steps`` on ``environment_set``: the counted budget times :data:`STEPS_CAP`, rounded
        up to whole collection chunks of every body (the run stops at the counted budget before it)."""
        chunk = len(get_set(environment_set).train) * CHUNK
        return math.ceil(self.budget(environment_set) * STEPS_CAP / chunk) * chunk

    def budget(self, environment_set: str) -> int:
        """The step budget on ``environment_set`` in the steps the original counts (the curves' x axis);
        GridError if it has none or it is off the curves' grid."""
        if environment_set not in self.steps:
            raise GridError(f"scale {self.name} has no budget for {environment_set}; give --steps")
        steps, interval = self.steps[environment_set], self.log_interval(environment_set)
        if steps % interval:
            raise GridError(
                f"--steps {steps} on {environment_set}: must be a multiple of {interval} (its "
                f"{len(get_set(environment_set).train)} bodies x {CHUNK} steps x {self.log_iterations} chunks "
                "between curve points)"
            )
        return steps


ScaleName = Literal["micro", "small", "paper"]
"""The keys of :data:`SETTINGS`."""
SETTINGS = {
    "micro": Settings(
        name="micro",
        seeds=2,
        steps={"hopper": 600, "walker": 800},
        width=8,
        layers=1,
        feedforward=16,
        random_steps=100,
        capacity=1_000,
        log_iterations=1,
    ),
    "small": Settings(
        name="small",
        seeds=4,
        steps={"hopper": 24_000, "walker": 30_000, "cheetah": 60_000, "animal_walkers": 37_500},
        width=32,
        layers=1,
        feedforward=64,
        random_steps=1_000,
        learning_rate=1e-3,
        capacity=50_000,
    ),
    "paper": Settings(
        name="paper",
        seeds=5,
        steps={name: 10_000_000 for name in ORIGINAL_SET_FLAGS},
        log_iterations=100,
    ),
}
"""``micro`` is a smoke test of the whole pipeline (a few minutes); ``small`` fits Hopper++ and Walker++, both implementations, into about 80 minutes of 2 CPU cores;
``paper`` is the paper's sizes and budget (days of the original on a CPU)."""


# The two sides' runs


def ours(out: Path, settings: Settings, environment_set: str) -> list[RunSpec]:
    """swat_jax's paper-preset run of each seed (:func:`paper_config`), as the original runs its seeds: one
    program (one process) per seed, in ``OUT/runs/<set>-swat_jax-seed<k>``."""
    return [
        RunSpec(
            paper_config(
                settings,
                environment_set,
                out / "runs" / f"{environment_set}-swat_jax-seed{seed}",
                seeds=1,
                seed=seed,
            )
        )
        for seed in range(settings.seeds)
    ]


def paper_config(settings: Settings, environment_set: str, run_dir: Path, **fields: Any) -> TrainConfig:
    """The paper preset at these settings: it stops at the counted budget (``--counted-steps``, the original's
    own measure, so after the round that reaches it, as the original does), with :meth:`Settings.steps_cap`
    as its ``--steps``, and logs a row (with the steps counted so far) after every chunk, for the curves to
    be binned by counted steps; ``fields`` on top."""
    chunk = len(get_set(environment_set).train) * CHUNK
    return settings.config(
        PRESETS["paper"], environment_set, run_dir, steps=settings.steps_cap(environment_set),
        counted_steps=settings.budget(environment_set), log_interval=chunk, **fields,
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class OriginalRun:
    """One seed of the original trainer on one set."""

    out: Path
    settings: Settings
    environment_set: str
    seed: int

    @property
    def name(self) -> str:
        return f"{self.environment_set}-seed{self.seed}"

    @property
    def folder(self) -> Path:
        """Where its stat.json, args.txt and log are kept in OUT."""
        return self.out / "original" / self.name

    @property
    def experiment_id(self) -> str:
        """The original's --expID: unique per OUT folder, so two comparisons never share a results folder."""
        digest = hashlib.sha1(str(self.out.resolve()).encode()).hexdigest()[:8]
        return f"swat_jax_against_{digest}_{self.name}"

    def flags(self) -> list[str]:
        """The original main.py's flags for these settings."""
        s = self.settings
        if self.environment_set not in ORIGINAL_SET_FLAGS:
            raise GridError(
                f"the original code has no folder for {self.environment_set}; sets it can train: "
                f"{', '.join(ORIGINAL_SET_FLAGS)}"
            )
        return [
            *ORIGINAL_SET_FLAGS[self.environment_set],
            "--actor_type", "swat", "--critic_type", "swat", "--seed", str(self.seed),
            "--expID", self.experiment_id, "--max_timesteps", str(s.budget(self.environment_set)),
            "--start_timesteps", str(s.random_steps), "--lr", str(s.learning_rate),
            "--batch_size", str(s.batch_size), "--rb_per_env", str(s.capacity),
            "--attention_embedding_size", str(s.width), "--attention_heads", str(s.heads),
            "--attention_layers", str(s.layers), "--attention_hidden_size", str(s.feedforward),
        ]  # fmt: skip

    def command(self, python: Path, tools: Path, timeout: float) -> list[str]:
        return [str(python), str(tools / "run_trainer.py"), str(timeout), *self.flags()]

    def finished(self) -> bool:
        """Whether the seed ran to its end; GridError if it ran another budget than these settings'."""
        if not (self.folder / "stat.json").is_file():
            return False
        arguments = self.folder / "args.txt"
        ran = int(float(json.loads(arguments.read_text())["max_timesteps"])) if arguments.is_file() else None
        if ran is not None and ran != self.settings.budget(self.environment_set):
            raise GridError(
                f"{self.folder} holds a run of the original to {ran:,} counted steps, not "
                f"{self.settings.budget(self.environment_set):,}: give --steps {ran}, or another folder"
            )
        return True

    def log(self) -> str:
        """The trainer's log, copied next to its ``stat.json``."""
        return (self.folder / "trainer.log").read_text()


def original_runs(out: Path, settings: Settings, environment_set: str) -> list[OriginalRun]:
    return [OriginalRun(out, settings, environment_set, seed) for seed in range(settings.seeds)]


@dataclasses.dataclass(frozen=True)
class Original:
    """Where the original trainer runs: its venv's python and the folder of its tools."""

    python: Path
    tools: Path
    parallel: int
    timeout: float

    def missing(self) -> str | None:
        """Why it cannot run here, or None."""
        if not self.python.is_file():
            return f"no original-code venv at {self.python} (give --original-python)"
        if self.tools == Path():
            return "no folder of the original's tools: give --original-tools DIR or set $ORIGINAL_TOOLS"
        if not (self.tools / "run_trainer.py").is_file():
            return f"no run_trainer.py in {self.tools} (give --original-tools)"
        return None


Start = Callable[[int], subprocess.Popen]
"""Starts one seed's process on a core slot (0 to ``parallel`` - 1) and returns it."""
Finish = Callable[[int, float], None]
"""Checks one seed's exit status and wall clock (s) and keeps its results."""


def side_by_side(seeds: Sequence[tuple[Start, Finish]], parallel: int) -> None:
    """Run every seed's process, ``parallel`` at a time, each on its own core slot. Ctrl-C, or a seed that
    fails its check, stops those still running (Ctrl-C raises GridInterrupted)."""
    pending, running, free = list(seeds), [], list(range(parallel))
    try:
        while pending or running:
            while pending and free:
                start, finish = pending.pop(0)
                slot = free.pop(0)
                running.append((start(slot), finish, slot, time.perf_counter()))
            time.sleep(1.0)
            for entry in list(running):
                process, finish, slot, began = entry
                if process.poll() is None:
                    continue
                running.remove(entry)
                free.append(slot)
                finish(process.returncode, time.perf_counter() - began)
    except KeyboardInterrupt:
        raise GridInterrupted(
            "stopped; the finished seeds are kept, run the same command again to go on"
        ) from None
    finally:
        for process, *_ in running:
            process.terminate()


class ForeignRun(Protocol):
    """One seed of another implementation's trainer (:class:`OriginalRun`, SGRL's ``SgrlRun``)."""

    @property
    def name(self) -> str: ...

    def finished(self) -> bool: ...


def train_foreign(
    who: str,
    runs: Sequence[ForeignRun],
    start: Callable[[Any, int], subprocess.Popen],
    finish: Callable[[Any, int, float], None],
    prepare: Callable[[], None],
    parallel: int,
    timing: tuple[Path, str],
) -> None:
    """Run every unfinished seed of another trainer (``who``: its name in the messages) from its start,
    ``parallel`` at a time: ``prepare()`` once before the first, ``start(run, slot)`` and ``finish(run,
    status, seconds)`` each (:func:`side_by_side`); the wall clock of them all added to ``timings.json`` in
    ``timing`` (the folder and the key)."""
    pending = []
    for run in runs:
        if run.finished():
            print(f"{who} {run.name}: done, kept", file=sys.stderr)
        else:
            pending.append(run)
    if not pending:
        return
    prepare()
    began = time.perf_counter()
    try:
        side_by_side(
            [(functools.partial(start, run), functools.partial(finish, run)) for run in pending], parallel
        )
    finally:
        add_timing(*timing, time.perf_counter() - began)


def train_original(runs: Sequence[OriginalRun], original: Original, out: Path) -> None:
    """Run every unfinished seed, ``original.parallel`` at a time, each with one torch thread; copy its
    stat.json, args.txt and log into OUT; add the wall clock to ``timings.json``."""
    train_foreign(
        "original",
        runs,
        lambda run, slot: _start_original(run, original, slot),
        _collect_original,
        lambda: prepare_tree(original),
        original.parallel,
        (out, f"original-{runs[0].environment_set}"),
    )


SINGLE_THREAD_XLA = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
"""XLA flags that keep a swat_jax seed's program on one thread, as the original's seeds run on one."""


def train_ours(runs: Sequence[RunSpec], parallel: int, out: Path) -> None:
    """Train every seed that has not reached its budget (resuming one that stopped part-way), ``parallel``
    at a time, each process single-threaded and pinned to one core; its output in ``OUT/runs/<name>.log``,
    its wall clock added to ``timings.json``."""
    pending = []
    for run in runs:
        steps = progress(run)
        if steps is not None and reached_budget(run, steps):
            print(f"{run.name}: done ({steps:,} steps), kept", file=sys.stderr)
        else:
            pending.append((functools.partial(_start_ours, run), functools.partial(_collect_ours, run, out)))
    side_by_side(pending, parallel)


def _start_ours(run: RunSpec, slot: int) -> subprocess.Popen:
    if progress(run) is None:
        run.write_config()
        command = [*run.command(), "--no-progress"]
    else:
        command = [*run.resume_command(), "--no-progress"]
    print(f"{run.name} on core {slot}: {shlex.join(command)}", file=sys.stderr)
    flags = f"{os.environ.get('XLA_FLAGS', '')} {SINGLE_THREAD_XLA}".strip()
    cores = sorted(os.sched_getaffinity(0))
    process = subprocess.Popen(
        command,
        stdout=_log_file(run).open("w"),
        stderr=subprocess.STDOUT,
        env={**os.environ, "XLA_FLAGS": flags},
    )
    with contextlib.suppress(ProcessLookupError):  # a process that already ended needs no core
        os.sched_setaffinity(process.pid, {cores[slot % len(cores)]})
    return process


def _log_file(run: RunSpec) -> Path:
    run.run_dir.parent.mkdir(parents=True, exist_ok=True)
    return run.run_dir.parent / f"{run.name}.log"


def _collect_ours(run: RunSpec, out: Path, status: int, seconds: float) -> None:
    add_timing(out, run.name, seconds)
    if status != 0 or not reached_budget(run, progress(run) or 0):
        raise GridError(f"{run.name}: swat_jax.train exited with status {status}; its log: {_log_file(run)}")
    print(f"{run.name}: finished in {seconds / 60:.1f} min", file=sys.stderr)


def prepare_tree(original: Original) -> None:
    """Have the original's tools copy its tree into ORIGINAL_WORK once, before seeds start side by side (each
    would copy it otherwise, and a seed started during another's copy finds it half-written)."""
    setup = f"import sys; sys.path.insert(0, {str(original.tools)!r}); import common; common.extract()"
    environment = {**os.environ, "ORIG_SWAT_DIR": str(ORIGINAL_WORK)}
    subprocess.run([str(original.python), "-c", setup], env=environment, cwd="/tmp", check=True)


def _start_original(run: OriginalRun, original: Original, _slot: int) -> subprocess.Popen:
    """Start the seed, one torch thread, on no core in particular (as every committed original run was)."""
    for stale in (ORIGINAL_WORK / "src" / "results", ORIGINAL_WORK / "src" / "buffers"):
        shutil.rmtree(stale / run.experiment_id, ignore_errors=True)
    run.folder.mkdir(parents=True, exist_ok=True)
    command = run.command(original.python, original.tools, original.timeout)
    print(f"original {run.name}: {shlex.join(command)}", file=sys.stderr)
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "ORIG_SWAT_DIR": str(ORIGINAL_WORK)}
    log = (run.folder / "trainer.log").open("w")
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=environment, cwd="/tmp")


def _collect_original(run: OriginalRun, status: int, seconds: float) -> None:
    results = ORIGINAL_WORK / "src" / "results" / run.experiment_id
    if status != 0 or not (results / "stat.json").is_file():
        raise GridError(
            f"original {run.name} exited with status {status}; its log: {run.folder / 'trainer.log'}"
        )
    if "training finished" not in run.log():
        raise GridError(
            f"original {run.name} stopped before its budget (after {seconds:.0f} s); raise --original-timeout "
            f"(its log: {run.folder / 'trainer.log'})"
        )
    shutil.copy(results / "args.txt", run.folder / "args.txt")
    shutil.copy(results / "stat.json", run.folder / "stat.json")
    print(f"original {run.name}: finished in {seconds / 60:.1f} min", file=sys.stderr)
