"""The paper's experiments as one command each: train the grid, then draw the figure or write the table.

    python -m experiments.paper figure4|figure5|figure6|tables --scale tiny|paper [--sets SET ...]

  figure4  multi-task learning (section 5.2): SWAT, AMORPHEUS and SMP on every set
  figure5  transfer (section 5.3): SWAT, AMORPHEUS and SMP pretrained on a set's train bodies, then
           fine-tuned on its held-out bodies, against SWAT trained on them from scratch ("w/o transfer")
  figure6  ablations (section 5.4): SWAT without its positional embedding (PE), its relational
           embedding (RE), and both
  tables   zero-shot returns on held-out bodies (appendix A.4, Tables 3-4) of the figure4 runs

Every (set, algorithm) is one ``python -m swat_jax.train`` process that trains all seeds in one program
(``--seeds``), in ``OUT/runs/<set>-<algorithm>``; commands share runs (figure5, figure6 and tables reuse
figure4's). A run that has reached its budget is kept, one that stopped part-way is resumed, so after a
Ctrl-C (the running run checkpoints first) the same command continues where it stopped. Then the
figure (``OUT/<figure>.png``, its numbers in ``OUT/<figure>.csv``) or the tables (``OUT/tables.md``)
are written, with ``OUT/<command>.md``: the command, machine, date, wall clock of each run and the
final returns.

Scales: ``paper`` is the paper's settings (paper-sized networks and TD3, 10M environment steps per set
summed over its bodies, 1M for fine-tuning, 5 seeds) for a GPU; ``tiny`` (small networks, 3 seeds,
80K steps per set) fits Hopper++ and Walker++ into about an hour of 2 CPU cores.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import json
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import tyro

from experiments.machine import cpu_model, host_cores, software_versions
from swat_jax.cli import strict_json
from swat_jax.compilation_cache import enable_caches
from swat_jax.morphology import get_set
from swat_jax.plot import plot_curves
from swat_jax.runs.checkpoint import Checkpoints
from swat_jax.runs.config import (
    CONFIG_FILE,
    PRESETS,
    Algorithm,
    NetworkSizes,
    TrainConfig,
    config_flags,
    flag_values,
    load_config,
)
from swat_jax.runs.metrics import CSV_FILE, read_metrics
from swat_jax.train import INTERRUPTED_STATUS

MAIN_ALGORITHMS = ("swat", "amorpheus", "smp")
ABLATIONS = ("swat", "swat_no_re", "swat_no_pe", "swat_no_pe_re")
TIMINGS_FILE = "timings.json"
"""Wall clock of each run, kept in OUT across invocations (a resumed run adds its parts)."""


@dataclasses.dataclass(frozen=True)
class Scale:
    """The size of every run of the grid."""

    name: str
    seeds: int
    """Seeds per run, trained in one program."""
    steps: int
    """Environment steps of a training run, summed over the set's bodies (the paper's convention)."""
    finetune_steps: int
    """Environment steps of a fine-tuning run on the held-out bodies (figure5)."""
    table_episodes: int
    """Deterministic episodes per body and seed of the zero-shot tables."""
    base: TrainConfig
    """Every other setting of the runs: preset, network sizes, iteration, TD3, logging."""
    sets: dict[str, tuple[str, ...]]
    """The sets each command runs on unless ``--sets`` names others."""
    smp_network: NetworkSizes | None = None
    """SMP's network sizes (its hidden layers), where the transformer's do not size it; None: the base's."""

    def run(self, run_dir: Path, environment_set: str, algorithm: str, **fields: Any) -> RunSpec:
        """The run of ``algorithm`` on ``environment_set`` in ``run_dir`` at this scale, with ``fields``."""
        network = self.smp_network if algorithm == "smp" and self.smp_network else self.base.network
        config = dataclasses.replace(
            self.base,
            env=environment_set,
            algo=algorithm,
            seeds=self.seeds,
            network=network,
            run_dir=str(run_dir),
            **{"steps": self.steps, **fields},
        )
        return RunSpec(config)


FAST = PRESETS["fast"]
TINY_NETWORK = NetworkSizes(width=32, layers=1, feedforward=64)
SCALES = {
    "paper": Scale(
        name="paper",
        seeds=5,
        steps=10_000_000,
        finetune_steps=1_000_000,
        table_episodes=100,
        base=dataclasses.replace(PRESETS["paper"], eval_interval=200_000, log_interval=50_000),
        sets={
            "figure4": ("hopper", "walker", "humanoid", "cheetah", "wh", "cwhh", "cwh", "animal_walkers"),
            "figure5": ("humanoid", "cwhh"),
            "figure6": ("animal_walkers", "cwhh"),
            "tables": ("walker", "humanoid", "cheetah", "cwhh"),
        },
    ),
    "tiny": Scale(
        name="tiny",
        seeds=3,
        steps=80_000,
        finetune_steps=40_000,
        table_episodes=10,
        base=dataclasses.replace(
            FAST,
            envs=dataclasses.replace(FAST.envs, copies=8),
            network=TINY_NETWORK,
            iteration=dataclasses.replace(
                FAST.iteration, chunk=25, updates=40, random_steps=1000, capacity=50_000
            ),
            td3=dataclasses.replace(FAST.td3, batch_size=100, learning_rate=0.001, n_step=1),
            log_interval=4000,
            checkpoint_interval=40_000,
        ),
        sets={
            "figure4": ("hopper", "walker"),
            "figure5": ("walker",),
            "figure6": ("hopper",),
            "tables": ("walker",),
        },
        smp_network=dataclasses.replace(TINY_NETWORK, smp_hidden=32),
    ),
}
"""The scales of ``--scale``."""


class GridError(RuntimeError):
    """The grid cannot go on; the message says why and what to do."""


class GridInterrupted(GridError):
    """Ctrl-C: the running run checkpointed; the same command continues."""


# Figures, tables and their reports


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One training run of the grid: its TrainConfig, written as JSON beside its run directory and trained
    with ``python -m swat_jax.train --config FILE``."""

    config: TrainConfig

    @property
    def run_dir(self) -> Path:
        return Path(self.config.run_dir)

    @property
    def name(self) -> str:
        return self.run_dir.name

    @property
    def config_file(self) -> Path:
        """``OUT/runs/<name>.json``, beside the run directory."""
        return self.run_dir.parent / f"{self.name}.json"

    def write_config(self) -> Path:
        """Write :attr:`config_file` (the grid's plan, read by the training command)."""
        self.config_file.parent.mkdir(parents=True, exist_ok=True)
        self.config_file.write_text(self.config.to_json())
        return self.config_file

    def command(self) -> list[str]:
        """The command that starts this run (from :attr:`config_file`)."""
        return [sys.executable, "-m", "swat_jax.train", "--config", str(self.config_file)]

    def resume_command(self) -> list[str]:
        """The command that continues this run from its newest checkpoint to its budget."""
        return [
            sys.executable,
            "-m",
            "swat_jax.train",
            "--resume",
            str(self.run_dir),
            "--steps",
            str(self.config.steps),
            *(["--counted-steps", str(self.config.counted_steps)] if self.config.counted_steps else []),
        ]


def set_label(environment_set: str) -> str:
    """The set's name in run directory names: a benchmark set's name, or a folder's name."""
    return Path(environment_set).name


def pretraining(out: Path, scale: Scale, environment_set: str, algorithm: str) -> RunSpec:
    """``algorithm`` trained on the train bodies of ``environment_set`` (figures 4 and 6, pretraining, tables)."""
    return scale.run(out / "runs" / f"{set_label(environment_set)}-{algorithm}", environment_set, algorithm)


def fine_tuning(out: Path, scale: Scale, environment_set: str, algorithm: str, transfer: bool) -> RunSpec:
    """``algorithm`` trained on the held-out bodies, from its pretrained run (``transfer``) or from scratch."""
    source = pretraining(out, scale, environment_set, algorithm)
    name = f"{set_label(environment_set)}-test-{algorithm}-{'transfer' if transfer else 'scratch'}"
    return scale.run(
        out / "runs" / name,
        environment_set,
        algorithm,
        split="test",
        steps=scale.finetune_steps,
        init_from=str(source.run_dir) if transfer else "",
    )


def with_test_bodies(sets: Sequence[str], command: str) -> list[str]:
    """The sets that have held-out bodies; GridError if none has."""
    kept = [environment_set for environment_set in sets if get_set(environment_set).split("test")]
    skipped = sorted(set(sets) - set(kept))
    if skipped:
        print(f"{command}: skipping {', '.join(skipped)} (no held-out test bodies)", file=sys.stderr)
    if not kept:
        raise GridError(f"{command} needs sets with held-out bodies, e.g. walker, humanoid, cheetah or cwhh")
    return kept


def grid(
    command: str, scale: Scale, sets: Sequence[str], algorithms: Sequence[str], out: Path
) -> list[RunSpec]:
    """The training runs ``command`` needs, in the order they run (pretraining before fine-tuning)."""
    if command in ("figure4", "figure6"):
        return [pretraining(out, scale, s, algorithm) for s in sets for algorithm in algorithms]
    if command == "tables":
        return [
            pretraining(out, scale, s, algorithm)
            for s in with_test_bodies(sets, command)
            for algorithm in algorithms
        ]
    runs = []
    for environment_set in with_test_bodies(sets, command):
        runs += [pretraining(out, scale, environment_set, algorithm) for algorithm in algorithms]
        runs += [
            fine_tuning(out, scale, environment_set, algorithm, transfer=True) for algorithm in algorithms
        ]
        runs.append(fine_tuning(out, scale, environment_set, "swat", transfer=False))
    return runs


def plotted_runs(command: str, runs: Sequence[RunSpec]) -> list[RunSpec]:
    """The runs drawn in ``command``'s figure: figure5 draws the fine-tuning runs only."""
    if command == "figure5":
        return [run for run in runs if run.config.split == "test"]
    return list(runs)


# Running the grid


def progress(run: RunSpec) -> int | None:
    """Environment steps of ``run``'s newest checkpoint; None if it has not started.

    Raises:
        GridError: the directory holds a run with other settings.
    """
    if not (run.run_dir / CONFIG_FILE).is_file():
        return None
    saved, expected = (flag_values(config) for config in (load_config(run.run_dir / CONFIG_FILE), run.config))
    differences = [
        f"{flag} {saved[flag]!r} (wanted {value!r})"
        for flag, value in expected.items()
        if flag not in ("--steps", "--counted-steps", "--run-dir") and saved[flag] != value
    ]
    if differences:
        raise GridError(
            f"{run.run_dir} holds a run with other settings: {', '.join(differences)}; delete it, or give "
            "another --out"
        )
    checkpoints = Checkpoints(run.run_dir)
    try:
        return checkpoints.latest_step() or 0
    finally:
        checkpoints.close()


def reached_budget(run: RunSpec, steps: int) -> bool:
    """Whether ``run``, its newest checkpoint at ``steps``, has ended: at its ``--steps``, or with
    ``--counted-steps`` once every seed has counted them (its metrics rows up to the checkpoint say)."""
    if steps >= run.config.steps:
        return True
    if not run.config.counted_steps or not (run.run_dir / CSV_FILE).is_file():
        return False
    counted = {
        row["seed"]: row["counted_steps"] for row in read_metrics(run.run_dir) if row["env_steps"] <= steps
    }
    return bool(counted) and min(counted.values()) >= run.config.counted_steps


def run_child(command: list[str]) -> int:
    """Run ``command`` to its end and return its exit status.

    A Ctrl-C reaches the child too (same process group): the training run checkpoints and exits, and
    this waits for it instead of killing it, as ``subprocess.run`` would.
    """
    process = subprocess.Popen(command)
    while True:
        try:
            return process.wait()
        except KeyboardInterrupt:
            continue


def read_timings(out: Path) -> dict[str, float]:
    """The wall clock (s) recorded for each run name in ``OUT/timings.json``; empty before any run."""
    path = out / TIMINGS_FILE
    return json.loads(path.read_text()) if path.is_file() else {}


def add_timing(out: Path, name: str, seconds: float) -> None:
    """Add ``seconds`` to ``name``'s wall clock in ``OUT/timings.json`` (a resumed run adds up its sittings)."""
    timings = read_timings(out)
    timings[name] = timings.get(name, 0.0) + seconds
    out.mkdir(parents=True, exist_ok=True)
    (out / TIMINGS_FILE).write_text(strict_json(timings, indent=2) + "\n")


def exit_status(work: Callable[[], Path | None]) -> int:
    """Run a command's ``work`` and give its exit status: 0 (printing the file it wrote, if any), the
    interrupted status after Ctrl-C (the same command continues), 2 with one error line for bad input."""
    try:
        path = work()
    except GridInterrupted as error:
        print(f"\n{error}", file=sys.stderr)
        return INTERRUPTED_STATUS
    except (GridError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if path is not None:
        print(f"wrote {path}")
    return 0


def shown(command: Sequence[str]) -> str:
    """``command`` as a shell line to copy, this interpreter's path written as ``python``."""
    return shlex.join("python" if part == sys.executable else part for part in command)


def train_all(runs: Sequence[RunSpec], out: Path) -> None:
    """Train every run that has not reached its budget, one after another; record their wall clock."""
    for index, run in enumerate(runs, start=1):
        steps = progress(run)
        label = f"[{index}/{len(runs)}] {run.name}"
        if steps is not None and reached_budget(run, steps):
            print(f"{label}: done ({steps:,} steps), kept", file=sys.stderr)
            continue
        command = run.command() if steps is None else run.resume_command()
        if steps is None:
            run.write_config()
        print(f"{label}: {'training' if steps is None else f'resuming at {steps:,} steps'}", file=sys.stderr)
        print(f"  {shown(command)}", file=sys.stderr)
        start = time.perf_counter()
        status = run_child(command)
        add_timing(out, run.name, time.perf_counter() - start)
        if status == INTERRUPTED_STATUS:
            raise GridInterrupted(
                f"{run.name} stopped before its budget; run the same command again to continue"
            )
        if status != 0 or not reached_budget(run, progress(run) or 0):
            raise GridError(f"{run.name}: swat_jax.train exited with status {status} (its message is above)")


def final_points(csv_path: Path) -> list[dict[str, str]]:
    """The last row of every (panel, algorithm) of a curves CSV written by ``swat_jax.plot``."""
    last: dict[tuple[str, str], dict[str, str]] = {}
    with csv_path.open() as file:
        for row in csv.DictReader(file):
            last[row["panel"], row["algorithm"]] = row
    return list(last.values())


def final_points_table(csv_path: Path) -> str:
    """A Markdown table of the final points of a curves CSV."""
    lines = [
        "| panel | algorithm | environment steps | return (mean ± s.e. over seeds) | seeds |",
        "|---|---|---|---|---|",
    ]
    for row in final_points(csv_path):
        lines.append(
            f"| {row['panel']} | {row['algorithm']} | {int(row['env_steps']):,} | "
            f"{float(row['mean']):.1f} ± {float(row['standard_error']):.1f} | {row['seeds']} |"
        )
    return "\n".join(lines)


def draw_figure(command: str, runs: Sequence[RunSpec], out: Path, scale: Scale) -> list[str]:
    """Draw ``command``'s curves (and the evaluation curves when the scale evaluates during training);
    returns the report's Markdown sections."""
    run_dirs = [run.run_dir for run in plotted_runs(command, runs)]
    metrics = ["train"] + (["eval"] if scale.base.eval_interval else [])
    sections = []
    for metric in metrics:
        png = out / (f"{command}.png" if metric == "train" else f"{command}_eval.png")
        plot_curves(run_dirs, png, metric=metric)
        what = (
            "training episodes (exploration noise on), as in the paper"
            if metric == "train"
            else ("deterministic evaluations during training")
        )
        sections.append(
            f"![{command}]({png.name})\n\nFinal point of each curve, return of the {what} "
            f"(numbers of every point: [{png.with_suffix('.csv').name}]({png.with_suffix('.csv').name})):\n\n"
            + final_points_table(png.with_suffix(".csv"))
        )
    return sections


def write_tables(runs: Sequence[RunSpec], out: Path, scale: Scale) -> list[str]:
    """Zero-shot returns of every set's runs on its held-out bodies, one Markdown table per set
    (``python -m swat_jax.eval --split test --markdown``); written to ``OUT/tables.md`` too."""
    by_set: dict[str, list[RunSpec]] = {}
    for run in runs:
        by_set.setdefault(run.config.env, []).append(run)
    sections = []
    for environment_set, set_runs in by_set.items():
        command = [
            sys.executable, "-m", "swat_jax.eval", *(str(run.run_dir) for run in set_runs),
            "--split", "test", "--episodes", str(scale.table_episodes), "--markdown",
        ]  # fmt: skip
        print(f"tables: {shown(command)}", file=sys.stderr)
        result = subprocess.run(command, stdout=subprocess.PIPE, text=True)
        if result.returncode != 0:
            raise GridError(f"swat_jax.eval exited with status {result.returncode} (its message is above)")
        sections.append(
            f"### {set_label(environment_set)}: held-out bodies, zero-shot\n\n{result.stdout.strip()}"
        )
    (out / "tables.md").write_text("\n\n".join(sections) + "\n")
    return sections


def report(
    command: str, argv: Sequence[str], scale: Scale, runs: Sequence[RunSpec], out: Path, sections: list[str]
) -> Path:
    """Write ``OUT/<command>.md``: the command, machine, date, settings, wall clock per run, results."""
    timings = read_timings(out)
    versions = ", ".join(f"{name} {version}" for name, version in software_versions().items())
    lines = [
        f"# {command}, scale {scale.name}",
        "",
        f"- Command: `python -m experiments.paper {shlex.join(argv)}`",
        f"- Date: {datetime.date.today().isoformat()}",
        f"- Machine: {cpu_model()}, {host_cores()} cores; {versions}",
        f"- Every run: {scale.seeds} seeds in one program; `{shlex.join(config_flags(scale.base))}`"
        + (f"; SMP runs `--network.smp-hidden {scale.smp_network.smp_hidden}`" if scale.smp_network else ""),
        "",
        "| run | environment steps per seed | wall clock (min, compile included) |",
        "|---|---|---|",
    ]
    for run in runs:
        seconds = timings.get(run.name)
        minutes = "-" if seconds is None else f"{seconds / 60:.1f}"
        lines.append(f"| {run.name} | {run.config.steps:,} | {minutes} |")
    path = out / f"{command}.md"
    path.write_text("\n".join([*lines, "", *sections]) + "\n")
    return path


Command = Literal["figure4", "figure5", "figure6", "tables"]
ScaleName = Literal["tiny", "paper"]


@dataclasses.dataclass(frozen=True)
class PaperCommand:
    """The paper's experiments as one command each: train the grid, then draw the figure or write the table.
    Runs are kept and resumed: after a Ctrl-C, the same command continues where it stopped."""

    command: tyro.conf.Positional[Command]
    """The figure or table to produce."""
    scale: ScaleName = "tiny"
    """tiny (small networks, 3 seeds, 80K steps per set; about an hour on 2 CPU cores) or paper (the paper's settings, 5 seeds, 10M steps per set; for a GPU)."""
    sets: tuple[str, ...] = ()
    """Environment sets (or MJCF folders) to run; none: the scale's sets for the command."""
    algos: tuple[Algorithm, ...] = ()
    """Algorithms to run; none: swat, amorpheus and smp (swat, swat_no_re, swat_no_pe, swat_no_pe_re for figure6)."""
    out: Path | None = None
    """The folder for runs, figures and reports; None: experiments/results/<scale>."""
    dry_run: bool = False
    """Write every run's config file (OUT/runs/<run>.json) and print the commands that train them, then stop."""


def produce(
    command: str, scale: Scale, sets: Sequence[str], algorithms: Sequence[str], out: Path, argv: Sequence[str]
) -> Path:
    """Train ``command``'s grid, draw its figure or tables, write its report; returns the report's path."""
    runs = grid(command, scale, sets, algorithms, out)
    train_all(runs, out)
    sections = (
        write_tables(runs, out, scale) if command == "tables" else draw_figure(command, runs, out, scale)
    )
    return report(command, argv, scale, runs, out, sections)


def main(argv: list[str] | None = None) -> int:
    enable_caches()
    argv = sys.argv[1:] if argv is None else argv
    args = tyro.cli(PaperCommand, args=argv, prog="python -m experiments.paper")
    scale = SCALES[args.scale]
    sets = args.sets or scale.sets[args.command]
    algorithms = args.algos or (ABLATIONS if args.command == "figure6" else MAIN_ALGORITHMS)
    out = args.out or Path("experiments/results") / scale.name

    def work() -> Path | None:
        if args.dry_run:
            for run in grid(args.command, scale, sets, algorithms, out):
                run.write_config()
                print(shown(run.command()))
            return None
        return produce(args.command, scale, sets, algorithms, out, argv)

    return exit_status(work)


if __name__ == "__main__":
    sys.exit(main())
