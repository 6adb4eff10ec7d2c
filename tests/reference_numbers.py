"""Compiled physical numbers of a MuJoCo model, for checking our MJCF against the benchmark's.

``summarize(model)`` lists what shapes the dynamics and the observations: per limb the tree, frame,
mass and inertia; per joint the axis, anchor, range, reference and passive parameters; per geom the
shape, placement and contact parameters (the margin as a contact with the floor gets it: MuJoCo 2 takes the
larger of the two geoms' margins, MuJoCo 3 their sum); per motor the joint, gear and control range; sites; timestep
and integrator. Visual properties are left out.

Run as a script with MuJoCo 2.3.3 (the last release that reads the reference's global coordinates)
to regenerate ``tests/data/reference_numbers.json`` from ``../shared/reference``:

    python -m venv /tmp/mj233 && /tmp/mj233/bin/pip install mujoco==2.3.3
    /tmp/mj233/bin/python tests/reference_numbers.py ../shared/reference

and ``tests/data/reference_numbers_3d.json`` from the 3D-SGRL benchmark's environments folder:

    /tmp/mj233/bin/python tests/reference_numbers.py --3d PATH/TO/sgrl/src/environments
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

import mujoco
import numpy as np

OUTPUT = Path(__file__).parent / "data" / "reference_numbers.json"
OUTPUT_3D = Path(__file__).parent / "data" / "reference_numbers_3d.json"


def _round(values, digits: int = 6) -> list[float]:
    return [round(float(v), digits) + 0.0 for v in np.ravel(values)]


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, index: int) -> str | None:
    return mujoco.mj_id2name(model, obj, index)


def floor_contact_margin(model: mujoco.MjModel, geom: int) -> float:
    """The margin of a contact between ``geom`` and the floor (geom 0) on this MuJoCo: the larger of the two
    geoms' margins before MuJoCo 3, their sum from 3 on (measured: 2.3.3 and 3.17 on the hoppers' files)."""
    combine = max if int(mujoco.__version__.split(".")[0]) < 3 else float.__add__
    return combine(float(model.geom_margin[geom]), float(model.geom_margin[0]))


def summarize(model: mujoco.MjModel) -> dict:
    """The physics-relevant numbers of a compiled model, as JSON-ready values (angles in radians)."""
    body_name = [_name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(model.nbody)]
    joint_name = [_name(model, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(model.njnt)]
    bodies = [
        dict(
            name=body_name[i],
            parent=body_name[model.body_parentid[i]],
            pos=_round(model.body_pos[i]),
            quat=_round(model.body_quat[i]),
            mass=_round([model.body_mass[i]])[0],
            inertia=_round(model.body_inertia[i]),
            ipos=_round(model.body_ipos[i]),
        )
        for i in range(1, model.nbody)
    ]
    joints = [
        dict(
            name=joint_name[j],
            body=body_name[model.jnt_bodyid[j]],
            type=int(model.jnt_type[j]),
            pos=_round(model.jnt_pos[j]),
            axis=_round(model.jnt_axis[j]),
            limited=bool(model.jnt_limited[j]),
            range=_round(model.jnt_range[j]),
            qpos0=_round([model.qpos0[model.jnt_qposadr[j]]])[0],
            stiffness=_round([model.jnt_stiffness[j]])[0],
            armature=_round([model.dof_armature[model.jnt_dofadr[j]]])[0],
            damping=_round([model.dof_damping[model.jnt_dofadr[j]]])[0],
            solref_limit=_round(model.jnt_solref[j]),
            solimp_limit=_round(model.jnt_solimp[j]),
        )
        for j in range(model.njnt)
    ]
    geoms = [
        dict(
            body=body_name[model.geom_bodyid[g]],
            type=int(model.geom_type[g]),
            size=_round(model.geom_size[g]),
            pos=_round(model.geom_pos[g]),
            quat=_round(model.geom_quat[g]),
            friction=_round(model.geom_friction[g]),
            contype=int(model.geom_contype[g]),
            conaffinity=int(model.geom_conaffinity[g]),
            condim=int(model.geom_condim[g]),
            floor_contact_margin=_round([floor_contact_margin(model, g)])[0],
            solref=_round(model.geom_solref[g]),
            solimp=_round(model.geom_solimp[g]),
        )
        for g in range(model.ngeom)
    ]
    motors = [
        dict(
            joint=joint_name[model.actuator_trnid[a, 0]],
            gear=_round([model.actuator_gear[a, 0]])[0],
            ctrlrange=_round(model.actuator_ctrlrange[a]),
            ctrllimited=bool(model.actuator_ctrllimited[a]),
        )
        for a in range(model.nu)
    ]
    sites = [
        dict(
            name=_name(model, mujoco.mjtObj.mjOBJ_SITE, s),
            body=body_name[model.site_bodyid[s]],
            pos=_round(model.site_pos[s]),
        )
        for s in range(model.nsite)
    ]
    option = dict(
        timestep=_round([model.opt.timestep])[0],
        integrator=int(model.opt.integrator),
        gravity=_round(model.opt.gravity),
    )
    return dict(option=option, bodies=bodies, joints=joints, geoms=geoms, motors=motors, sites=sites)


def assert_same_numbers(ours, reference, where: str) -> None:
    """Two :func:`summarize` results (or parts of them) agree: names and integers exactly, numbers to 2e-5,
    orientations up to the sign of the quaternion (q and -q are the same rotation)."""
    if isinstance(reference, dict):
        assert ours.keys() == reference.keys(), where
        for key in reference:
            assert_same_numbers(ours[key], reference[key], f"{where}.{key}")
    elif isinstance(reference, list) and reference and isinstance(reference[0], dict):
        assert len(ours) == len(reference), f"{where}: {len(ours)} entries, reference has {len(reference)}"
        for index, (a, b) in enumerate(zip(ours, reference, strict=True)):
            assert_same_numbers(a, b, f"{where}[{index}]")
    elif where.endswith("quat"):
        sign = 1.0 if np.dot(ours, reference) >= 0 else -1.0
        np.testing.assert_allclose(sign * np.asarray(ours), reference, atol=2e-5, err_msg=where)
    elif isinstance(reference, (list, float)):
        np.testing.assert_allclose(ours, reference, atol=2e-5, err_msg=where)
    else:
        assert ours == reference, where


def extract(reference_dir: Path) -> dict[str, dict]:
    """Summaries of every reference body; fixes the malformed hopper foot position on the way."""
    summaries = {}
    with tempfile.TemporaryDirectory() as tmp:
        # The reference files include ../../misc/*.xml relative to their own folder.
        work = Path(tmp) / "reference" / "morphologies"
        work.mkdir(parents=True)
        shutil.copytree(reference_dir / "misc", Path(tmp) / "misc")
        for source in sorted((reference_dir / "morphologies").glob("*.xml")):
            text = source.read_text().replace("0.13/2", "0.065")
            target = work / source.name
            target.write_text(text)
            summaries[source.stem] = summarize(mujoco.MjModel.from_xml_path(str(target)))
    return summaries


def extract_3d(environments: Path) -> dict[str, dict]:
    """Summaries of the 3D-SGRL benchmark's bodies (its ``src/environments`` folder), the hopper foot fixed
    as above; the ``_v2`` bodies have the same files and are not repeated."""
    summaries = {}
    with tempfile.TemporaryDirectory() as tmp:
        # The files include ../../misc/*.xml relative to their own folder.
        shutil.copytree(environments.parent / "misc", Path(tmp) / "misc")
        for source in sorted(environments.glob("*/*.xml")):
            if "_v2" in source.parent.name or source.stem in summaries:
                continue
            target = Path(tmp) / "environments" / source.parent.name / source.name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(source.read_text().replace("0.13/2", "0.065"))
            summaries[source.stem] = summarize(mujoco.MjModel.from_xml_path(str(target)))
    return summaries


if __name__ == "__main__":
    if sys.argv[1] == "--3d":
        summaries, output = extract_3d(Path(sys.argv[2])), OUTPUT_3D
    else:
        summaries, output = extract(Path(sys.argv[1])), OUTPUT
    output.write_text(json.dumps(summaries, indent=None, separators=(",", ":"), sort_keys=True) + "\n")
    print(f"wrote {len(summaries)} bodies to {output}")
