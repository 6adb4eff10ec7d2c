"""Evaluate a trained policy deterministically: ``python -m swat_jax.eval RUN_DIR [--split test]``.

Every body runs ``--episodes`` episodes in parallel for every seed of the run (one MJX program per body,
vmapped over seeds and episodes) from independent resets, with the actor's actions and no exploration
noise, until each episode terminates or reaches the time limit (1000 steps). The bodies are the run's
train bodies, its set's held-out test bodies (``--split test``, zero-shot: never seen in training), or
any names and MJCF paths (``--bodies``). Several seeds are summarised as the mean and standard error
over seeds of each seed's mean return (the paper's Tables 3-4).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from swat_jax.cli import run_command, strict_json
from swat_jax.compilation_cache import compile_cached, enable_caches
from swat_jax.morphology import MorphologyError, get_set
from swat_jax.morphology.variants import Variation
from swat_jax.runs import programs
from swat_jax.runs.checkpoint import CheckpointError
from swat_jax.runs.config import Split, require_positive
from swat_jax.runs.experiment import make_env
from swat_jax.runs.metrics import standard_error
from swat_jax.runs.trained import TrainedPolicy, load_policy
from swat_jax.td3.evaluation import make_evaluation


@dataclasses.dataclass(frozen=True)
class BodyEvaluation:
    """Returns and lengths of one body's evaluation episodes, for each evaluated seed of the run."""

    body: str
    seeds: tuple[int, ...]
    """The seed of each row of ``returns`` and ``lengths``."""
    returns: np.ndarray
    """[seeds, episodes] float32 undiscounted episode returns."""
    lengths: np.ndarray
    """[seeds, episodes] int32 episode lengths in environment steps."""
    qpos: np.ndarray | None = None
    """[length of episode 0, nq] joint positions of the first seed's first episode, when recorded."""
    targets: np.ndarray | None = None
    """[length of episode 0, 2] a 3D body's target at each of those poses, when recorded."""

    def seed_summary(self, index: int) -> dict[str, float]:
        """Mean and standard deviation over episodes of one seed's returns and lengths."""
        return {
            "return_mean": float(np.mean(self.returns[index])),
            "return_std": float(np.std(self.returns[index])),
            "length_mean": float(np.mean(self.lengths[index])),
            "length_std": float(np.std(self.lengths[index])),
        }

    def summary(self) -> dict[str, float]:
        """Over seeds: the mean and standard error of the seeds' mean returns and lengths (the error is NaN
        for one seed), and the mean and standard deviation over every episode of every seed."""
        seed_returns = np.mean(self.returns, axis=1, dtype=np.float64)
        seed_lengths = np.mean(self.lengths, axis=1, dtype=np.float64)
        return {
            "return_mean": float(np.mean(seed_returns)),
            "return_se": standard_error(seed_returns),
            "return_std": float(np.std(self.returns)),
            "length_mean": float(np.mean(seed_lengths)),
            "length_se": standard_error(seed_lengths),
            "length_std": float(np.std(self.lengths)),
        }


def evaluate(
    policy: TrainedPolicy,
    bodies: Sequence[str | Path],
    *,
    episodes: int = 100,
    seed: int = 0,
    record: bool = False,
    seed_indices: Sequence[int] | None = None,
    variants: int = 0,
    variation: Variation | None = None,
) -> list[BodyEvaluation]:
    """Run ``episodes`` deterministic episodes of every body (names or MJCF paths) under each chosen seed's
    actor (``seed_indices`` into the run's seeds; default every seed), all in one program
    (:func:`swat_jax.td3.evaluation.make_evaluation`). Every seed meets the same initial states, drawn
    from ``seed``. With ``variants`` K, episode j of a body runs its variant j mod K drawn by ``variation``
    (:mod:`swat_jax.morphology.variants`; held-out variants: another seed than training's).

    Raises:
        MorphologyError: a body cannot be loaded.
        ValueError: a body does not fit the policy (observation width, traversal positions), or a seed
            index is out of range.
    """
    tasks = policy.task_set(bodies)
    indices = tuple(range(len(policy.seeds)) if seed_indices is None else seed_indices)
    if variants > episodes:
        raise ValueError(
            f"--variants {variants} is more than --episodes {episodes}: each episode runs one variant"
        )
    env = make_env(
        policy.config, tasks.bodies, episodes, len(indices), variants=variants, variation=variation
    )
    params = jax.tree_util.tree_map(
        lambda *leaves: jnp.stack(leaves), *(policy.seed_params(index) for index in indices)
    )
    key = jax.random.PRNGKey(seed)
    evaluation = compile_cached(
        "evaluation",
        lambda: jax.jit(make_evaluation(env, tasks.structure, policy.actor, record=record)),
        (params, key),
        programs.recipe(policy.config, env, record),
    )
    result = jax.device_get(evaluation(params, key))
    seeds = tuple(policy.seeds[index] for index in indices)
    evaluations = []
    for k, name in enumerate(env.body_names):
        lengths = np.asarray(result.lengths[:, k], np.int32)
        qpos = np.asarray(result.qpos[k])[: lengths[0, 0]] if record else None
        targets = (
            np.asarray(result.targets[k])[: lengths[0, 0]] if record and result.targets[k].size else None
        )
        evaluations.append(
            BodyEvaluation(name, seeds, np.asarray(result.returns[:, k], np.float32), lengths, qpos, targets)
        )
    return evaluations


def selected_bodies(policy: TrainedPolicy, split: str, bodies: Sequence[str]) -> tuple[str, ...]:
    """``bodies`` if given; else for ``train`` the bodies the run trained on, for ``test`` its set's
    held-out bodies, for ``all`` both (without repeats); ValueError for an empty split."""
    if bodies:
        return tuple(bodies)
    trained = policy.config.training_bodies()
    held_out = get_set(policy.config.env).split("test")
    chosen = {"train": trained, "test": held_out, "all": tuple(dict.fromkeys(trained + held_out))}[split]
    if not chosen:
        raise ValueError(
            f"environment set {policy.config.env} has no {split} bodies; use --split train or name --bodies"
        )
    return chosen


def format_table(results: Sequence[BodyEvaluation], episodes: int) -> str:
    """A fixed-width table per body: for one seed the mean ± standard deviation over episodes of return
    and length; for several, the mean ± standard error over seeds of each seed's mean, and those means."""
    width = max(len("body"), *(len(r.body) for r in results))
    seeds = results[0].seeds
    if len(seeds) == 1:
        spread, columns = "std", ""
    else:
        spread, columns = "s.e.", "  " + "  ".join(f"{f'seed {seed}':>9}" for seed in seeds)
    over = f"over {episodes} episodes" + (f" x {len(seeds)} seeds" if len(seeds) > 1 else "")
    lines = [f"{'body':<{width}}  {f'return ± {spread}':>20}  {f'length ± {spread}':>16}{columns}  ({over})"]
    for result in results:
        s = result.summary()
        error = "std" if len(seeds) == 1 else "se"
        per_seed = "".join(
            f"  {result.seed_summary(index)['return_mean']:>9.1f}" for index in range(len(seeds))
        )
        lines.append(
            f"{result.body:<{width}}  {s['return_mean']:>10.1f} ± {s[f'return_{error}']:<7.1f}  "
            f"{s['length_mean']:>7.1f} ± {s[f'length_{error}']:<6.1f}{per_seed if len(seeds) > 1 else ''}"
        )
    return "\n".join(lines)


def json_report(results: Sequence[BodyEvaluation]) -> dict[str, Any]:
    """Per body: the summary over seeds, and per seed its summary, returns and lengths."""
    return {
        r.body: {
            **r.summary(),
            "per_seed": {
                str(seed): {
                    **r.seed_summary(index),
                    "returns": r.returns[index].tolist(),
                    "lengths": r.lengths[index].tolist(),
                }
                for index, seed in enumerate(r.seeds)
            },
        }
        for r in results
    }


@dataclasses.dataclass(frozen=True)
class EvalOptions:
    """What to evaluate in a run (``evaluate_run``'s argument; the command line's options)."""

    split: Split = "train"
    """train: the bodies the run trained on; test: its environment set's held-out bodies (zero-shot); all:
    both."""
    bodies: tuple[str, ...] = ()
    """Evaluate these bodies (benchmark names or MJCF paths) instead of a split."""
    episodes: int = 100
    """Episodes per body, per seed."""
    seed: int = 0
    """Seed of the reset noise."""
    seed_index: int | None = None
    """Evaluate only the K-th seed of a multi-seed run (an index into its seeds); None: every seed,
    summarised as the mean ± standard error over seeds."""
    video: Path | None = None
    """Also write VIDEO/<body>.mp4 of each body's first episode (a folder)."""
    variants: int = 0
    """Evaluate on K variants of each body (episode j runs variant j mod K; at most --episodes); 0: the bodies themselves."""
    variation: float = 0.2
    """With --variants: spread of the variants' factors, each uniform in [1 - variation, 1 + variation]."""
    variant_seed: int = 1
    """With --variants: seed of the draw; a training run with --envs.variants drew its own with --envs.variant-seed (default 0), so the default 1 gives held-out variants."""

    def variant_draw(self) -> Variation:
        """How the evaluated variants are drawn (--variation, --variant-seed); ValueError for a bad spread."""
        return Variation(self.variation, self.variant_seed)

    def __post_init__(self) -> None:
        require_positive("--episodes", self.episodes)
        self.variant_draw()
        if self.variants < 0:
            raise ValueError(f"--variants must be 0 (off) or more, got {self.variants}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvalCommand(EvalOptions):
    """Evaluate the newest checkpoint of a training run deterministically (no exploration noise): per body,
    the mean and standard deviation of the return and the episode length; for a multi-seed run, every seed
    and the mean and standard error over seeds."""

    run_dirs: tyro.conf.Positional[tuple[Path, ...]]
    """Run directories written by swat_jax.train (several: one table, or one --markdown column, each)."""
    json: bool = False
    """Print the results as JSON instead of a table."""
    markdown: bool = False
    """Print one Markdown table, a row per body and a column per run: the mean ± standard error over seeds
    of each seed's mean return (the paper's Tables 3-4)."""

    def check(self) -> None:
        """ValueError for options that contradict each other or a missing RUN_DIR."""
        if not self.run_dirs:
            raise ValueError("give at least one RUN_DIR (a folder written by python -m swat_jax.train)")
        if self.json and self.markdown:
            raise ValueError("--json and --markdown are two formats of one output; choose one")
        if self.video and self.variants:
            raise ValueError("--video draws the bodies themselves; evaluate --variants without --video")
        if self.video and len(self.run_dirs) > 1:
            raise ValueError("--video takes one RUN_DIR; evaluate the runs one at a time to record them")

    def options(self) -> EvalOptions:
        """The evaluation options alone."""
        return EvalOptions(
            **{field.name: getattr(self, field.name) for field in dataclasses.fields(EvalOptions)}
        )


@dataclasses.dataclass(frozen=True)
class RunEvaluation:
    """One run directory's policy and its evaluation per body."""

    run_dir: Path
    policy: TrainedPolicy
    results: list[BodyEvaluation]

    def label(self) -> str:
        return self.policy.config.algo


def evaluate_run(run_dir: str | Path, options: EvalOptions = EvalOptions()) -> RunEvaluation:
    """Evaluate the newest checkpoint of ``run_dir`` deterministically, as ``options`` say."""
    run_dir = Path(run_dir)
    policy = load_policy(run_dir)
    bodies = selected_bodies(policy, options.split, options.bodies)
    print(f"{run_dir}: evaluating {', '.join(Path(body).stem for body in bodies)} ...", file=sys.stderr)
    results = evaluate(
        policy,
        bodies,
        episodes=options.episodes,
        seed=options.seed,
        record=options.video is not None,
        seed_indices=None if options.seed_index is None else [options.seed_index],
        variants=options.variants,
        variation=options.variant_draw(),
    )
    if options.video is not None:
        from swat_jax.render import render_rollout

        options.video.mkdir(parents=True, exist_ok=True)
        for body, result in zip(bodies, results, strict=True):
            path = render_rollout(
                body, result.qpos, options.video / f"{result.body}.mp4", targets=result.targets
            )
            print(f"wrote {path}", file=sys.stderr)
    return RunEvaluation(run_dir, policy, results)


def markdown_table(runs: Sequence[RunEvaluation], episodes: int) -> str:
    """A Markdown table, a row per body (in order of first appearance) and a column per run: mean ± standard
    error over seeds of each seed's mean return ("mean" alone for one seed; "-" where a run has no such
    body). Columns are labelled by algorithm, or by run directory where algorithms repeat."""
    labels = [run.label() for run in runs]
    if len(set(labels)) < len(labels):
        labels = [run.run_dir.name for run in runs]
    bodies = list(dict.fromkeys(result.body for run in runs for result in run.results))
    lines = ["| body | " + " | ".join(labels) + " |", "|---|" + "---|" * len(runs)]
    for body in bodies:
        cells = []
        for run in runs:
            found = [result for result in run.results if result.body == body]
            if not found:
                cells.append("-")
                continue
            summary = found[0].summary()
            spread = "" if math.isnan(summary["return_se"]) else f" ± {summary['return_se']:.1f}"
            cells.append(f"{summary['return_mean']:.1f}{spread}")
        lines.append(f"| {body} | " + " | ".join(cells) + " |")
    seeds = sorted({len(run.results[0].seeds) for run in runs})
    lines.append("")
    lines.append(
        f"Mean ± standard error over {'/'.join(map(str, seeds))} seeds of each seed's mean return over "
        f"{episodes} deterministic episodes."
    )
    return "\n".join(lines)


def json_run(run: RunEvaluation, options: EvalOptions) -> dict[str, Any]:
    """The ``--json`` object of one run."""
    return {
        "run_dir": str(run.run_dir),
        "algo": run.policy.config.algo,
        "env_steps": run.policy.info.env_steps,
        "episodes": options.episodes,
        "seed": options.seed,
        "seeds": list(run.results[0].seeds),
        "variants": (
            {"count": options.variants, "variation": options.variation, "seed": options.variant_seed}
            if options.variants
            else None
        ),
        "bodies": json_report(run.results),
    }


def run(command: EvalCommand) -> str:
    """Evaluate (and render) as the command says; returns the text to print."""
    command.check()
    options = command.options()
    runs = [evaluate_run(run_dir, options) for run_dir in command.run_dirs]
    if command.markdown:
        return markdown_table(runs, options.episodes)
    if command.json:
        reports = [json_run(run, options) for run in runs]
        return strict_json(reports[0] if len(reports) == 1 else {"runs": reports}, indent=2)
    return "\n\n".join(
        f"{run.run_dir} after {run.policy.info.env_steps:,} environment steps ({run.policy.config.algo})\n"
        + format_table(run.results, options.episodes)
        for run in runs
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad run directory, body or option)."""
    enable_caches()
    return run_command(
        EvalCommand,
        run,
        argv,
        (CheckpointError, MorphologyError, ValueError, OSError),
        prog="python -m swat_jax.eval",
    )


if __name__ == "__main__":
    sys.exit(main())
