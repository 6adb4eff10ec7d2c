"""Fixtures from SGRL's own SET modules (Chen et al. 2023) for ``tests/test_set_network.py``.

Run as a script in a virtual environment that runs SGRL's code (PyTorch, xmltodict, gym 0.13.1 and the
small mujoco_py stand-in of the workspace's original-code tools; docs/networks.md, "SET"), with SGRL's
``src`` folder and that stand-in named, to rewrite ``tests/data/sgrl/set.npz``:

    SGRL_SRC=/path/to/sgrl/src SHIM=/path/to/tools/original/shim OMP_NUM_THREADS=1 \\
        /tmp/orig-venv/bin/python tests/sgrl_set_data.py

For four 3D bodies of different limb counts it stores SGRL's structure inputs (parents from its
``getGraphStructure``, traversals and relations from its ``getGraphDict``, as its ``main.py`` builds
them), random observations (41 values a limb, gravity and a unit target direction where SGRL's
observation has them) and actions, and the outputs of SGRL's ``SEPolicy`` (actions, [batch, limbs * 3])
and ``SECritic`` (q1, q2, [batch, limbs]) at small sizes. Every weight is drawn by
:func:`original_parity_data.filled_state_dict` (actor seed 1, critic seed 2); only the state dicts' keys
and shapes are stored, and the test draws the same weights again (the filled networks are megabytes).
"""

from __future__ import annotations

import os
import sys
import types
from pathlib import Path

import numpy as np
from original_parity_data import filled_state_dict

OUTPUT = Path(__file__).resolve().parent / "data" / "sgrl" / "set.npz"
BODIES = {
    "3d_hopper_4_lower_shin": "3d_hoppers",
    "3d_walker_7_full": "3d_walkers",
    "3d_humanoid_9_full": "3d_humanoids",
    "3d_cheetah_11_leftfleg": "3d_cheetahs",
}
"""Each fixture body and the folder of SGRL's ``environments`` that holds its XML."""
FEATURES = 41
MOTORS = 3
BATCH = 3
GRAVITY = (0.0, 0.0, -9.81)
SIZES = {
    "attention_embedding_size": 16,
    "attention_heads": 2,
    "attention_hidden_size": 32,
    "attention_layers": 2,
}
SEEDS = {"actor": 1, "critic": 2}


def _sgrl_args() -> types.SimpleNamespace:
    """The arguments SGRL's SEPolicy and SECritic read, as its main.py sets them for 3D bodies."""
    return types.SimpleNamespace(
        **SIZES,
        dropout_rate=0.0,
        condition_decoder_on_features=1,
        transformer_norm=1,
        traversal_types=["pre", "inlcrs", "postlcrs"],
        rel_size=3,
    )


def _observation(rng: np.random.Generator, limbs: int) -> np.ndarray:
    """[BATCH, limbs * FEATURES]: uniform in [-1, 1], gravity at 3:6, a unit target direction in the floor
    plane at 6:9 (the same for every limb of a sample) and unit joint axes at 15:24."""
    observation = rng.uniform(-1, 1, (BATCH, limbs, FEATURES))
    observation[..., 3:6] = GRAVITY
    heading = rng.uniform(-np.pi, np.pi, (BATCH, 1))
    observation[..., 6:9] = np.stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)], -1)
    axes = rng.normal(size=(BATCH, limbs, 3, 3))
    observation[..., 15:24] = (axes / np.linalg.norm(axes, axis=-1, keepdims=True)).reshape(BATCH, limbs, 9)
    return observation.reshape(BATCH, limbs * FEATURES).astype(np.float32)


def generate() -> dict[str, np.ndarray]:
    import torch
    from common import util

    util.device = torch.device("cpu")
    import utils
    from SEActor import SEPolicy
    from SECritic import SECritic

    args = _sgrl_args()
    actor = SEPolicy(FEATURES, MOTORS, 32, BATCH, 1.0, None, True, True, True, args)
    critic = SECritic(FEATURES, MOTORS, 32, BATCH, None, True, True, True, args)
    out: dict[str, np.ndarray] = {key: np.int32(value) for key, value in SIZES.items()}
    for name, network in (("actor", actor), ("critic", critic)):
        shapes = {key: tuple(value.shape) for key, value in network.state_dict().items()}
        keys = sorted(shapes)
        out[f"{name}/keys"] = np.array(keys)
        out[f"{name}/shapes"] = np.array([",".join(map(str, shapes[key])) for key in keys])
        weights = filled_state_dict(shapes, SEEDS[name])
        network.load_state_dict({key: torch.from_numpy(value) for key, value in weights.items()})
    rng = np.random.default_rng(0)
    for body, folder in BODIES.items():
        xml = os.path.join(os.environ["SGRL_SRC"], "environments", folder, f"{body}.xml")
        parents = utils.getGraphStructure(xml)
        graph = utils.getGraphDict(parents, args.traversal_types, device=torch.device("cpu"))
        out[f"structure/{body}/parents"] = np.array(parents, np.int32)
        out[f"structure/{body}/traversals"] = np.stack([t.numpy() for t in graph["traversals"]], -1).astype(
            np.int32
        )
        out[f"structure/{body}/relations"] = graph["relation"].numpy().astype(np.float32)
        observation = _observation(rng, len(parents))
        action = rng.uniform(-1, 1, (BATCH, len(parents) * MOTORS)).astype(np.float32)
        out[f"inputs/{body}/observation"], out[f"inputs/{body}/action"] = observation, action
        actor.change_morphology(graph)
        critic.change_morphology(graph)
        with torch.no_grad():
            out[f"outputs/{body}/actor"] = actor(torch.from_numpy(observation)).numpy()
            q1, q2 = critic(torch.from_numpy(observation), torch.from_numpy(action))
        out[f"outputs/{body}/q1"], out[f"outputs/{body}/q2"] = q1.numpy(), q2.numpy()
    return out


def main() -> None:
    sys.path[:0] = [os.environ["SGRL_SRC"], os.environ["SHIM"]]
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUTPUT, **generate())
    print(f"wrote {OUTPUT} ({OUTPUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
