"""Run by tests/test_sharding.py in a process with 4 fake CPU devices: train a run over a 2 x 2 mesh and its
unsharded twin, resume each on the other layout, then evaluate and export the sharded one. The copies of
each body run two variants of it (--variants 2), whose rows are split over the mesh with the copies.

    XLA_FLAGS=--xla_force_host_platform_device_count=4 python tests/sharded_twins.py BODY_FOLDER OUT

Prints one JSON object: the mesh lines the runs printed, the physics calls the sharded runs made on each
device, the largest differences between the twins' states (after training, and after each was resumed on
the other layout), whether the copies hold different variants (the same in both seeds), the evaluation's
returns, the exported policy's actions, and an environment whose copies do not divide by the devices
(3 of hopper_3 on 4 devices) stepped over them against one device.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from conftest import tiny_train_config
from jax.sharding import Mesh

from swat_jax import export, serving
from swat_jax.envs.multi_task import MultiTaskEnv
from swat_jax.eval import evaluate
from swat_jax.runs.checkpoint import Checkpoints
from swat_jax.runs.experiment import Experiment
from swat_jax.runs.trained import load_policy
from swat_jax.td3.iteration import IterationConfig
from swat_jax.train import train


def config(out: Path, folder: Path, name: str, steps: int):
    """2 seeds of a 1-layer AMORPHEUS on the folder's 2 bodies, 2 copies each running its own variant of
    the body: 40 steps per iteration, updates from the second. Short, because contacts amplify the float
    rounding in which the layouts' programs differ (1e-7) into visible differences within tens of steps."""
    return tiny_train_config(
        out / name,
        folder,
        steps=steps,
        iteration=IterationConfig(chunk=10, random_steps=10, capacity=1000, loop="rounds"),
        envs={"variants": 2, "variation": 0.3},
        eval_interval=0,
        log_interval=40,
        checkpoint_interval=40,
    )


def final_state(run_config):
    checkpoints = Checkpoints(run_config.directory())
    try:
        return Experiment.build(run_config, jax.devices()[:1]).restore_state(checkpoints)[0]
    finally:
        checkpoints.close()


def largest_differences(first, second) -> dict[str, float]:
    """Over the float arrays of two states: the largest absolute difference relative to max(1, |value|),
    and whether every integer array is equal."""
    relative, integers_equal = 0.0, True
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(second), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if not a.size:
            continue
        if np.issubdtype(a.dtype, np.floating):
            scale = np.maximum(1.0, np.abs(b))
            relative = max(relative, float(np.max(np.abs(a - b) / scale)))
        else:
            integers_equal &= bool(np.array_equal(a, b))
    return {"relative": relative, "integers_equal": integers_equal}


def trained(run_config, devices: int, resume: bool = False) -> tuple[str, str | None]:
    """Train (or resume) on the first ``devices`` devices; returns the mesh line the run printed and its
    physics calls line (None on one device)."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        train(run_config, progress=False, devices=devices, resume=resume)
    lines = printed.getvalue().splitlines()
    calls = [line for line in lines if line.startswith("physics calls")]
    return next(line for line in lines if line.startswith("mesh of")), (calls[0] if calls else None)


def padded_copies(folder: Path, steps: int = 4) -> dict:
    """3 copies of hopper_3 stepped over the 4 devices (one padding copy) and on one device: whether every
    array of the two states is equal, bit for bit, and the calls each device made."""
    mesh = Mesh(np.asarray(jax.devices()).reshape(2, 2), ("seeds", "tasks"))
    states, calls = [], None
    for layout in (mesh, None):
        env = MultiTaskEnv([str(folder / "hopper_3.xml")], copies=3, physics="c", mesh=layout)
        step = jax.jit(env.step)
        state = env.reset(jax.random.PRNGKey(0))
        action = jnp.full((1, *env.action_shape), 0.3)
        for _ in range(steps):
            state, _ = step(state, action)
        states.append(jax.device_get(state))
        calls = calls or env.physics_calls()
    equal = all(
        np.asarray(a).tobytes() == np.asarray(b).tobytes()
        for a, b in zip(jax.tree.leaves(states[0]), jax.tree.leaves(states[1]), strict=True)
    )
    return {"equal": equal, "calls": {str(device): count for device, count in calls.items()}}


def main(folder: Path, out: Path) -> None:
    sharded, unsharded = config(out, folder, "sharded", 80), config(out, folder, "unsharded", 80)
    lines = [trained(sharded, 4), trained(unsharded, 1)]
    after_training = largest_differences(final_state(sharded), final_state(unsharded))

    sharded, unsharded = config(out, folder, "sharded", 120), config(out, folder, "unsharded", 120)
    lines += [trained(sharded, 1, resume=True), trained(unsharded, 4, resume=True)]
    resumed = [final_state(sharded), final_state(unsharded)]
    after_resume = largest_differences(*resumed)
    variants = np.asarray(resumed[0].env.bodies[0].variant.index)  # [seeds, copies]

    policy = load_policy(sharded.directory())
    evaluation = evaluate(policy, policy.info.bodies, episodes=2)
    export.export_policy(sharded.directory(), out / "policy.npz")
    loaded = serving.load(out / "policy.npz")
    observation = np.zeros((3, loaded.max_limbs, loaded.observation_features), np.float32)
    actions = np.asarray(loaded(observation, loaded.bodies[0]))
    print(
        json.dumps(
            {
                "devices": len(jax.devices()),
                "meshes": [mesh for mesh, _ in lines],
                "physics_calls": [calls for _, calls in lines],
                "padded": padded_copies(folder),
                "after_training": after_training,
                "after_resume": after_resume,
                "steps_per_task": [state.steps_per_task.item() for state in resumed],
                "copies_differ": bool(np.all(variants[:, 0] != variants[:, 1])),
                "seeds_share_variants": bool(np.array_equal(variants[0], variants[1])),
                "eval_returns": [result.returns.tolist() for result in evaluation],
                "actions_shape": list(actions.shape),
                "actions_finite": bool(np.isfinite(actions).all()),
            }
        )
    )


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
