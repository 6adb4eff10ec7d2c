"""Specialists beside the generalist: one Brax MLP policy per body against one swat_jax policy over the set.

For each train body of ``--env`` and each of ``--seeds`` seeds, trains a specialist with Brax's own SAC or
PPO (``brax.training.agents``, Brax's default MLPs) on the body as a MuJoCo Playground environment
(:mod:`swat_jax.adapters.playground`, MuJoCo C, the ``fast`` preset's observation switches) at two budgets
of environment steps per body: the per-body share of the generalist run's budget (its steps over its
bodies, or ``--share-steps``) and ``--learn-steps``, a budget at which the specialist learns. Each
specialist is evaluated as ``python -m swat_jax.eval`` evaluates a run: deterministic actions,
``--episodes`` episodes per body from the reset noise, each until it terminates or reaches the 1000-step
limit. The generalist (``--swat-run``, a run directory of ``swat_jax.train`` with its checkpoints) is
evaluated by ``swat_jax.eval`` itself, every seed.

Writes under ``--out``: ``<env>-<algo>.json`` (every specialist: body, seed, budget, returns, lengths and
training seconds; written after each, so an interrupted command goes on where it stopped),
``<env>-swat.json`` (the generalist's evaluation, its run's path and wall clock), and ``<env>-<algo>.md`` and
``<env>-<algo>.png``: per body, the generalist's return and each budget's specialists, mean ± standard
error over seeds, with the training wall clock of each side. ``python -m experiments.tables`` writes the
table of the committed sets into BENCHMARKS.md (:func:`table_lines`).

    python -m experiments.specialists --env hopper --algo sac --swat-run RUN_DIR [--seeds 4] [--out DIR]
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from experiments.machine import cpu_model, host_cores
from swat_jax.morphology import get_set
from swat_jax.runs.config import CONFIG_FILE, load_config

ROOT = Path(__file__).resolve().parents[1]
"""The repository: a generalist run inside it is recorded by its path from here."""


@dataclasses.dataclass(frozen=True)
class SpecialistsCommand:
    """Train one Brax policy per body of a set; report them body by body beside a swat_jax run."""

    env: str = "hopper"
    """The environment set: its train bodies get a specialist each."""
    algo: Literal["sac", "ppo"] = "sac"
    """Brax's trainer of the specialists."""
    swat_run: Path | None = None
    """The generalist: a swat_jax.train run directory of the set with its checkpoints (None: no generalist;
    then --share-steps is needed)."""
    seeds: int = 4
    """Specialists per body and budget, seeds 0 to N - 1."""
    share_steps: int | None = None
    """The first budget, environment steps per body (None: the generalist's steps over its bodies)."""
    learn_steps: int = 40_000
    """The second budget, environment steps per body: one at which the specialists learn."""
    episodes: int = 10
    """Deterministic evaluation episodes per specialist (and per seed of the generalist)."""
    out: Path = Path("experiments/results/specialists")
    """Where the JSON, the table and the figure go."""


SAC_SETTINGS = dict(
    num_envs=16,
    batch_size=256,
    grad_updates_per_step=8,
    learning_rate=1e-3,
    discounting=0.99,
    reward_scaling=1.0,
    num_evals=2,
    num_eval_envs=2,
)
"""Brax SAC's settings (besides the budget, and 1,000 random steps first, or a quarter of a smaller budget):
16 environments, an update per 2 environment steps, batches of 256, Brax's default 256 x 256 MLPs
(hopper_3 reached a return of about 750 at 20,000 steps)."""
PPO_SETTINGS = dict(
    num_envs=32,
    batch_size=64,
    num_minibatches=8,
    unroll_length=20,
    num_updates_per_batch=4,
    learning_rate=3e-4,
    entropy_cost=1e-3,
    discounting=0.99,
    num_evals=2,
    num_eval_envs=2,
)
"""Brax PPO's settings (besides the budget), with Brax's default networks."""


def train_specialist(body: str, algo: str, steps: int, seed: int) -> tuple[Any, float]:
    """A deterministic Brax policy of ``body`` after ``steps`` environment steps, and the training's wall
    seconds (compilation included)."""
    from brax.training.agents.ppo import train as ppo
    from brax.training.agents.sac import train as sac
    from mujoco_playground import wrapper

    from swat_jax.adapters.playground import PlaygroundBody, restore_device_put_replicated

    restore_device_put_replicated()
    env = PlaygroundBody(body, physics="c")
    settings = dict(
        environment=env,
        num_timesteps=steps,
        episode_length=env.body.morphology.family.max_episode_steps,
        wrap_env_fn=wrapper.wrap_for_brax_training,
        seed=seed,
    )
    start = time.perf_counter()
    if algo == "sac":
        random_steps = min(1000, steps // 4)
        make_policy, params, _ = sac.train(
            **settings, **SAC_SETTINGS, min_replay_size=random_steps, max_replay_size=steps
        )
    else:
        make_policy, params, _ = ppo.train(**settings, **PPO_SETTINGS)
    seconds = time.perf_counter() - start
    return make_policy(params, deterministic=True), seconds


def evaluate(body: str, policy: Any, episodes: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """[episodes] returns and lengths of ``policy`` on ``body`` (MuJoCo C), each episode from the reset noise
    until its first termination or the time limit, as swat_jax.eval scores them."""
    from swat_jax.adapters.playground import PlaygroundBody

    env = PlaygroundBody(body, physics="c")
    limit = env.body.morphology.family.max_episode_steps

    def step(carry, key):
        states, returns, lengths, alive = carry
        actions, _ = policy(states.obs, key)
        states = jax.vmap(env.step)(states, actions)
        returns = returns + jnp.where(alive, states.reward, 0.0)
        lengths = lengths + alive.astype(jnp.int32)
        return (states, returns, lengths, alive & (states.done == 0)), None

    @jax.jit
    def run(key):
        reset_key, action_key = jax.random.split(key)
        states = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))
        zeros = jnp.zeros(episodes)
        carry = (states, zeros, zeros.astype(jnp.int32), jnp.ones(episodes, bool))
        (_, returns, lengths, _), _ = jax.lax.scan(step, carry, jax.random.split(action_key, limit))
        return returns, lengths

    returns, lengths = run(jax.random.key(seed))
    return np.asarray(returns), np.asarray(lengths)


def budgets(command: SpecialistsCommand) -> list[int]:
    """The two budgets per body: the generalist's share (or --share-steps), then --learn-steps."""
    if command.share_steps is not None:
        return [command.share_steps, command.learn_steps]
    if command.swat_run is None:
        raise SystemExit("give --swat-run (the generalist) or --share-steps")
    config = load_config(command.swat_run / CONFIG_FILE)
    return [config.steps // len(config.training_bodies()), command.learn_steps]


def file_stem(env: str) -> str:
    """What the files of set ``env`` are named by: the set's name, or a folder set's folder name."""
    return Path(env).name


def read_entries(path: Path) -> list[dict]:
    return json.loads(path.read_text()) if path.is_file() else []


def train_all(command: SpecialistsCommand, bodies: list[str]) -> list[dict]:
    """Every specialist of the command, those of an earlier, interrupted call kept; each recorded under its
    body's name (a folder set's bodies are MJCF paths)."""
    path = command.out / f"{file_stem(command.env)}-{command.algo}.json"
    entries = read_entries(path)
    done = {(entry["budget"], entry["body"], entry["seed"]) for entry in entries}
    for budget in budgets(command):
        for body in bodies:
            for seed in range(command.seeds):
                if (budget, Path(body).stem, seed) in done:
                    continue
                policy, seconds = train_specialist(body, command.algo, budget, seed)
                returns, lengths = evaluate(body, policy, command.episodes)
                entries.append(
                    dict(
                        body=Path(body).stem,
                        seed=seed,
                        budget=budget,
                        train_seconds=seconds,
                        returns=returns.tolist(),
                        lengths=lengths.tolist(),
                    )
                )
                path.write_text(json.dumps(entries, indent=1))
                print(
                    f"{Path(body).stem} seed {seed} at {budget:,}: {returns.mean():.1f} in {seconds:.0f} s",
                    flush=True,
                )
    return entries


def evaluate_generalist(command: SpecialistsCommand) -> dict | None:
    """The generalist run's evaluation (swat_jax.eval's JSON, every seed) and wall seconds, kept from an
    earlier call; None without a run."""
    if command.swat_run is None:
        return None
    path = command.out / f"{file_stem(command.env)}-swat.json"
    if not path.is_file():
        output = subprocess.run(
            [
                sys.executable,
                "-m",
                "swat_jax.eval",
                str(command.swat_run),
                "--json",
                "--episodes",
                f"{command.episodes}",
            ],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        run = command.swat_run.resolve()
        record = {
            "run": str(run.relative_to(ROOT) if run.is_relative_to(ROOT) else run),
            "wall_seconds": generalist_seconds(run),
            "evaluation": json.loads(output),
        }
        path.write_text(json.dumps(record, indent=1))
    return json.loads(path.read_text())


def generalist_seconds(run_dir: Path) -> float | None:
    """The generalist run's wall seconds, from the ``timings.json`` of the results folder that holds it."""
    timings = run_dir.parent.parent / "timings.json"
    if not timings.is_file():
        return None
    return json.loads(timings.read_text()).get(run_dir.name)


def mean_se(values: list[float]) -> tuple[float, float]:
    """Mean and standard error (sample standard deviation over sqrt(n); 0 for one value)."""
    values = np.asarray(values, float)
    se = values.std(ddof=1) / np.sqrt(len(values)) if len(values) > 1 else 0.0
    return float(values.mean()), float(se)


@dataclasses.dataclass(frozen=True)
class SetResult:
    """One set's committed results, summarised: per body, each side's (mean, standard error) over seeds of
    each seed's mean return."""

    env: str
    algo: str
    budgets: tuple[int, ...]
    """Specialists' budgets, environment steps per body: the generalist's share, then the learning budget."""
    rows: dict[str, dict[Any, tuple[float, float]]]
    """Per body: ``"swat"`` (the generalist) and each budget."""
    seconds: dict[Any, float | None]
    """Training wall seconds: ``"swat"`` the generalist run's (all its seeds and bodies), each budget the sum
    over its specialists."""
    runs: dict[int, int]
    """Specialists trained at each budget."""
    seeds: int


def read_results(out: Path, env: str, algo: str) -> SetResult:
    """The results :func:`main` wrote under ``out`` for ``env`` and ``algo``."""
    entries = read_entries(out / f"{file_stem(env)}-{algo}.json")
    swat_path = out / f"{file_stem(env)}-swat.json"
    generalist = json.loads(swat_path.read_text()) if swat_path.is_file() else None
    budgets = tuple(sorted({entry["budget"] for entry in entries}))
    rows: dict[str, dict] = {}
    for body in dict.fromkeys(entry["body"] for entry in entries):
        row: dict[Any, tuple[float, float]] = {}
        if generalist is not None:
            per_seed = generalist["evaluation"]["bodies"][body]["per_seed"].values()
            row["swat"] = mean_se([seed["return_mean"] for seed in per_seed])
        for budget in budgets:
            row[budget] = mean_se(
                [np.mean(e["returns"]) for e in entries if e["body"] == body and e["budget"] == budget]
            )
        rows[body] = row
    seconds = {
        budget: sum(e["train_seconds"] for e in entries if e["budget"] == budget) for budget in budgets
    }
    return SetResult(
        env=env,
        algo=algo,
        budgets=budgets,
        rows=rows,
        seconds={"swat": None if generalist is None else generalist["wall_seconds"], **seconds},
        runs={budget: sum(e["budget"] == budget for e in entries) for budget in budgets},
        seeds=len({entry["seed"] for entry in entries}),
    )


TABLE_HEADER = (
    "| set | body | swat_jax, one policy for the set | specialists at the generalist's share of steps | "
    "specialists at the learning budget |"
)


def table_lines(results: list[SetResult]) -> list[str]:
    """One Markdown table of every set's results: a row per body, then the set's training wall clock."""
    lines = [TABLE_HEADER, "|---|---|---|---|---|"]
    for result in results:
        share, learn = result.budgets
        name = f"{get_set(result.env).title} ({result.algo.upper()}: {share:,} / {learn:,} steps a body)"
        for body, row in result.rows.items():
            cells = [
                f"{row[key][0]:.1f} ± {row[key][1]:.1f}" if key in row else ""
                for key in ("swat", share, learn)
            ]
            lines.append(f"| {name} | {body} | " + " | ".join(cells) + " |")
        swat = result.seconds["swat"]
        clocks = ["" if swat is None else f"{swat:.0f} s (one run, {result.seeds} seeds)"] + [
            f"{result.seconds[budget]:.0f} s ({result.runs[budget]} runs)" for budget in (share, learn)
        ]
        lines.append(f"| {name} | wall clock of training | " + " | ".join(clocks) + " |")
    return lines


def figure(result: SetResult, path: Path) -> None:
    """Bars per body: the generalist and each budget's specialists, with their standard errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ["swat", *result.budgets] if "swat" in next(iter(result.rows.values())) else list(result.budgets)
    width = 0.8 / len(keys)
    fig, axis = plt.subplots(figsize=(1.6 + 1.3 * len(result.rows), 3.6))
    for index, key in enumerate(keys):
        means, errors = zip(*(row[key] for row in result.rows.values()), strict=True)
        label = (
            "swat_jax, one policy" if key == "swat" else f"{result.algo.upper()} specialists, {key:,} steps"
        )
        axis.bar(
            np.arange(len(result.rows)) + index * width, means, width, yerr=errors, label=label, capsize=3
        )
    axis.set_xticks(np.arange(len(result.rows)) + width * (len(keys) - 1) / 2, list(result.rows), rotation=20)
    axis.set_ylabel(f"return (mean ± s.e. over {result.seeds} seeds)")
    axis.set_title(get_set(result.env).title)
    axis.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    command = tyro.cli(SpecialistsCommand, args=argv, prog="python -m experiments.specialists")
    command.out.mkdir(parents=True, exist_ok=True)
    train_all(command, list(get_set(command.env).train))
    evaluate_generalist(command)
    result = read_results(command.out, command.env, command.algo)
    stem = f"{file_stem(command.env)}-{command.algo}"
    figure(result, command.out / f"{stem}.png")
    note = (
        f'\n"±" is the standard error over seeds of each seed\'s mean return ({command.episodes} deterministic '
        f"episodes per body). Machine: {cpu_model()}, {host_cores()} cores.\n"
    )
    markdown = "\n".join(table_lines([result])) + "\n" + note
    (command.out / f"{stem}.md").write_text(markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
