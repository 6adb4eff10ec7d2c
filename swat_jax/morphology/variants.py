"""Variants of a body: the same tree of limbs with its physical quantities drawn around the nominal ones.

A variant keeps the topology (limb names, parents, joints, motors), so it has the body's structural
encodings and every array shape of its MJX model; only numbers change. For each limb, six factors are
drawn independently from ``U[1 - spread, 1 + spread]`` (:data:`QUANTITIES`):

  length       the limb's geoms (``fromto`` endpoints, or ``pos`` and the half-length of a capsule or
               cylinder) and its children's joint anchors, scaled about the limb's own joint anchor (the
               torso's: its origin), so that every child stays attached where the limb now ends
  radius       the radius of the limb's geoms
  mass         the density of the limb's geoms: the limb weighs the factor times what its resized shape
               weighs at the nominal density
  joint_range  both limits of the limb's hinge (a range of [-150, 0] degrees with 1.1 becomes [-165, 0])
  damping      the hinge's damping
  gear         the gear of the limb's motor

Longer or shorter limbs would start the body in the floor or in the air, so the torso is then raised or
lowered (its ``pos`` and the height joint's ``ref`` together) until the body's lowest point is as high
above the floor as the nominal body's. The torso has no hinge and no motor, so its last three factors are drawn and unused (every body draws
the same ``[limbs, 6]`` table from a seed). MuJoCo's model editing (``mujoco.MjSpec``) applies the
factors and compiles the variant, so masses, inertias and the bodies' frames are computed by MuJoCo from
the edited geometry, never scaled as arrays. A variant's MJCF records the body it was drawn from
(``swat_source``), whose family constants (termination heights, reset noise) it keeps.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np

from swat_jax.morphology.mjcf import SOURCE_TEXT, MorphologyError, compile_model, load
from swat_jax.morphology.types import Morphology

QUANTITIES = ("length", "radius", "mass", "joint_range", "damping", "gear")
"""The per-limb factors of a variant, in the order of the last axis of :func:`draw_factors`."""
ELONGATED = (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER)
"""Geom types whose second size is a half-length along the geom's axis."""


@dataclasses.dataclass(frozen=True)
class Variation:
    """How variants are drawn: each factor uniform in [1 - spread, 1 + spread], from ``seed``."""

    spread: float = 0.2
    """Half-width of the factors' interval, in [0, 1)."""
    seed: int = 0
    """Seed of the draw; the same seed draws the same factors."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.spread < 1.0:
            raise ValueError(
                f"the variation's spread must lie in [0, 1) (factors in [1 - spread, 1 + spread] must stay "
                f"positive), got {self.spread}"
            )

    def factors(self, num_limbs: int, count: int) -> np.ndarray:
        """[count, num_limbs, 6] float64 factors of ``count`` variants (:data:`QUANTITIES` order)."""
        rng = np.random.default_rng(self.seed)
        return rng.uniform(1.0 - self.spread, 1.0 + self.spread, (count, num_limbs, len(QUANTITIES)))


def _rotated(vector: np.ndarray, quat: np.ndarray) -> np.ndarray:
    result = np.zeros(3)
    mujoco.mju_rotVecQuat(result, np.asarray(vector, np.float64), np.asarray(quat, np.float64))
    return result


def _anchor(body: mujoco.MjsBody) -> np.ndarray:
    """The limb's joint anchor in its own frame (its origin for the torso, whose joints slide)."""
    hinges = [joint for joint in body.joints if joint.type == mujoco.mjtJoint.mjJNT_HINGE]
    return np.array(hinges[0].pos if hinges and body.parent.name != "world" else np.zeros(3), np.float64)


def _scale_geometry(body: mujoco.MjsBody, length: float, radius: float, mass: float) -> None:
    anchor = _anchor(body)
    for geom in body.geoms:
        if np.all(np.isfinite(geom.fromto)):
            ends = np.asarray(geom.fromto, np.float64).reshape(2, 3)
            geom.fromto = (anchor + length * (ends - anchor)).reshape(6)
        else:
            geom.pos = anchor + length * (np.asarray(geom.pos, np.float64) - anchor)
            if geom.type in ELONGATED:
                geom.size[1] *= length
        geom.size[0] *= radius
        if np.isfinite(geom.mass):
            geom.mass *= mass
        else:
            geom.density *= mass
    for site in body.sites:
        site.pos = anchor + length * (np.asarray(site.pos, np.float64) - anchor)
    for child in body.bodies:
        child_anchor = np.asarray(child.pos, np.float64) + _rotated(_anchor(child), child.quat)
        moved = anchor + length * (child_anchor - anchor)
        child.pos = np.asarray(child.pos, np.float64) + (moved - child_anchor)


def _scale_joint_and_motor(spec: mujoco.MjSpec, body: mujoco.MjsBody, factors: np.ndarray) -> None:
    joint_range, damping, gear = factors
    for joint in body.joints:
        joint.range = np.asarray(joint.range, np.float64) * joint_range
        joint.damping = np.asarray(joint.damping, np.float64) * damping
        for actuator in spec.actuators:
            if actuator.target == joint.name:
                actuator.gear[0] *= gear


def lowest_point(model: mujoco.MjModel) -> float:
    """Height of the lowest point of the body's geoms (the floor, attached to the world, excluded) at qpos0:
    exact for capsules, cylinders and spheres, the bounding sphere for other shapes."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    lowest = np.inf
    for geom in np.flatnonzero(model.geom_bodyid > 0):
        radius, half = model.geom_size[geom, :2]
        centre, axis = data.geom_xpos[geom], data.geom_xmat[geom].reshape(3, 3)[:, 2]
        if model.geom_type[geom] in ELONGATED:
            bottom = centre[2] - abs(axis[2]) * half - radius
        elif model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_SPHERE:
            bottom = centre[2] - radius
        else:
            bottom = centre[2] - model.geom_rbound[geom]
        lowest = min(lowest, float(bottom))
    return lowest


def _keep_clearance(spec: mujoco.MjSpec, torso: str, clearance: float) -> None:
    """Raise or lower the torso so that the lowest point of the edited body is ``clearance`` above the floor."""
    shift = clearance - lowest_point(spec.compile())
    body = spec.body(torso)
    body.pos = np.asarray(body.pos, np.float64) + np.array([0.0, 0.0, shift])
    for joint in body.joints:
        if joint.type == mujoco.mjtJoint.mjJNT_SLIDE and np.allclose(joint.axis, (0.0, 0.0, 1.0)):
            joint.ref += shift


def variant_spec(
    morphology: Morphology, factors: np.ndarray, clearance: float | None = None
) -> mujoco.MjSpec:
    """The MjSpec of ``morphology`` with the per-limb ``factors`` [num_limbs, 6] applied (module docstring).
    ``clearance``: the nominal body's :func:`lowest_point`, when already known (it is computed otherwise).

    Raises:
        ValueError: ``factors`` is not [num_limbs, 6] of positive finite numbers, or MuJoCo refuses the
            edited body (mujoco's own message).
    """
    factors = np.asarray(factors, np.float64)
    if factors.shape != (morphology.num_limbs, len(QUANTITIES)) or not np.all(
        np.isfinite(factors) & (factors > 0)
    ):
        raise ValueError(
            f"{morphology.name}: factors must be [{morphology.num_limbs}, {len(QUANTITIES)}] positive finite "
            f"numbers (limbs x {', '.join(QUANTITIES)}), got shape {factors.shape}"
        )
    spec = mujoco.MjSpec.from_file(str(morphology.path))
    if clearance is None:
        clearance = lowest_point(spec.compile())
    for limb, name in enumerate(morphology.limb_names):
        body = spec.body(name)
        _scale_geometry(body, *factors[limb, :3])
        if limb > 0:
            _scale_joint_and_motor(spec, body, factors[limb, 3:])
    _keep_clearance(spec, morphology.limb_names[0], clearance)
    return spec


def variant_name(body: str, seed: int, index: int) -> str:
    """The file stem of variant ``index`` of ``body`` drawn from ``seed``."""
    return f"{body}__s{seed}v{index}"


def write_variants(
    body: str | Path, count: int, variation: Variation, directory: str | Path
) -> list[Morphology]:
    """Draw ``count`` variants of ``body`` (a benchmark name or MJCF path), write each as its own MJCF file
    in ``directory`` (``<body>__s<seed>v<index>.xml``) and load them.

    Raises:
        MorphologyError: the body cannot be loaded, or MuJoCo refuses a variant: the message names the
            body, the limb and the drawn factors.
        ValueError: ``count`` below 1.
    """
    if count < 1:
        raise ValueError(f"the number of variants must be at least 1, got {count}")
    nominal = load(body)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    clearance = lowest_point(compile_model(nominal))
    variants = []
    for index, factors in enumerate(variation.factors(nominal.num_limbs, count)):
        try:
            spec = variant_spec(nominal, factors, clearance)
        except ValueError as error:
            raise MorphologyError(
                nominal.path,
                f"MuJoCo refuses variant {index} (seed {variation.seed}, spread {variation.spread}): {error}; "
                f"its factors per limb ({', '.join(QUANTITIES)}): {_factor_text(nominal, factors)}",
            ) from None
        spec.add_text(name=SOURCE_TEXT, data=nominal.name)
        path = directory / f"{variant_name(nominal.name, variation.seed, index)}.xml"
        path.write_text(spec.to_xml())
        variants.append(load(path))
    return variants


def _factor_text(morphology: Morphology, factors: np.ndarray) -> str:
    return "; ".join(
        f"{name} {' '.join(f'{value:.4g}' for value in row)}"
        for name, row in zip(morphology.limb_names, factors, strict=True)
    )
