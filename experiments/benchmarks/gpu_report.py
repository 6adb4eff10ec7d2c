"""The GPU report: the figures that "accelerated" rests on, in one command, as JSON and Markdown.

One run measures, each configuration in a fresh process (its compilation and memory peak its own):

1. Multi-task MJX environment steps per second (every training body of a set, K bodies x n copies, random
   actions, :func:`env_benchmark.throughput_worker`) on Hopper++, Animal-Walkers and CWHH++ over 1, 16,
   256 and 2048 copies per body. A set's sweep stops once throughput grows by less than ``MIN_GAIN`` over
   the previous count, or a run runs out of memory or of the time budget. Each set also runs on MuJoCo C
   on every core of the host (one process per core, :func:`env_benchmark.c_steps_per_second_on_cores`).
2. Trace (lower) and XLA compile seconds of every configuration, with the persistent compilation cache as
   configured (a fresh machine's is empty, so the times are cold; ``SWAT_JAX_COMPILATION_CACHE=0`` makes
   them cold anywhere).
3. TD3 update throughput of the paper-sized SWAT (Table 1) on Animal-Walkers and CWHH++: batch 100 per
   body, all bodies in one vmapped update (:func:`update_benchmark.vmapped_throughput`).
4. Time to return: ``train_presets`` trained on ``train_set`` (each preset's network, ``train_seeds`` seeds in one
   program) for ``train_seconds`` each, in a subprocess stopped with Ctrl-C's signal (the run checkpoints
   and exits): seconds to the first metrics row (start-up and compilation), environment steps per second
   per seed, and the mean return over seeds of the training episodes against wall clock, row by row.
5. Peak device memory and peak RSS of every configuration; the device, the host, the software versions.

The whole run keeps to ``--budget`` seconds (420 by default, well inside 9 minutes on an H100 or H200
once the image has started): a run stops when the budget ends, and a configuration expected to take
longer than what is left (its series' previous run took longer) is not started; both are listed under
"not measured". ``--tiny`` runs the same code on a CPU in CI time: the hopper set at 1 and 2 copies, a
few steps, a width-16 one-layer SWAT::

    python -m experiments.benchmarks.gpu_report --out reports/gpu           # reports/gpu/report.json, report.md
    python -m experiments.benchmarks.gpu_report --tiny --out /tmp/gpu_report
"""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import tyro

from experiments.benchmarks.env import (
    c_steps_per_second_on_cores,
    display_name,
    gib,
    info_worker,
    peak_memory,
    progress,
    sweep_copies,
    throughput_job,
    train_bodies,
)
from experiments.benchmarks.update import vmapped_throughput
from experiments.machine import cpu_model, host_cores, host_memory_gib
from experiments.workers import Job, WorkerError, in_fresh_process
from swat_jax.cli import strict_json
from swat_jax.compilation_cache import cache_directory, enable_caches
from swat_jax.networks import network_config
from swat_jax.runs.metrics import read_metrics

MIN_GAIN = 1.05
"""A set's copy sweep stops once steps/s grows by less than this factor over the previous count."""
MIN_START_S = 5.0
"""No worker starts with less time than this left in the budget."""
REPORT_FILES = ("report.json", "report.md")


@dataclasses.dataclass(frozen=True)
class ReportSettings:
    """What one report measures, and its time budget."""

    sets: tuple[str, ...]
    """Environment sets whose training bodies are stepped, in this order."""
    copies: tuple[int, ...]
    """Copies per body of the sweep, increasing."""
    steps: int
    """Env steps per timed call (one lax.scan inside one jit)."""
    repeats: int
    """Timed calls per configuration (median, after a warm-up call)."""
    c_steps: int
    """Env steps per body in each MuJoCo C process."""
    update_sets: tuple[str, ...]
    """Sets whose TD3 update is timed (each right after its env sweep)."""
    network: str
    """Network variant of the update, a name network_config takes."""
    network_overrides: dict[str, int]
    """NetworkConfig fields that differ from the named variant (none: the paper's sizes)."""
    batch: int
    """Sampled transitions per body per update."""
    updates: int
    """Updates per timed call (scanned in one jit)."""
    budget_s: float
    """Seconds the whole report may take."""
    train_set: str = "hopper"
    """Set the presets train on for the time-to-return rows."""
    train_presets: tuple[str, ...] = ("paper", "fast")
    """Presets trained for ``train_seconds`` each (none: no training rows)."""
    train_seeds: int = 5
    """Seeds in each training program."""
    train_seconds: float = 90.0
    """Wall seconds of each training run, start-up included (a run goes on to its first metrics row)."""
    train_flags: tuple[str, ...] = ()
    """More ``swat_jax.train`` flags of every training run (none: each preset's own network, paper-sized for paper, width 32 for fast)."""


FULL = ReportSettings(
    sets=("hopper", "animal_walkers", "cwhh"),
    copies=(1, 16, 256, 2048),
    steps=100,
    repeats=3,
    c_steps=1000,
    update_sets=("animal_walkers", "cwhh"),
    network="swat",
    network_overrides={},
    batch=100,
    updates=20,
    budget_s=420.0,
)
TINY = ReportSettings(
    sets=("hopper",),
    copies=(1, 2),
    steps=5,
    repeats=1,
    c_steps=20,
    update_sets=("hopper",),
    network="swat",
    network_overrides={"width": 16, "heads": 1, "layers": 1, "feedforward": 32},
    batch=8,
    updates=2,
    budget_s=300.0,
    train_presets=("fast",),
    train_seeds=2,
    train_seconds=30.0,
    train_flags=(
        "--network.width", "16", "--network.heads", "1", "--network.layers", "1", "--network.feedforward", "32",
        "--envs.copies", "2",
        "--iteration.chunk", "10", "--iteration.updates", "2", "--iteration.random-steps", "20",
        "--iteration.capacity", "2000", "--td3.batch-size", "8", "--log-interval", "60",
    ),
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Options:
    """The GPU report: the figures that "accelerated" rests on, in one command, as JSON and Markdown."""

    out: Path
    """Folder for report.json and report.md."""
    tiny: bool = False
    """CPU-sized: hopper, copies 1 2, a few steps, tiny SWAT."""
    sets: tuple[str, ...] | None = None
    """Environment sets (None: hopper animal_walkers cwhh, or --tiny's)."""
    copies: tuple[int, ...] | None = None
    """Copies per body (None: 1 16 256 2048, or --tiny's)."""
    update_sets: tuple[str, ...] | None = None
    """Sets whose update is timed (None: animal_walkers cwhh, or --tiny's)."""
    budget: float | None = None
    """Seconds the report may take (None: 420, or --tiny's)."""
    train_set: str | None = None
    """Set of the time-to-return runs (None: hopper)."""
    train_presets: tuple[str, ...] | None = None
    """Presets trained (None: paper fast, or --tiny's; none given: no training)."""
    train_seconds: float | None = None
    """Wall seconds of each training run (None: 90, or --tiny's)."""


def update_worker(
    set_name: str, network: str, overrides: dict[str, int], batch: int, updates: int, repeats: int
) -> dict[str, Any]:
    """TD3 update throughput of ``network`` on every training body of ``set_name``, and peak memory."""
    result = vmapped_throughput(set_name, network_config(network, **overrides), batch, updates, repeats)
    return {**result, **peak_memory()}


def training_worker(
    set_name: str, preset: str, seeds: int, seconds: float, flags: list[str]
) -> dict[str, Any]:
    """Train ``preset`` on ``set_name`` for ``seconds`` of wall clock, and at least until its first metrics
    row (then SIGINT: the run checkpoints and exits), and read its metrics: per row, the wall seconds
    since the command started (the rows' own steps per second, the start-up before the first row
    included), steps per seed and the mean return over seeds of the training episodes."""
    with tempfile.TemporaryDirectory(prefix="gpu_report_train_") as folder:
        run_dir = Path(folder) / "run"
        command = [
            sys.executable, "-m", "swat_jax.train", "--preset", preset, "--env", set_name, "--seeds", str(seeds),
            "--steps", "100000000", "--checkpoint-interval", "100000000", "--run-dir", str(run_dir), *flags,
        ]  # fmt: skip
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            process.wait(timeout=seconds)
        except subprocess.TimeoutExpired:
            wait_for_first_row(run_dir / "metrics.csv", process)
            process.send_signal(signal.SIGINT)
            process.wait()
        wall = time.perf_counter() - start
        errors = process.stderr.read() if process.stderr else ""
        if process.returncode != 0 or not (run_dir / "metrics.csv").is_file():
            raise WorkerError(f"training {preset} exited with {process.returncode}: {errors[-2000:]}")
        rows = read_metrics(run_dir)
    by_steps: dict[float, list[dict[str, float]]] = {}
    for row in rows:
        by_steps.setdefault(row["env_steps"], []).append(row)
    steps = sorted(by_steps)
    windows = np.cumsum(
        [(b - a) / by_steps[b][0]["steps_per_second"] for a, b in zip([0.0, *steps[:-1]], steps, strict=True)]
    )
    startup = wall - windows[-1]
    curve = [
        {
            "seconds": startup + float(window),
            "env_steps_per_seed": step,
            "mean_return": float(np.nanmean([row["mean_return"] for row in by_steps[step]])),
        }
        for step, window in zip(steps, windows, strict=True)
    ]
    return {
        "set": set_name,
        "preset": preset,
        "seeds": seeds,
        "wall_s": wall,
        "first_row_s": curve[0]["seconds"],
        "env_steps_per_second_per_seed": steps[-1] / windows[-1],
        "curve": curve,
        **peak_memory(),
    }


def wait_for_first_row(metrics: Path, process: subprocess.Popen) -> None:
    """Return once ``metrics`` (a run's metrics.csv) holds a whole row after its header, or ``process`` has
    ended: a run is then training (its stop handlers in place), however long its start took."""
    while process.poll() is None and not (metrics.is_file() and metrics.read_text().count("\n") >= 2):
        time.sleep(0.2)


class Budget:
    """The report's time budget: runs worker processes of this script only where they fit in it."""

    def __init__(self, seconds: float):
        self.seconds = seconds
        self.deadline = time.perf_counter() + seconds
        self.last_seconds: dict[str, float] = {}
        """Wall seconds of the previous run of each series (a set's sweep, the updates)."""

    def left(self) -> float:
        return self.deadline - time.perf_counter()

    def run(self, job: Job, series: str) -> dict[str, Any]:
        """The result of ``job`` in a fresh process, stopped when the budget ends.

        Raises:
            WorkerError: ``timed_out`` when the run was stopped, or not started because less time is left
                than ``MIN_START_S`` or than the series' previous run took; ``out_of_memory`` when it ran
                out of device memory.
        """
        left = self.left()
        needed = max(MIN_START_S, self.last_seconds.get(series, 0.0))
        if left < needed:
            raise WorkerError(f"{left:.0f} s left of the budget, {needed:.0f} s expected", timed_out=True)
        start = time.perf_counter()
        result = in_fresh_process(job, timeout=left)
        self.last_seconds[series] = time.perf_counter() - start
        return result


def environment_rows(
    set_name: str, settings: ReportSettings, budget: Budget, started: float
) -> tuple[list[dict[str, Any]], str, float]:
    """The throughput rows of one set's copy sweep (each with MuJoCo C's rate), why the sweep stopped, and
    MuJoCo C's steps per second on every core."""
    cores = host_cores()
    progress(
        f"{display_name(set_name)}: MuJoCo C on {cores} processes, {settings.c_steps} steps per body", started
    )
    c_rate = c_steps_per_second_on_cores(train_bodies(set_name), settings.c_steps, cores)

    def measure(copies: int) -> dict[str, Any]:
        return budget.run(throughput_job(set_name, copies, settings.steps, settings.repeats), series=set_name)

    rows, stop = sweep_copies(set_name, settings.copies, measure, MIN_GAIN, started)
    for row in rows:
        row.update(c_steps_per_second=c_rate, mjx_over_c=row["steps_per_second"] / c_rate)
    return rows, stop, c_rate


def update_row(set_name: str, settings: ReportSettings, budget: Budget, started: float) -> dict[str, Any]:
    """The TD3 update measurement of one set (WorkerError when it ran out of time or memory)."""
    progress(
        f"{display_name(set_name)}: TD3 update of {settings.network}, batch {settings.batch} per body",
        started,
    )
    job = Job(
        update_worker,
        {
            "set_name": set_name,
            "network": settings.network,
            "overrides": settings.network_overrides,
            "batch": settings.batch,
            "updates": settings.updates,
            "repeats": settings.repeats,
        },
    )
    row = {
        "set": set_name,
        "network": settings.network,
        "batch_per_body": settings.batch,
        **budget.run(job, "update"),
    }
    progress(
        f"  {row['transitions_per_second']:,.0f} transitions/s (compile {row['compile_s']:.1f} s)", started
    )
    return row


def training_rows(
    settings: ReportSettings, budget: Budget, started: float
) -> tuple[list[dict[str, Any]], list[str]]:
    """Every preset's time-to-return row, and what did not fit in the budget."""
    rows, not_measured = [], []
    for preset in settings.train_presets:
        progress(
            f"{display_name(settings.train_set)}: training {preset} for {settings.train_seconds:.0f} s",
            started,
        )
        arguments = {
            "set_name": settings.train_set,
            "preset": preset,
            "seeds": settings.train_seeds,
            "seconds": settings.train_seconds,
            "flags": list(settings.train_flags),
        }
        try:
            rows.append(budget.run(Job(training_worker, arguments), "training"))
        except WorkerError as error:
            if not error.timed_out:
                raise
            not_measured.append(f"{display_name(settings.train_set)}: training {preset}, out of time")
    return rows, not_measured


def measure_report(settings: ReportSettings, command: str) -> dict[str, Any]:
    """Every measurement of ``settings``, as the report's JSON object."""
    started = time.perf_counter()
    budget = Budget(settings.budget_s)
    info = budget.run(Job(info_worker), "info")
    environment, updates, stops, c_rates, not_measured = [], [], {}, {}, []
    for set_name in settings.sets:
        rows, stops[set_name], c_rates[set_name] = environment_rows(set_name, settings, budget, started)
        environment.extend(rows)
        if stops[set_name].startswith(("out of time", "out of memory")):
            not_measured.append(f"{display_name(set_name)}: {stops[set_name]} and more")
        if set_name in settings.update_sets:
            try:
                updates.append(update_row(set_name, settings, budget, started))
            except WorkerError as error:
                if not (error.timed_out or error.out_of_memory):
                    raise
                reason = "out of time" if error.timed_out else "out of memory"
                not_measured.append(f"{display_name(set_name)}: TD3 update, {reason}")
    training, not_trained = training_rows(settings, budget, started)
    not_measured += not_trained
    peaks = [
        row["device_peak_gib"]
        for row in environment + updates + training
        if row["device_peak_gib"] is not None
    ]
    return {
        "command": command,
        "settings": dataclasses.asdict(settings),
        "machine": {
            "cpu": cpu_model(),
            "cores": host_cores(),
            "memory_gib": round(host_memory_gib(), 1),
            "platform": info["platform"],
            "device": info["device"],
            "device_count": info["device_count"],
        },
        "software": info["versions"],
        "compilation_cache": str(cache_directory() or "off"),
        "mujoco_c_steps_per_second": c_rates,
        "environment": environment,
        "sweep_stops": stops,
        "td3_update": updates,
        "training": training,
        "peak_device_memory_gib": max(peaks, default=None),
        "not_measured": not_measured,
        "total_s": time.perf_counter() - started,
    }


def environment_table(report: dict[str, Any]) -> list[str]:
    cores = report["machine"]["cores"]
    lines = [
        f"| set | bodies x max limbs | copies | MJX steps/s | MuJoCo C steps/s ({cores} processes) | MJX / C "
        "| trace (s) | compile (s) | device peak (GiB) | peak RSS (GiB) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["environment"]:
        lines.append(
            f"| {display_name(row['set'])} | {row['bodies']}x{row['max_limbs']} | {row['copies']} "
            f"| {row['steps_per_second']:,.0f} | {row['c_steps_per_second']:,.0f} | {row['mjx_over_c']:.2f} "
            f"| {row['trace_s']:.1f} | {row['compile_s']:.1f} | {gib(row['device_peak_gib'])} | {gib(row['rss_gib'])} |"
        )
    return lines


def update_table(report: dict[str, Any]) -> list[str]:
    lines = [
        "| set | network | actor / critic parameters | bodies x batch | trace (s) | compile (s) | updates/s "
        "| transitions/s | device peak (GiB) | peak RSS (GiB) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["td3_update"]:
        lines.append(
            f"| {display_name(row['set'])} | {row['network']} | {row['actor_parameters']:,} / "
            f"{row['critic_parameters']:,} | {row['tasks']}x{row['batch_per_body']} | {row['trace_s']:.1f} "
            f"| {row['compile_s']:.1f} | {row['updates_per_second']:,.1f} | {row['transitions_per_second']:,.0f} "
            f"| {gib(row['device_peak_gib'])} | {gib(row['rss_gib'])} |"
        )
    return lines


def training_table(report: dict[str, Any]) -> list[str]:
    lines = [
        "| set | preset | seeds | wall (s) | first metrics row (s) | env steps/s per seed | steps per seed "
        "| mean return at the end | return against wall clock (s: return) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["training"]:
        curve = row["curve"]
        points = ", ".join(f"{point['seconds']:.0f}: {point['mean_return']:.0f}" for point in curve)
        lines.append(
            f"| {display_name(row['set'])} | {row['preset']} | {row['seeds']} | {row['wall_s']:.0f} "
            f"| {row['first_row_s']:.0f} | {row['env_steps_per_second_per_seed']:,.0f} "
            f"| {curve[-1]['env_steps_per_seed']:,.0f} | {curve[-1]['mean_return']:.1f} | {points} |"
        )
    return lines


def markdown(report: dict[str, Any]) -> str:
    """The report as Markdown: machine and software, the two tables, sweep stops, what was not measured."""
    machine, settings = report["machine"], report["settings"]
    device = (
        "CPU only" if machine["platform"] == "cpu" else f"{machine['device_count']} x {machine['device']}"
    )
    software = ", ".join(f"{name} {version}" for name, version in report["software"].items())
    stops = "; ".join(
        f"{display_name(name)}: {stop or 'every count ran'}" for name, stop in report["sweep_stops"].items()
    )
    peak = report["peak_device_memory_gib"]
    lines = [
        "# GPU report",
        "",
        f"Machine: {machine['cpu']}, {machine['cores']} cores, {machine['memory_gib']:.0f} GiB; {device} "
        f"({machine['platform']})  ",
        f"Software: {software}  ",
        f"Command: `{report['command']}`, {report['total_s']:.0f} s of a {settings['budget_s']:.0f} s budget; "
        f"persistent compilation cache: {report['compilation_cache']}",
        "",
        f"## Environment steps per second ({settings['steps']} steps per timed call, median of "
        f"{settings['repeats']}; random actions; every training body of the set)",
        "",
        *environment_table(report),
        "",
        f"Copy sweeps: {stops}.",
        "",
        f"## TD3 update (every body of the set in one vmapped update, {settings['updates']} updates per timed call)",
        "",
        *update_table(report),
        "",
        f"## Time to return (each preset trained for {settings['train_seconds']:.0f} s, start-up included; "
        "returns of the training episodes, mean over seeds)",
        "",
        *training_table(report),
        "",
        f"Peak device memory: {'not reported by this backend' if peak is None else f'{peak:.2f} GiB'}.",
    ]
    if report["not_measured"]:
        lines += ["", f"Not measured: {'; '.join(report['not_measured'])}."]
    return "\n".join(lines) + "\n"


def write_report(report: dict[str, Any], folder: Path) -> list[Path]:
    """``report.json`` and ``report.md`` in ``folder`` (created)."""
    folder.mkdir(parents=True, exist_ok=True)
    json_path, markdown_path = (folder / name for name in REPORT_FILES)
    json_path.write_text(strict_json(report, indent=2) + "\n")
    markdown_path.write_text(markdown(report))
    return [json_path, markdown_path]


def settings_from(args: Options) -> ReportSettings:
    """FULL or TINY, with the options given on the command line."""
    settings = TINY if args.tiny else FULL
    chosen = {
        "sets": args.sets,
        "copies": args.copies,
        "update_sets": args.update_sets,
        "budget_s": args.budget,
        "train_set": args.train_set,
        "train_presets": args.train_presets,
        "train_seconds": args.train_seconds,
    }
    return dataclasses.replace(settings, **{key: value for key, value in chosen.items() if value is not None})


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.gpu_report")
    report = measure_report(settings_from(args), f"python {' '.join(sys.argv)}")
    paths = write_report(report, args.out)
    print(markdown(report))
    print(f"wrote {', '.join(map(str, paths))}", flush=True)


if __name__ == "__main__":
    main()
