"""SWAT trained on a set's bodies against SWAT trained on variants of them, both evaluated zero-shot on
held-out variants: does training on variants help a policy meet bodies it has not seen?

    python -m experiments.variants [--env hopper] [--out experiments/results/variants] [--dry-run]

Two runs of the ``tiny`` scale of ``experiments/paper.py`` (small networks, the ``fast`` preset, 3 seeds
in one program, 80K steps summed over the bodies): ``nominal`` trains on the set's train bodies,
``variants`` on ``--train-variants`` variants of each (every copy its own, ``--variation`` spread). Each
is evaluated deterministically on the bodies themselves and on held-out variants (another seed than
training's) at each spread of ``--spreads``: ``--episodes`` episodes per body and seed, episode j on
variant j. Written to OUT: ``variants.csv`` (one row per run, condition, body and seed: the seed's
mean return), ``variants.png`` (per condition, per run: the mean over bodies, mean ± standard error over
seeds) and ``variants.md`` (the command, machine, wall clock and the numbers). A finished run is kept and
one stopped part-way resumes, so the same command continues after Ctrl-C.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import tyro
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from experiments.machine import cpu_model, host_cores, software_versions
from experiments.paper import SCALES, RunSpec, exit_status, read_timings, train_all
from swat_jax.compilation_cache import enable_caches
from swat_jax.eval import EvalOptions, evaluate_run
from swat_jax.runs.config import config_flags
from swat_jax.runs.metrics import standard_error

ARMS = ("nominal", "variants")
CSV_COLUMNS = ("run", "condition", "body", "seed", "mean_return")


@dataclasses.dataclass(frozen=True)
class Options:
    """Train SWAT on a set's bodies and on variants of them; evaluate both on held-out variants."""

    env: str = "hopper"
    """Environment set."""
    out: Path = Path("experiments/results/variants")
    """Folder of the runs and of the figure, CSV and report."""
    train_variants: int = 8
    """Variants per body in the variants run (each of its 8 copies runs its own)."""
    variation: float = 0.2
    """Spread of the training variants."""
    spreads: tuple[float, ...] = (0.2, 0.4)
    """Spreads of the held-out variants each run is evaluated on (and on the bodies themselves)."""
    episodes: int = 16
    """Evaluation episodes per body and seed (one held-out variant each)."""
    variant_seed: int = 1
    """Seed of the held-out variants (the training draw uses seed 0)."""
    dry_run: bool = False
    """Print the plan (the runs' commands, the evaluations) and stop."""


def runs(options: Options) -> dict[str, RunSpec]:
    """The two training runs of the experiment."""
    scale = SCALES["tiny"]
    variants = dataclasses.replace(
        scale.base.envs, variants=options.train_variants, variation=options.variation
    )
    return {
        "nominal": scale.run(options.out / "runs" / f"{options.env}-nominal", options.env, "swat"),
        "variants": scale.run(
            options.out / "runs" / f"{options.env}-variants", options.env, "swat", envs=variants
        ),
    }


def conditions(options: Options) -> dict[str, EvalOptions]:
    """The evaluations of each run, by label: the bodies themselves, then held-out variants per spread."""
    held_out = {
        f"variants ±{spread:.0%}": EvalOptions(
            episodes=options.episodes,
            variants=options.episodes,
            variation=spread,
            variant_seed=options.variant_seed,
        )
        for spread in options.spreads
    }
    return {"bodies": EvalOptions(episodes=options.episodes), **held_out}


def evaluate_all(options: Options) -> list[dict[str, object]]:
    """One row per run, condition, body and seed (the seed's mean return over its episodes)."""
    rows = []
    for arm, run in runs(options).items():
        for label, evaluation in conditions(options).items():
            result = evaluate_run(run.run_dir, evaluation)
            for body in result.results:
                for index, seed in enumerate(body.seeds):
                    rows.append(
                        dict(
                            run=arm,
                            condition=label,
                            body=body.body,
                            seed=seed,
                            mean_return=float(body.returns[index].mean()),
                        )
                    )
    return rows


def summary(rows: list[dict[str, object]]) -> dict[tuple[str, str], tuple[float, float, int]]:
    """(run, condition) -> mean over seeds of each seed's mean over bodies, its standard error, seeds."""
    table = {}
    for key in dict.fromkeys((row["run"], row["condition"]) for row in rows):
        chosen = [row for row in rows if (row["run"], row["condition"]) == key]
        seeds = sorted({row["seed"] for row in chosen})
        per_seed = np.array(
            [np.mean([row["mean_return"] for row in chosen if row["seed"] == seed]) for seed in seeds]
        )
        table[key] = (float(per_seed.mean()), standard_error(per_seed), len(seeds))
    return table


def figure(table: dict[tuple[str, str], tuple[float, float, int]], title: str) -> Figure:
    """Grouped bars: a group per condition, a bar per run, mean ± standard error over seeds."""
    labels = list(dict.fromkeys(condition for _, condition in table))
    arms = list(dict.fromkeys(arm for arm, _ in table))
    figure = Figure(figsize=(7, 4))
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    width = 0.8 / len(arms)
    for index, arm in enumerate(arms):
        means = [table[(arm, label)][0] for label in labels]
        errors = [table[(arm, label)][1] for label in labels]
        positions = np.arange(len(labels)) + (index - (len(arms) - 1) / 2) * width
        axes.bar(positions, means, width, yerr=errors, capsize=4, label=f"trained on {arm}")
    axes.set_xticks(range(len(labels)), labels)
    axes.set_ylabel("return (mean over bodies)")
    axes.set_title(title)
    axes.legend()
    figure.tight_layout()
    return figure


def report(options: Options, table: dict, seconds: dict[str, float]) -> str:
    """The Markdown report: command, machine, wall clock and the numbers."""
    lines = [
        f"# SWAT on {options.env}: trained on the bodies or on variants, evaluated on held-out variants",
        "",
        f"Command: `python -m experiments.variants --env {options.env}`, "
        f"{datetime.date.today().isoformat()}, {cpu_model()} ({host_cores()} cores), {software_versions()}.",
        "",
        "| evaluated on | " + " | ".join(f"trained on {arm}" for arm in ARMS) + " |",
        "|---|" + "---|" * len(ARMS),
    ]
    for label in dict.fromkeys(condition for _, condition in table):
        cells = [f"{table[(arm, label)][0]:.1f} ± {table[(arm, label)][1]:.1f}" for arm in ARMS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Mean over bodies of each seed's mean return over {options.episodes} deterministic episodes per body "
        "(one held-out variant each), then mean ± standard error over seeds. Wall clock of training: "
        + ", ".join(f"{name} {value / 60:.1f} min" for name, value in seconds.items())
        + ".",
    ]
    return "\n".join(lines) + "\n"


def produce(options: Options) -> Path | None:
    plan = runs(options)
    if options.dry_run:
        for arm, run in plan.items():
            print(f"{arm}: python -m swat_jax.train {shlex.join(config_flags(run.config))}")
        for label, evaluation in conditions(options).items():
            print(f"evaluate each on {label}: {evaluation}")
        return None
    enable_caches()
    start = time.perf_counter()
    train_all(list(plan.values()), options.out)
    rows = evaluate_all(options)
    with (options.out / "variants.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    table = summary(rows)
    image = figure(
        table,
        f"SWAT on {options.env}, zero-shot on held-out variants ({len(rows) and table[next(iter(table))][2]} seeds)",
    )
    image.savefig(options.out / "variants.png", dpi=120)
    timings = {
        name: value
        for name, value in read_timings(options.out).items()
        if name in {r.name for r in plan.values()}
    }
    (options.out / "variants.md").write_text(report(options, table, timings))
    print(f"done in {(time.perf_counter() - start) / 60:.1f} min", file=sys.stderr)
    return options.out / "variants.md"


if __name__ == "__main__":
    sys.exit(exit_status(lambda: produce(tyro.cli(Options))))
