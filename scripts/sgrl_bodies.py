"""Write the 3D-SGRL benchmark's bodies as swat_jax MJCF files, from their compiled numbers.

SGRL (Chen, Han, Sun and Huang, ICML 2023) publishes its 3D Hopper++, Walker++, Humanoid++ and
Cheetah++ bodies in MJCF with ``coordinate="global"``, which MuJoCo read until 2.3.3 and no longer
reads. This script compiles each of them with MuJoCo 2.3.3 and writes, from the compiled model only
(frames, joints, geoms, motors, sites, options), a file of the project's own layout in local
coordinates: ``morphologies/3d_<family>_<n>_<name>.xml`` for every body, and the ``_v2`` bodies
(the same bodies with a nearby target, SGRL's second task) as ``3d_<family>_v2_<n>_<name>.xml``,
identical but for their declared family. ``tests/test_3d_bodies.py`` checks that our files compile
(MuJoCo 3) to the numbers the benchmark's files compile to (``tests/data/reference_numbers_3d.json``,
written by ``tests/reference_numbers.py``).

    python -m venv /tmp/mj233 && /tmp/mj233/bin/pip install mujoco==2.3.3 numpy
    /tmp/mj233/bin/python scripts/sgrl_bodies.py PATH/TO/sgrl/src/environments

The benchmark's 3D hoppers write ``pos="0.13/2 0 ..."`` for the foot, which no MuJoCo reads; as in the
2D bodies, it is read as 0.065. Their geoms have a contact margin of 0.001: MuJoCo 2 gives a contact the
larger of its two geoms' margins, MuJoCo 3 their sum, so each geom is written with half of it (every geom
of such a body has the same margin; a body whose margins differ is refused).
"""

from __future__ import annotations

import collections
import shutil
import sys
import tempfile
from pathlib import Path

import mujoco
import numpy as np

MORPHOLOGIES = Path(__file__).resolve().parent.parent / "morphologies"
FAMILY_FOLDERS = ("3d_hoppers", "3d_walkers", "3d_humanoids", "3d_cheetahs", "zero_shot")
FOOT_FIX = ("0.13/2", "0.065")
JOINT_DEFAULTS = dict(solreflimit="0.02 1", solimplimit="0.9 0.95 0.001 0.5 2")
GEOM_DEFAULTS = dict(
    friction="1 0.005 0.0001", condim="3", contype="1", conaffinity="1", margin="0",
    solref="0.02 1", solimp="0.9 0.95 0.001 0.5 2",
)  # fmt: skip
"""MuJoCo's own defaults: an attribute equal to them is not written."""
INTEGRATORS = {int(mujoco.mjtIntegrator.mjINT_EULER): "Euler", int(mujoco.mjtIntegrator.mjINT_RK4): "RK4"}


def _numbers(values) -> str:
    """Numbers as MJCF writes them, to 1e-9 (the benchmark's files give at most 6 decimals)."""
    return " ".join(f"{round(float(v), 9) + 0.0:.10g}" for v in np.ravel(values))


def _family(name: str) -> str:
    """``3d_hopper_v2_3_shin`` -> ``3d_hopper_v2``; ``3d_hopper_3_shin`` -> ``3d_hopper``."""
    parts = name.split("_")
    return "_".join(parts[:3]) if parts[2] == "v2" else "_".join(parts[:2])


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, index: int) -> str | None:
    return mujoco.mj_id2name(model, obj, index)


def contact_margins(model: mujoco.MjModel) -> np.ndarray:
    """Per geom [ngeom], the margin under which MuJoCo 3 (a contact's margin: the sum of its geoms') gives
    every contact the margin MuJoCo 2.3.3 gave it (the larger of its geoms'): half the body's one margin."""
    margins = np.unique(model.geom_margin)
    if len(margins) > 1:
        raise ValueError(f"geom margins {margins.tolist()}: MuJoCo 3 cannot give every contact the larger")
    return model.geom_margin / 2


def _geom_attributes(model: mujoco.MjModel, g: int, margin: float) -> dict[str, str]:
    attributes = {}
    name = _name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
    if name:
        attributes["name"] = name
    kind = mujoco.mjtGeom(model.geom_type[g]).name.removeprefix("mjGEOM_").lower()
    attributes["type"] = kind
    pos, quat, size = model.geom_pos[g], model.geom_quat[g], model.geom_size[g]
    if kind == "capsule":
        axis = np.zeros(3)
        mujoco.mju_rotVecQuat(axis, np.array([0.0, 0.0, 1.0]), quat)
        # MuJoCo 3 points a fromto capsule's z axis from "to" to "from" (2.3.3: from "from" to "to").
        attributes["fromto"] = _numbers(np.concatenate([pos + size[1] * axis, pos - size[1] * axis]))
        attributes["size"] = _numbers(size[:1])
    else:
        attributes["pos"] = _numbers(pos)
        if not np.allclose(quat, (1, 0, 0, 0)):
            attributes["quat"] = _numbers(quat)
        attributes["size"] = _numbers(size[:3] if kind == "plane" else size[:1])
    attributes.update(
        friction=_numbers(model.geom_friction[g]),
        condim=str(model.geom_condim[g]),
        contype=str(model.geom_contype[g]),
        conaffinity=str(model.geom_conaffinity[g]),
        margin=_numbers([margin]),
        solref=_numbers(model.geom_solref[g]),
        solimp=_numbers(model.geom_solimp[g]),
    )
    return attributes


def _joint_attributes(model: mujoco.MjModel, j: int) -> dict[str, str]:
    dof = model.jnt_dofadr[j]
    attributes = dict(
        name=_name(model, mujoco.mjtObj.mjOBJ_JOINT, j),
        pos=_numbers(model.jnt_pos[j]),
        axis=_numbers(model.jnt_axis[j]),
        range=_numbers(np.degrees(model.jnt_range[j])),
        armature=_numbers([model.dof_armature[dof]]),
        damping=_numbers([model.dof_damping[dof]]),
        stiffness=_numbers([model.jnt_stiffness[j]]),
        solreflimit=_numbers(model.jnt_solref[j]),
        solimplimit=_numbers(model.jnt_solimp[j]),
    )
    if not model.jnt_limited[j]:
        raise ValueError(
            f"joint {attributes['name']} has no range; every limb hinge of the benchmark has one"
        )
    if model.qpos0[model.jnt_qposadr[j]] != 0:
        attributes["ref"] = _numbers(np.degrees([model.qpos0[model.jnt_qposadr[j]]]))
    return attributes


def _common(rows: list[dict[str, str]], keys: tuple[str, ...]) -> dict[str, str]:
    """The most frequent value of each key over ``rows`` (ties: the first seen), for a <default>."""
    return {key: collections.Counter(row[key] for row in rows).most_common(1)[0][0] for key in keys}


def _element(tag: str, attributes: dict[str, str], default: dict[str, str], indent: int) -> str:
    written = {k: v for k, v in attributes.items() if default.get(k) != v}
    return " " * indent + f"<{tag} " + " ".join(f'{k}="{v}"' for k, v in written.items()) + "/>"


def _mjcf(name: str, model: mujoco.MjModel) -> str:
    """Our MJCF text of the compiled ``model`` (called ``name``)."""
    joints = [_joint_attributes(model, j) for j in range(model.njnt) if model.jnt_type[j] == 3]
    if any(model.jnt_type[j] not in (0, 3) for j in range(model.njnt)) or model.jnt_type[0] != 0:
        raise ValueError(f"{name}: expected a free torso joint and hinges below it")
    geoms = [_geom_attributes(model, g, margin) for g, margin in enumerate(contact_margins(model))]
    joint_keys = ("armature", "damping", "stiffness", "solreflimit", "solimplimit")
    geom_keys = tuple(GEOM_DEFAULTS)
    joint_default = _common(joints, joint_keys)
    geom_default = _common(geoms[1:], geom_keys)
    children = collections.defaultdict(list)
    for body in range(1, model.nbody):
        children[model.body_parentid[body]].append(body)
    limbs = [_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, model.nbody)]
    lines = [
        f"<!-- 3D-SGRL body {name} ({len(limbs)} limbs): {', '.join(limbs)}.",
        "     Written by `scripts/sgrl_bodies.py` from the compiled numbers of the benchmark's body. -->",
        f'<mujoco model="{name}">',
        '  <include file="assets/scene.xml"/>',
        '  <compiler angle="degree" inertiafromgeom="true"/>',
        f'  <option timestep="{model.opt.timestep:.10g}" integrator="{INTEGRATORS[model.opt.integrator]}"/>',
        "  <custom>",
        f'    <text name="swat_family" data="{_family(name)}"/>',
        "  </custom>",
        "  <default>",
        _element("joint", {"limited": "true", **joint_default}, JOINT_DEFAULTS, 4),
        _element("geom", {**geom_default, "material": "limb"}, GEOM_DEFAULTS, 4),
        '    <motor ctrllimited="true" ctrlrange="-1 1"/>',
        "  </default>",
        "  <worldbody>",
        _element("geom", {**geoms[0], "material": "floor"}, {**GEOM_DEFAULTS, **geom_default}, 4),
    ]

    def write(body: int, indent: int) -> None:
        attributes = {
            "name": _name(model, mujoco.mjtObj.mjOBJ_BODY, body),
            "pos": _numbers(model.body_pos[body]),
        }
        if not np.allclose(model.body_quat[body], (1, 0, 0, 0)):
            attributes["quat"] = _numbers(model.body_quat[body])
        lines.append(" " * indent + "<body " + " ".join(f'{k}="{v}"' for k, v in attributes.items()) + ">")
        for j in range(model.njnt):
            if model.jnt_bodyid[j] != body:
                continue
            if model.jnt_type[j] == 0:
                free = dict(
                    name=_name(model, mujoco.mjtObj.mjOBJ_JOINT, j), type="free", limited="false",
                    armature=_numbers(model.dof_armature[model.jnt_dofadr[j] : model.jnt_dofadr[j] + 1]),
                    damping=_numbers(model.dof_damping[model.jnt_dofadr[j] : model.jnt_dofadr[j] + 1]),
                    stiffness=_numbers([model.jnt_stiffness[j]]),
                )  # fmt: skip
                lines.append(_element("joint", free, {}, indent + 2))
            else:
                lines.append(
                    _element(
                        "joint", _joint_attributes(model, j), {**JOINT_DEFAULTS, **joint_default}, indent + 2
                    )
                )
        for g in range(model.ngeom):
            if model.geom_bodyid[g] == body:
                lines.append(_element("geom", geoms[g], {**GEOM_DEFAULTS, **geom_default}, indent + 2))
        for s in range(model.nsite):
            if model.site_bodyid[s] == body:
                site = dict(name=_name(model, mujoco.mjtObj.mjOBJ_SITE, s), pos=_numbers(model.site_pos[s]))
                lines.append(_element("site", site, {}, indent + 2))
        for child in children[body]:
            write(child, indent + 2)
        lines.append(" " * indent + "</body>")

    for root in children[0]:
        write(root, 4)
    lines += ["  </worldbody>", "  <actuator>"]
    for a in range(model.nu):
        motor = dict(
            joint=_name(model, mujoco.mjtObj.mjOBJ_JOINT, model.actuator_trnid[a, 0]),
            gear=_numbers(model.actuator_gear[a, :1]),
        )
        if not np.allclose(model.actuator_ctrlrange[a], (-1, 1)) or not model.actuator_ctrllimited[a]:
            raise ValueError(f"{name}: motor {a} is not limited to [-1, 1]")
        lines.append(_element("motor", motor, {}, 4))
    lines += ["  </actuator>", "</mujoco>", ""]
    return "\n".join(lines)


def compile_benchmark(environments: Path) -> dict[str, mujoco.MjModel]:
    """Every 3D body of SGRL's environments folder, compiled by the running MuJoCo (2.3.3), by name."""
    models = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / "src"
        shutil.copytree(environments.parent / "misc", work / "misc")
        for folder in FAMILY_FOLDERS:
            (work / "environments" / folder).mkdir(parents=True)
            for source in sorted((environments / folder).glob("*.xml")):
                target = work / "environments" / folder / source.name
                target.write_text(source.read_text().replace(*FOOT_FIX))
                models[source.stem] = mujoco.MjModel.from_xml_path(str(target))
    return models


def v2_name(name: str) -> str:
    """``3d_hopper_3_shin`` -> ``3d_hopper_v2_3_shin``."""
    family, rest = name.split("_", 2)[:2], name.split("_", 2)[2]
    return "_".join([*family, "v2", rest])


def main(environments: Path) -> None:
    models = compile_benchmark(environments)
    v2_folders = {p.stem for p in environments.glob("3d_*_v2/*.xml")}
    for name, model in models.items():
        (MORPHOLOGIES / f"{name}.xml").write_text(_mjcf(name, model))
        if v2_name(name) in v2_folders:
            (MORPHOLOGIES / f"{v2_name(name)}.xml").write_text(_mjcf(v2_name(name), model))
    print(f"wrote {len(models)} bodies and {len(v2_folders)} v2 bodies to {MORPHOLOGIES}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
