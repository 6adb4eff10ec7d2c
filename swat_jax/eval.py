"""Evaluate a trained policy deterministically: ``python -m swat_jax.eval RUN_DIR [--split test]``.

Every body runs ``--episodes`` episodes in parallel (one vmapped MJX program per body) from independent
resets, with the actor's actions and no exploration noise, until each episode terminates or reaches the
time limit (1000 steps). The bodies are the run's train bodies, its set's held-out test bodies
(``--split test``, zero-shot: never seen in training), or any names and MJCF paths (``--bodies``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from swat_jax.cli import ERROR_STATUS, positive_int
from swat_jax.envs.body import BodyEnv
from swat_jax.morphology import MorphologyError, get_set, load, pad_structures
from swat_jax.networks import check_structures
from swat_jax.runs.checkpoint import CheckpointError
from swat_jax.runs.config import ConfigError
from swat_jax.runs.experiment import TrainedPolicy, load_policy

SPLITS = ("train", "test", "all")


@dataclasses.dataclass(frozen=True)
class BodyEvaluation:
    """Returns and lengths of one body's evaluation episodes."""

    body: str
    returns: np.ndarray
    """[episodes] float32 undiscounted episode returns."""
    lengths: np.ndarray
    """[episodes] int32 episode lengths in environment steps."""
    qpos: np.ndarray | None = None
    """[length of episode 0 + 1, nq] joint positions of the first episode, when recorded (for videos)."""

    def summary(self) -> dict[str, float]:
        return {
            "return_mean": float(np.mean(self.returns)),
            "return_std": float(np.std(self.returns)),
            "length_mean": float(np.mean(self.lengths)),
            "length_std": float(np.std(self.lengths)),
        }


def evaluate_body(
    policy: TrainedPolicy, body: str | Path, *, episodes: int = 100, seed: int = 0, record: bool = False
) -> BodyEvaluation:
    """Run ``episodes`` deterministic episodes of ``body`` (a name or MJCF path) under ``policy``.

    Raises:
        MorphologyError: the body cannot be loaded.
        ValueError: the body does not fit the policy (observation width, traversal positions).
    """
    morphology = load(body)
    env = BodyEnv(morphology, torso_relative_x=policy.config.torso_relative_x)
    features = int(policy.info["observation_features"])
    if env.observation_features != features:
        raise ValueError(
            f"body {morphology.name} has {env.observation_features} observation features per limb, the policy "
            f"was trained on {features} (another family vocabulary); evaluate bodies of the run's families"
        )
    batch = pad_structures([morphology], reference_inorder=policy.config.reference_inorder)
    check_structures(policy.config.network(), batch)
    structure = jax.tree_util.tree_map(lambda x: jnp.asarray(x[0]), batch)
    max_steps = morphology.family.max_episode_steps

    def run(params, key: jax.Array):
        states = jax.vmap(env.reset)(jax.random.split(key, episodes))
        track = jnp.zeros((max_steps + 1, env.mj_model.nq)).at[0].set(states.data.qpos[0])
        finished = jnp.zeros(episodes, bool)
        zeros = jnp.zeros(episodes)

        def unfinished(carry) -> jax.Array:
            t, _, finished, *_ = carry
            return (t < max_steps) & ~jnp.all(finished)

        def step(carry):
            t, states, finished, returns, lengths, track = carry
            actions = policy.actor.apply(params, states.observation, structure)
            states = jax.vmap(env.step)(states, actions)
            ended = states.done & ~finished
            returns = jnp.where(ended, states.episode_return, returns)
            lengths = jnp.where(ended, states.episode_length, lengths)
            if record:
                track = track.at[t + 1].set(states.data.qpos[0])
            return t + 1, states, finished | states.done, returns, lengths, track

        *_, returns, lengths, track = jax.lax.while_loop(
            unfinished, step, (jnp.zeros((), jnp.int32), states, finished, zeros, zeros, track)
        )
        return returns, lengths, track

    returns, lengths, track = jax.jit(run)(policy.params, jax.random.PRNGKey(seed))
    lengths = np.asarray(lengths).astype(np.int32)
    qpos = np.asarray(track)[: lengths[0] + 1] if record else None
    return BodyEvaluation(morphology.name, np.asarray(returns, np.float32), lengths, qpos)


def selected_bodies(policy: TrainedPolicy, split: str, bodies: Sequence[str]) -> tuple[str, ...]:
    """``bodies`` if given, else the run's set's ``split``; ValueError for an empty split."""
    if bodies:
        return tuple(bodies)
    chosen = get_set(policy.config.env).split(split)
    if not chosen:
        raise ValueError(
            f"environment set {policy.config.env} has no {split} bodies; use --split train or name --bodies"
        )
    return chosen


def format_table(results: Sequence[BodyEvaluation], episodes: int) -> str:
    """A fixed-width table: body, mean +- std of return and of episode length."""
    width = max(len("body"), *(len(r.body) for r in results))
    lines = [f"{'body':<{width}}  {'return':>20}  {'length':>16}  (over {episodes} episodes)"]
    for result in results:
        s = result.summary()
        lines.append(
            f"{result.body:<{width}}  {s['return_mean']:>10.1f} ± {s['return_std']:<7.1f}  "
            f"{s['length_mean']:>7.1f} ± {s['length_std']:<6.1f}"
        )
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser."""
    parser = argparse.ArgumentParser(
        prog="python -m swat_jax.eval",
        description="Evaluate the newest checkpoint of a training run deterministically (no exploration "
        "noise): per body, the mean and standard deviation of the return and the episode length.",
    )
    parser.add_argument(
        "run_dir", type=Path, metavar="RUN_DIR", help="run directory written by swat_jax.train"
    )
    parser.add_argument(
        "--split",
        choices=SPLITS,
        default="train",
        help="bodies of the run's environment set: train (default), test (held-out, zero-shot) or all",
    )
    parser.add_argument(
        "--bodies",
        nargs="+",
        default=(),
        metavar="NAME_OR_PATH",
        help="evaluate these bodies (benchmark names or MJCF paths) instead of a split",
    )
    parser.add_argument("--episodes", type=positive_int, default=100, help="episodes per body (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the reset noise (default 0)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON instead of a table")
    parser.add_argument(
        "--video", type=Path, metavar="DIR", help="also write DIR/<body>.mp4 of each body's first episode"
    )
    return parser


def run(args: argparse.Namespace) -> str:
    """Evaluate (and render) per the parsed command line; returns the text to print."""
    policy = load_policy(args.run_dir)
    bodies = selected_bodies(policy, args.split, args.bodies)
    results = []
    for body in bodies:
        print(f"evaluating {Path(body).stem} ...", file=sys.stderr)
        results.append(
            evaluate_body(policy, body, episodes=args.episodes, seed=args.seed, record=bool(args.video))
        )
    if args.video:
        from swat_jax.render import render_rollout

        args.video.mkdir(parents=True, exist_ok=True)
        for body, result in zip(bodies, results, strict=True):
            path = render_rollout(body, result.qpos, args.video / f"{result.body}.mp4")
            print(f"wrote {path}", file=sys.stderr)
    if args.json:
        return json.dumps(
            {
                "run_dir": str(args.run_dir),
                "env_steps": policy.info["env_steps"],
                "episodes": args.episodes,
                "seed": args.seed,
                "bodies": {
                    r.body: {**r.summary(), "returns": r.returns.tolist(), "lengths": r.lengths.tolist()}
                    for r in results
                },
            },
            indent=2,
        )
    header = f"{args.run_dir} after {policy.info['env_steps']:,} environment steps ({policy.config.algo})"
    return header + "\n" + format_table(results, args.episodes)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad run directory, body or option)."""
    args = build_parser().parse_args(argv)
    try:
        print(run(args))
    except (ConfigError, CheckpointError, MorphologyError, ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return ERROR_STATUS
    return 0


if __name__ == "__main__":
    sys.exit(main())
