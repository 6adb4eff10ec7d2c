"""SGRL's 3D environments as recorded (``tests/data/sgrl_3d.npz``), and states built from them.

The recordings come from the benchmark's own environment classes, run with random actions by the
recorder of the workspace's SGRL tools on MuJoCo 2.3.3 (20 steps per body, a reset every 10), one
``.npz`` per body; this script packs them into one file (observations in float32):

    STEPS=20 EPISODE=10 OUT=/tmp/sgrl-fix python record_sgrl.py
    python tests/sgrl_fixture.py /tmp/sgrl-fix
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from swat_jax.envs import BodyEnv
from swat_jax.envs.c_physics import CData

FIXTURE = Path(__file__).parent / "data" / "sgrl_3d.npz"
UNUSED = ("motors", "bodies", "joints")
"""Names the recorder writes that the tests do not read (our model's own names are checked instead)."""


@functools.cache
def _fixture() -> dict[str, np.ndarray]:
    with np.load(FIXTURE) as data:
        return {key: data[key] for key in data.files}


def recorded_bodies() -> tuple[str, ...]:
    return tuple(sorted({key.split("/")[0] for key in _fixture()}))


def recording(body: str) -> dict[str, np.ndarray]:
    """One body's arrays: qpos, qvel, action (motor order), obs [steps, n * 41], reward, done,
    qpos_after, qvel_after, target, after_reset, and reset_qpos/qvel/obs/target per reset."""
    prefix = f"{body}/"
    return {key.removeprefix(prefix): value for key, value in _fixture().items() if key.startswith(prefix)}


def exact_data(env: BodyEnv, qpos: np.ndarray, qvel: np.ndarray) -> CData:
    """C-physics states [B] at float64 ``qpos`` [B, nq] and ``qvel`` [B, nv] exactly (their float32
    rounding plus the remainders), kinematics computed."""
    batch = len(qpos)
    initial = env.simulator.initial
    state = np.concatenate([qpos, qvel, np.zeros((batch, initial.act.shape[0] + qvel.shape[1]))], axis=1)
    rounded = state.astype(np.float32)
    middle = (state - rounded).astype(np.float32)
    low = (state - rounded - middle).astype(np.float32)
    nq, nv = qpos.shape[1], qvel.shape[1]
    data = CData(
        **{
            name: jnp.broadcast_to(value, (batch, *value.shape))
            for name, value in vars(initial).items()
            if value is not None
        }
    ).replace(
        qpos=jnp.asarray(rounded[:, :nq]),
        qvel=jnp.asarray(rounded[:, nq : nq + nv]),
        remainder=jnp.asarray(np.concatenate([middle, low], axis=1)),
    )
    return jax.vmap(env.kinematics)(data)


def pack(folder: Path) -> None:
    """Write FIXTURE from the recorder's per-body files in ``folder``."""
    arrays = {}
    for path in sorted(folder.glob("*.npz")):
        with np.load(path) as data:
            for key in data.files:
                if key not in UNUSED:
                    value = data[key].astype(np.float32) if key.endswith("obs") else data[key]
                    arrays[f"{path.stem}/{key}"] = value
    np.savez_compressed(FIXTURE, **arrays)


if __name__ == "__main__":
    pack(Path(sys.argv[1]))
