"""Reading one body from MJCF into an immutable ``Morphology``, with errors that say what to fix.

A body file follows the benchmark's conventions: one root body under the worldbody (the torso) that
moves on two slide joints (x, then z) and one hinge (pitch), and below it a tree of limbs, each with
exactly one hinge joint driven by exactly one motor. A body of a 3D family (SGRL's benchmark) has a
free torso instead, and one to three hinges per limb (x, y, z), each with its motor. The family is
declared in the file: ``<custom><text name="swat_family" data="walker"/></custom>`` (families.py
lists them).
"""

from __future__ import annotations

import difflib
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

from swat_jax.morphology.families import FAMILIES, family_spec
from swat_jax.morphology.paths import MORPHOLOGY_DIR
from swat_jax.morphology.types import FamilySpec, Morphology

FAMILY_TEXT = "swat_family"
SOURCE_TEXT = "swat_source"
"""Optional ``<text>``: the benchmark body whose per-body constants a file keeps (a variant's nominal body)."""
ROOT_JOINTS = (
    (mujoco.mjtJoint.mjJNT_SLIDE, (1.0, 0.0, 0.0)),
    (mujoco.mjtJoint.mjJNT_SLIDE, (0.0, 0.0, 1.0)),
    (mujoco.mjtJoint.mjJNT_HINGE, (0.0, 1.0, 0.0)),
)
"""Torso joints in order: qpos[0] = x, qpos[1] = height, qpos[2] = pitch angle."""
MOTOR_TYPES = (mujoco.mjtDyn.mjDYN_NONE, mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_NONE)
"""Dynamics, gain and bias types of a ``<motor>``: the control is a force, scaled by the gear."""
_BODY, _GEOM, _JOINT, _SITE, _ACTUATOR = (
    mujoco.mjtObj.mjOBJ_BODY,
    mujoco.mjtObj.mjOBJ_GEOM,
    mujoco.mjtObj.mjOBJ_JOINT,
    mujoco.mjtObj.mjOBJ_SITE,
    mujoco.mjtObj.mjOBJ_ACTUATOR,
)
CHECKED_NUMBERS = (
    ("geom_pos", _GEOM, "pos or fromto", False),
    ("geom_quat", _GEOM, "orientation or fromto", False),
    ("geom_friction", _GEOM, "friction", True),
    ("body_pos", _BODY, "pos", False),
    ("body_quat", _BODY, "orientation (quat, euler, axisangle, xyaxes or zaxis)", False),
    ("body_ipos", _BODY, "<inertial> pos", False),
    ("body_iquat", _BODY, "<inertial> orientation", False),
    ("site_pos", _SITE, "pos", False),
    ("jnt_pos", _JOINT, "pos", False),
    ("jnt_axis", _JOINT, "axis", False),
    ("jnt_stiffness", _JOINT, "stiffness", True),
    ("dof_damping", _JOINT, "damping", True),
    ("dof_armature", _JOINT, "armature", True),
    ("dof_frictionloss", _JOINT, "frictionloss", True),
    ("actuator_gear", _ACTUATOR, "gear", False),
    ("actuator_ctrlrange", _ACTUATOR, "ctrlrange", False),
)
"""Compiled numbers that MuJoCo 3.17 accepts although NaN, infinite (it only warns) or, where the
last column says so, negative: (model field, element type, MJCF attribute, must be >= 0). Geoms come
before bodies because a body's inertial frame is computed from its geoms. Masses, inertias and geom
sizes are not listed: MuJoCo refuses non-finite and non-positive ones itself."""


class MorphologyError(ValueError):
    """A body file that cannot be used; the message names the file, the element and the fix."""

    def __init__(self, path: Path | str, problem: str):
        super().__init__(f"{path}: {problem}")
        self.path = Path(path)
        self.problem = problem


def benchmark_names() -> tuple[str, ...]:
    """Names of the bodies shipped in ``morphologies/``, sorted."""
    return tuple(sorted(p.stem for p in MORPHOLOGY_DIR.glob("*.xml")))


def resolve(name_or_path: str | Path) -> Path:
    """The MJCF path of a benchmark name or of a file path; raises MorphologyError if neither exists."""
    candidate = MORPHOLOGY_DIR / f"{name_or_path}.xml"
    if isinstance(name_or_path, str) and "/" not in name_or_path and candidate.exists():
        return candidate
    path = Path(name_or_path).expanduser()
    if path.is_file():
        return path
    if path.is_dir():
        raise MorphologyError(
            path,
            "is a folder, not a body file; give the path of one MJCF file in it "
            "(a folder of body files is an environment set: `python -m swat_jax.train --env FOLDER`)",
        )
    if path.suffix.lower() != ".xml" and "/" not in str(name_or_path):
        close = difflib.get_close_matches(str(name_or_path), benchmark_names(), n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        raise MorphologyError(
            name_or_path,
            f"not a benchmark body and no such file.{hint} "
            "`python -m swat_jax.morphology list` prints the benchmark's bodies.",
        )
    raise MorphologyError(path, "no such file; give the path of an MJCF file or a benchmark body name")


def _check_xml(path: Path) -> ET.Element:
    """The root element of a well-formed MJCF file (``<mujoco>``); MuJoCo would also read a URDF."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        line, column = error.position
        raise MorphologyError(path, f"malformed XML at line {line}, column {column}: {error}") from None
    if root.tag != "mujoco":
        raise MorphologyError(
            path,
            f"not a MuJoCo file: its root element is <{root.tag}>, an MJCF body file's is <mujoco>; "
            "write the body in MJCF (a URDF can be converted: load it with MuJoCo and save it with "
            "mujoco.mj_saveLastXML, then follow the body conventions of docs/bodies-and-environments.md, "
            "'Bringing a new body')",
        )
    return root


def _check_motor_targets(path: Path, root: ET.Element) -> None:
    joints = {j.get("name") for j in root.iter("joint")}
    for actuator in root.iter("actuator"):
        for index, motor in enumerate(actuator):
            target = motor.get("joint")
            if target is not None and target not in joints:
                raise MorphologyError(
                    path,
                    f"<actuator> element {index} (<{motor.tag} joint={target!r}>) drives an unknown joint; "
                    f"joints in this file: {', '.join(sorted(n for n in joints if n))}",
                )


def _check_no_free_limbs(path: Path, root: ET.Element) -> None:
    """MuJoCo refuses free joints below the top level with a generic message; say it in body terms."""
    for torso in root.iterfind("worldbody/body"):
        for limb in torso.iter("body"):
            direct = [
                *limb.findall("freejoint"),
                *(j for j in limb.findall("joint") if j.get("type") == "free"),
            ]
            if limb is not torso and direct:
                raise MorphologyError(
                    path,
                    f"limb <body name={limb.get('name')!r}> has a free joint; limbs below the torso need hinges",
                )


def _compile(path: Path) -> mujoco.MjModel:
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as error:
        message = "; ".join(line.strip() for line in str(error).splitlines() if line.strip())
        raise MorphologyError(path, f"MuJoCo cannot compile this file: {message}") from None


def compile_model(morphology: Morphology) -> mujoco.MjModel:
    """The MuJoCo model of a loaded body (its MJCF file compiled again)."""
    return _compile(morphology.path)


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, index: int) -> str:
    return mujoco.mj_id2name(model, obj, index) or f"#{index}"


def _numbers(values: np.ndarray) -> str:
    """Numbers as they would be written in MJCF: ``"0 nan 1"``."""
    return '"' + " ".join(f"{v:g}" for v in np.ravel(values)) + '"'


def _element(model: mujoco.MjModel, obj: mujoco.mjtObj, index: int) -> str:
    """An element in MJCF terms: ``<joint name='knee'>``, or an unnamed one by what it belongs to."""
    tag = mujoco.mjtObj(obj).name.removeprefix("mjOBJ_").lower()
    name = mujoco.mj_id2name(model, obj, index)
    if name:
        return f"<{tag} name={name!r}>"
    if obj == _ACTUATOR and model.actuator_trntype[index] == mujoco.mjtTrn.mjTRN_JOINT:
        joint = _name(model, _JOINT, model.actuator_trnid[index, 0])
        return f"the unnamed actuator of <joint name={joint!r}>"
    owner = {_GEOM: model.geom_bodyid, _SITE: model.site_bodyid}.get(obj)
    if owner is None:
        return f"<{tag}> #{index}"
    return f"an unnamed <{tag}> of <body name={_name(model, _BODY, owner[index])!r}>"


def _check_numbers(path: Path, model: mujoco.MjModel) -> None:
    """Refuse the NaN, infinite or negative numbers MuJoCo compiles (CHECKED_NUMBERS) and a bad timestep."""
    timestep = model.opt.timestep
    if not (np.isfinite(timestep) and timestep > 0):
        raise MorphologyError(
            path, f'<option timestep="{timestep:g}">; the timestep must be a positive number of seconds'
        )
    if not np.isfinite(model.opt.gravity).all():
        raise MorphologyError(
            path, f"<option gravity={_numbers(model.opt.gravity)}>; write three finite numbers"
        )
    for field, obj, attribute, nonnegative in CHECKED_NUMBERS:
        values = getattr(model, field)
        rows = tuple(range(1, values.ndim))
        bad = ~np.isfinite(values).all(axis=rows) | (nonnegative & (values < 0).any(axis=rows))
        for row in np.flatnonzero(bad):
            index = model.dof_jntid[row] if field.startswith("dof_") else row
            allowed = "finite numbers of at least 0" if nonnegative else "finite numbers"
            raise MorphologyError(
                path,
                f"{_element(model, obj, index)} has {attribute} {_numbers(values[row])}; write {allowed} "
                "there (MuJoCo compiles it, the simulation would not be meaningful)",
            )


def _check_geom_masses(path: Path, root: ET.Element) -> None:
    """MuJoCo ignores a NaN or infinite ``<geom mass>`` (the density decides); refuse it instead."""
    parents = {child: parent for parent in root.iter() for child in parent}
    for geom in root.iter("geom"):
        mass = geom.get("mass")
        if mass is not None and not _is_finite(mass):
            parent = parents[geom]
            where = f"<geom name={geom.get('name')!r}>" if geom.get("name") else "a <geom>"
            owner = f" in <{parent.tag} name={parent.get('name')!r}>" if parent.get("name") else ""
            raise MorphologyError(
                path, f'{where}{owner} has mass="{mass}"; write a positive number of kilograms'
            )


def _is_finite(text: str) -> bool:
    try:
        return bool(np.isfinite(float(text)))
    except ValueError:
        return True  # not a number at all: MuJoCo's own parser reports it


def _custom_text(model: mujoco.MjModel, name: str) -> str | None:
    """The data of the file's ``<custom><text name=NAME>``, None without one."""
    text = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, name)
    if text < 0:
        return None
    start, size = model.text_adr[text], model.text_size[text]
    return bytes(model.text_data[start : start + size - 1]).decode()


def _family_name(path: Path, model: mujoco.MjModel) -> str:
    family = _custom_text(model, FAMILY_TEXT)
    declare = f'<custom><text name="{FAMILY_TEXT}" data="FAMILY"/></custom> with FAMILY one of {", ".join(FAMILIES)}'
    if family is None:
        raise MorphologyError(path, f"no family declared; add {declare}")
    if family not in FAMILIES:
        raise MorphologyError(
            path, f"<text name={FAMILY_TEXT!r}> names unknown family {family!r}; use {declare}"
        )
    return family


def _check_root(path: Path, model: mujoco.MjModel, spec: FamilySpec) -> None:
    roots = [b for b in range(1, model.nbody) if model.body_parentid[b] == 0]
    if not roots:
        raise MorphologyError(path, "<worldbody> has no <body>; a body file needs one root body, the torso")
    if len(roots) > 1:
        names = ", ".join(_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in roots)
        raise MorphologyError(
            path, f"<worldbody> has {len(roots)} root bodies ({names}); keep one, the torso"
        )
    torso = _name(model, mujoco.mjtObj.mjOBJ_BODY, 1)
    joints = [j for j in range(model.njnt) if model.jnt_bodyid[j] == 1]
    if spec.three_d:
        if len(joints) != 1 or model.jnt_type[joints[0]] != mujoco.mjtJoint.mjJNT_FREE:
            raise MorphologyError(
                path,
                f"torso <body name={torso!r}> of a 3D body ({spec.name}) needs exactly one joint, a free "
                f'joint (<freejoint/> or <joint type="free"/>); it has {len(joints)} joints',
            )
        return
    expected = "slide along x, slide along z, hinge about y (in that order)"
    if len(joints) != len(ROOT_JOINTS):
        raise MorphologyError(
            path, f"torso <body name={torso!r}> has {len(joints)} joints; it needs 3: {expected}"
        )
    for joint, (kind, axis) in zip(joints, ROOT_JOINTS, strict=True):
        if model.jnt_type[joint] != kind or not np.allclose(model.jnt_axis[joint], axis):
            name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
            found = mujoco.mjtJoint(model.jnt_type[joint]).name.removeprefix("mjJNT_").lower()
            raise MorphologyError(
                path,
                f"torso joint {name!r} is a {found} with axis {_numbers(model.jnt_axis[joint])}, so the "
                f"torso is not planar; the torso's joints must be {expected}",
            )


def _limb_joints(path: Path, model: mujoco.MjModel, body: int, most: int) -> tuple[int, ...]:
    """The hinges of limb ``body``: exactly one for a planar body, one to ``most`` in 3D."""
    limb = _name(model, mujoco.mjtObj.mjOBJ_BODY, body)
    joints = [j for j in range(model.njnt) if model.jnt_bodyid[j] == body]
    if not joints:
        raise MorphologyError(
            path, f"limb <body name={limb!r}> has no joint; give it one hinge joint and a motor"
        )
    names = [_name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
    for joint, name in zip(joints, names, strict=True):
        if model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_HINGE:
            kind = mujoco.mjtJoint(model.jnt_type[joint]).name.removeprefix("mjJNT_").lower()
            raise MorphologyError(
                path,
                f"limb <body name={limb!r}> has a {kind} joint {name!r}; limbs below the torso need hinges",
            )
    if len(joints) > most:
        allowed = "one hinge" if most == 1 else f"at most {most} hinges (x, y, z) in 3D"
        raise MorphologyError(
            path,
            f"limb <body name={limb!r}> has {len(joints)} joints ({', '.join(names)}); a limb has {allowed}",
        )
    for joint, name in zip(joints, names, strict=True):
        if not model.jnt_limited[joint]:
            raise MorphologyError(
                path,
                f'limb joint <joint name={name!r}> has no range (limited="false", no range, or LOW >= HIGH); '
                'the observation scales each joint angle by its range: give it range="LOW HIGH" in degrees, '
                "LOW < HIGH",
            )
    return tuple(joints)


def _check_motor(path: Path, model: mujoco.MjModel, actuator: int) -> None:
    """A torque motor on one joint: the policy's action is a torque command."""
    name = _element(model, _ACTUATOR, actuator)
    if model.actuator_trntype[actuator] != mujoco.mjtTrn.mjTRN_JOINT:
        raise MorphologyError(path, f"{name} does not drive a joint; every motor drives one limb joint")
    kind = (
        model.actuator_dyntype[actuator],
        model.actuator_gaintype[actuator],
        model.actuator_biastype[actuator],
    )
    if kind != MOTOR_TYPES:
        raise MorphologyError(
            path,
            f"{name} is not a <motor> (a <position> or <velocity> servo, or an actuator with "
            "activation dynamics or a bias force); the policy's actions are torques: drive every limb "
            'joint with <motor joint="..." gear="...">',
        )


def _limb_motors(
    path: Path, model: mujoco.MjModel, limb_joints: list[tuple[int, ...]]
) -> tuple[tuple[int, ...], ...]:
    """The motor of each limb's hinges; () for the torso. A limb needs a motor with a nonzero gear (3D
    bodies keep the benchmark's gear-0 motors on the hinges it does not drive)."""
    for actuator in range(model.nu):
        _check_motor(path, model, actuator)
    motors: list[tuple[int, ...]] = [()]
    for joints in limb_joints:
        limb_motors = []
        for joint in joints:
            driving = [a for a in range(model.nu) if model.actuator_trnid[a, 0] == joint]
            name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
            if len(driving) != 1:
                raise MorphologyError(
                    path,
                    f"joint {name!r} is driven by {len(driving)} motors; every limb joint needs exactly one <motor>",
                )
            limb_motors.append(driving[0])
        if not model.actuator_gear[limb_motors, 0].any():
            names = " and ".join(_element(model, _ACTUATOR, motor) for motor in limb_motors)
            raise MorphologyError(
                path,
                f'{names} {"has" if len(limb_motors) == 1 else "have"} gear="0", so its limb can never move; '
                "give it a nonzero gear (the benchmark's motors use 12.5 to 300)",
            )
        motors.append(tuple(limb_motors))
    return tuple(motors)


def _limb_type(spec: FamilySpec, limb: str) -> int:
    for index, keys in enumerate(spec.limb_type_rules):
        if any(key in limb for key in keys):
            return index
    return -1


def _joint_range(model: mujoco.MjModel, joint: int) -> tuple[float, float]:
    low, high = np.degrees(model.jnt_range[joint])
    return (round(float(low), 9), round(float(high), 9))


def load(name_or_path: str | Path, *, max_limbs: int | None = None) -> Morphology:
    """Describe one body: a benchmark name (``"walker_3_main"``) or the path of an MJCF file.

    Raises ``MorphologyError`` naming the file and element when the file cannot be read, is not
    well-formed XML, does not compile, breaks the body conventions above, or has more than
    ``max_limbs`` limbs.
    """
    path = resolve(name_or_path)
    root = _check_xml(path)
    _check_motor_targets(path, root)
    _check_no_free_limbs(path, root)
    _check_geom_masses(path, root)
    model = _compile(path)
    _check_numbers(path, model)
    family = _family_name(path, model)
    spec = family_spec(family, _custom_text(model, SOURCE_TEXT) or path.stem)
    _check_root(path, model, spec)
    limbs = list(range(1, model.nbody))
    if max_limbs is not None and len(limbs) > max_limbs:
        raise MorphologyError(
            path, f"{len(limbs)} limbs, more than the maximum of {max_limbs}; raise max_limbs or remove limbs"
        )
    joints = [_limb_joints(path, model, body, spec.motors_per_limb) for body in limbs[1:]]
    names = tuple(_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in limbs)
    return Morphology(
        name=path.stem,
        path=path,
        family=spec,
        limb_names=names,
        parents=tuple(int(model.body_parentid[b]) - 1 for b in limbs),
        limb_types=tuple(_limb_type(spec, "torso" if i == 0 else n) for i, n in enumerate(names)),
        joint_names=((), *(tuple(_name(model, _JOINT, j) for j in limb) for limb in joints)),
        joint_ranges=((), *(tuple(_joint_range(model, j) for j in limb) for limb in joints)),
        limb_motors=_limb_motors(path, model, joints),
        timestep=float(model.opt.timestep),
        integrator=mujoco.mjtIntegrator(model.opt.integrator).name.removeprefix("mjINT_"),
    )
