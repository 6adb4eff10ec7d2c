"""Time an exported policy file (``swat_jax.export``) against the in-process jitted actor it was made from.

Trains nothing: a paper-sized actor (``network_config(NETWORK)``, Table 1 sizes) with random parameters is
exported for every body of an environment set (train and test, padded to the set's largest body) and
read back with ``swat_jax.serving.load``. Both are then called on the set's largest body, at each batch
size, with random observations (zero on padded limbs):

- exported: ``policy(observation, structure)``, the loaded file's own call (input checks included), the
  structure fetched once with ``policy.structure(body)``;
- in-process: ``jax.jit(actor.apply)(params, observation, structure)``, the parameters passed as inputs.

Actions per second count observations answered (one action for every limb of the body per observation)
per second: batch x calls / seconds, each call waited for. The first call of each batch size compiles
and is reported separately; the rate is the median over repeats of calls for at least ``--seconds``.

    python -m experiments.benchmarks.export [--set cwhh] [--network swat] [--batches 1 16 256 4096]
        [--seconds 1] [--repeats 3]
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import numpy as np
import tyro

from experiments.machine import cpu_model
from experiments.timing import first_call_seconds
from swat_jax import export, serving
from swat_jax.compilation_cache import enable_caches
from swat_jax.envs.observation import features_per_limb
from swat_jax.morphology import get_set, load, pad_structures
from swat_jax.networks import make_actor_critic, network_config, param_count

Call = Callable[[np.ndarray], jax.Array]


def actions_per_second(call: Call, observation: np.ndarray, seconds: float, repeats: int) -> float:
    """Median over ``repeats`` of observations answered per second, calling for at least ``seconds``."""
    rates = []
    for _ in range(repeats):
        calls, start = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            jax.block_until_ready(call(observation))
            calls += 1
        rates.append(len(observation) * calls / elapsed)
    return statistics.median(rates)


def benchmark(
    set_name: str, network: str, batches: Sequence[int], seconds: float, repeats: int, folder: Path
) -> tuple[dict[str, object], list[dict[str, float]]]:
    """Export a random-parameter actor for the set and time both calls at every batch size."""
    names = get_set(set_name).split("all")
    bodies = [load(name) for name in names]
    structures = pad_structures(bodies)
    features = features_per_limb(bodies[0].family.num_limb_types)  # one vocabulary per set
    actor, _ = make_actor_critic(network_config(network), features)
    params = jax.jit(actor.init)(jax.random.key(0))
    row = int(np.argmax(structures.num_limbs))
    body_structure = jax.tree.map(lambda x: x[row], structures)

    start = time.perf_counter()
    program = export.serialize_actor(actor, params, body_structure, ("cpu",))
    path = folder / "policy.npz"
    export.write_policy(path, program, structures, [body.name for body in bodies], features, algo=network)
    export_seconds = time.perf_counter() - start
    start = time.perf_counter()
    policy = serving.load(path)
    load_seconds = time.perf_counter() - start

    structure = policy.structure(bodies[row].name)
    apply = jax.jit(actor.apply)
    calls: dict[str, Call] = {
        "exported": lambda observation: policy(observation, structure),
        "in-process": lambda observation: apply(params, observation, body_structure),
    }
    rng = np.random.default_rng(0)
    results = []
    for batch in batches:
        observation = rng.normal(size=(batch, policy.max_limbs, features)).astype(np.float32)
        observation *= body_structure.limb_mask[None, :, None]
        result: dict[str, float] = {"batch": batch}
        for name, call in calls.items():
            result[f"{name} first call"] = first_call_seconds(
                lambda call=call, observation=observation: call(observation)
            )
            result[name] = actions_per_second(call, observation, seconds, repeats)
        results.append(result)
    setup = {
        "body": bodies[row].name,
        "limbs": int(body_structure.num_limbs),
        "max_limbs": policy.max_limbs,
        "bodies": len(bodies),
        "parameters": param_count(params),
        "file MiB": path.stat().st_size / 2**20,
        "export s": export_seconds,
        "load s": load_seconds,
    }
    return setup, results


@dataclasses.dataclass(frozen=True)
class Options:
    """Time an exported policy file (swat_jax.export) against the in-process jitted actor it was made from."""

    set: str = "cwhh"
    """Environment set whose bodies the file holds."""
    network: str = "swat"
    """Network variant, any name network_config accepts."""
    batches: tuple[int, ...] = (1, 16, 256, 4096)
    """Observations per call."""
    seconds: float = 1.0
    """Least seconds of calls per measurement."""
    repeats: int = 3
    """Measurements per rate (median)."""


def main() -> None:
    enable_caches()
    args = tyro.cli(Options, prog="python -m experiments.benchmarks.export")

    with tempfile.TemporaryDirectory() as folder:
        setup, results = benchmark(
            args.set, args.network, args.batches, args.seconds, args.repeats, Path(folder)
        )
    print(
        f"CPU: {cpu_model()}; jax {jax.__version__} on {jax.devices()[0].platform}; {args.network} "
        f"({setup['parameters']:,} parameters), random init; file of {setup['bodies']} {args.set} bodies, "
        f"max limbs {setup['max_limbs']}, {setup['file MiB']:.1f} MiB, export {setup['export s']:.1f} s, "
        f"load {setup['load s']:.2f} s; called on {setup['body']} ({setup['limbs']} limbs); "
        f"median of {args.repeats} x >= {args.seconds:g} s"
    )
    print(
        "| batch | first call exported / in-process (s) | exported actions/s | in-process actions/s "
        "| exported / in-process |"
    )
    print("|---|---|---|---|---|")
    for result in results:
        print(
            f"| {result['batch']} | {result['exported first call']:.2f} / {result['in-process first call']:.2f} "
            f"| {result['exported']:,.0f} | {result['in-process']:,.0f} "
            f"| {result['exported'] / result['in-process']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
