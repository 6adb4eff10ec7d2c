"""Learning on a 3D set: SWAT, AMORPHEUS, SMP and SET with one preset, beside the random-action return.

Trains each algorithm on the set (``--seeds`` seeds in one program, one run directory each; a run
directory that exists is resumed, or left as it is when it has finished, whatever budget it was started
with), measures the random-action return of every body (uniform actions in [-1, 1],
``--random-episodes`` episodes per body on MuJoCo C), and writes under ``--out``: the runs, the curves
(``curves.png``, mean over the set's bodies, a band of ± standard error over seeds), and ``RESULTS.md``
with each run's curve point at the smallest budget of the runs and at its own last point, beside the
random return, per body and over the set.

    python -m experiments.three_d [--env 3d_hopper] [--steps 40000] [--seeds 4] [--out DIR]
"""

from __future__ import annotations

import csv
import dataclasses
import json
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from experiments.machine import cpu_model, host_cores
from swat_jax.envs import BodyEnv
from swat_jax.morphology import get_set

ALGORITHMS = ("swat", "amorpheus", "smp", "set")


@dataclasses.dataclass(frozen=True)
class ThreeDCommand:
    """Train SWAT, AMORPHEUS, SMP and SET on a 3D set with one preset; report them beside random actions."""

    env: str = "3d_hopper"
    """The environment set."""
    preset: str = "fast"
    """The training preset of every run."""
    steps: int = 40_000
    """Environment steps of each run, summed over the set's bodies."""
    seeds: int = 4
    """Seeds of each run, trained in one program."""
    algorithms: tuple[str, ...] = ALGORITHMS
    """The networks to train."""
    random_episodes: int = 32
    """Episodes per body that measure the random-action return."""
    out: Path = Path("experiments/results/three_d")
    """Where the runs, the figure and RESULTS.md go."""


def random_returns(body: str, episodes: int, seed: int = 0) -> np.ndarray:
    """[episodes] returns of uniform random actions from reset until the episode ends (MuJoCo C)."""
    env = BodyEnv(body, physics="c")
    limit = env.morphology.family.max_episode_steps

    def episode(key: jax.Array) -> jax.Array:
        reset_key, action_key = jax.random.split(key)

        def step(carry, action_key):
            state, total, over = carry
            action = jax.random.uniform(action_key, env.action_shape, minval=-1.0, maxval=1.0)
            state = env.step(state, action)
            total = total + jnp.where(over, 0.0, state.reward)
            return (state, total, over | state.done), None

        start = (env.reset(reset_key), jnp.zeros(()), jnp.zeros((), bool))
        (_, total, _), _ = jax.lax.scan(step, start, jax.random.split(action_key, limit))
        return total

    return np.asarray(jax.jit(jax.vmap(episode))(jax.random.split(jax.random.key(seed), episodes)))


def curve_point(
    run_dir: Path, bodies: Sequence[str], budget: int | None = None
) -> dict[str, tuple[float, float]]:
    """Per body and "set" (the mean over bodies): mean and std over seeds of the curve point at the
    largest step not beyond ``budget`` (None: the last point)."""
    with open(run_dir / "metrics.csv") as file:
        rows = list(csv.DictReader(file))
    steps = [int(row["env_steps"]) for row in rows]
    chosen = max(step for step in steps if budget is None or step <= budget)
    final = [row for row, step in zip(rows, steps, strict=True) if step == chosen]
    per_seed = {body: [float(row[f"return/{body}"] or "nan") for row in final] for body in bodies}
    per_seed["set"] = list(np.nanmean([per_seed[body] for body in bodies], axis=0))
    return {key: (float(np.nanmean(values)), float(np.nanstd(values))) for key, values in per_seed.items()}


def train(command: ThreeDCommand, algorithm: str) -> Path:
    """Train (or resume, or leave a finished) run of ``algorithm``; its run directory."""
    run_dir = command.out / "runs" / algorithm
    arguments = [sys.executable, "-m", "swat_jax.train"]
    if (run_dir / "config.json").exists():
        arguments += ["--resume", str(run_dir)]  # a finished run stops at once
    else:
        arguments += [
            "--preset", command.preset, "--env", command.env, "--algo", algorithm,
            "--seeds", str(command.seeds), "--steps", str(command.steps), "--run-dir", str(run_dir),
        ]  # fmt: skip
    subprocess.run(arguments, check=True)
    return run_dir


def run_budget(run_dir: Path) -> tuple[int, int]:
    """(seeds, steps) a run directory was trained with (its config.json)."""
    config = json.loads((run_dir / "config.json").read_text())
    return int(config["seeds"]), int(config["steps"])


def report(command: ThreeDCommand, runs: dict[str, Path], random: dict[str, np.ndarray]) -> str:
    """RESULTS.md: each run's curve point at the smallest budget of the runs and at its last point, beside
    the random-action return."""
    bodies = get_set(command.env).train
    budgets = {algorithm: run_budget(run_dir) for algorithm, run_dir in runs.items()}
    common = min(steps for _, steps in budgets.values())
    columns = {f"{a} at {common:,}": curve_point(run_dir, bodies, common) for a, run_dir in runs.items()}
    columns |= {
        f"{a} at {steps:,}": curve_point(run_dir, bodies)
        for a, run_dir in runs.items()
        if (steps := budgets[a][1]) > common
    }
    random_set = float(np.mean([random[body].mean() for body in bodies]))
    runs_text = "; ".join(f"{a}: {seeds} seeds, {steps:,} steps" for a, (seeds, steps) in budgets.items())
    lines = [
        f"# Learning on {get_set(command.env).title}: {', '.join(runs)} with the `{command.preset}` preset",
        "",
        f"`python -m experiments.three_d --env {command.env}` on {cpu_model()} ({host_cores()} cores), MuJoCo"
        f" C physics; each run's seeds in one program, its environment steps summed over the bodies ({runs_text})."
        " Cells: the last curve point (the training episodes' mean return over a metrics interval) not"
        " beyond the step named, mean ± std over seeds; random actions: uniform in [-1, 1],"
        f" {command.random_episodes} episodes per body, mean ± std.",
        "",
        "![curves](curves.png)",
        "",
        "| body | random actions | " + " | ".join(columns) + " |",
        "|" + "---|" * (2 + len(columns)),
    ]
    for body in (*bodies, "set"):
        chance = (
            f"{random_set:.1f}" if body == "set" else f"{random[body].mean():.1f} ± {random[body].std():.1f}"
        )
        cells = " | ".join(f"{column[body][0]:.1f} ± {column[body][1]:.1f}" for column in columns.values())
        lines.append(f"| {body if body != 'set' else '**mean over the bodies**'} | {chance} | {cells} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    command = tyro.cli(ThreeDCommand, args=argv, prog="python -m experiments.three_d")
    runs = {algorithm: train(command, algorithm) for algorithm in command.algorithms}
    random = {body: random_returns(body, command.random_episodes) for body in get_set(command.env).train}
    subprocess.run(
        [
            sys.executable,
            "-m",
            "swat_jax.plot",
            "curves",
            *map(str, runs.values()),
            "-o",
            str(command.out / "curves.png"),
        ],
        check=True,
    )
    (command.out / "RESULTS.md").write_text(report(command, runs, random))
    print((command.out / "RESULTS.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
