"""Writes the benchmark's variant bodies from each family's intact body.

Every variant of a family is its intact body (a hand-written MJCF file in ``morphologies/``) with limbs
removed. Removing a limb deletes its body, joint, geoms, sites and motor; children of a removed limb
that stay are re-attached to its parent at the removed limb's joint anchor, which is how the short
Hopper++ legs are built (hopper_5 without ``leg`` and ``lower_leg`` is hopper_3). The files are edited
as XML, so the variants keep the source's degrees, ``fromto`` capsules and defaults exactly.

    python -m swat_jax.morphology.generate            # rewrite the variant files in morphologies/
    python -m swat_jax.morphology.generate --check    # exit 1 if a checked-in file differs
"""

from __future__ import annotations

import dataclasses
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import tyro

from swat_jax.morphology.paths import MORPHOLOGY_DIR


@dataclasses.dataclass(frozen=True)
class Variant:
    """A body derived from ``source`` (an intact body's name) by removing ``removed`` limbs."""

    source: str
    removed: tuple[str, ...] = ()
    torso_height: float | None = None
    """New torso z; the height joint's reference moves with it. None keeps the source's."""


def _walkers() -> dict[str, Variant]:
    removed = {
        2: ("left2", "left3", "right1", "right2", "right3"),
        3: ("left2", "left3", "right2", "right3"),
        4: ("left3", "right2", "right3"),
        5: ("left3", "right3"),
        6: ("right3",),
        7: (),
    }
    # The flipped walkers have the main walkers' bodies (as in the original code).
    return {
        f"walker_{n}_{kind}": Variant("walker_7_main", limbs)
        for n, limbs in removed.items()
        for kind in ("main", "flipped")
        if (n, kind) != (7, "main")
    }


def _cheetahs() -> dict[str, Variant]:
    kept = {
        "cheetah_2_back": "bthigh",
        "cheetah_2_front": "fthigh",
        "cheetah_3_back": "bthigh bshin",
        "cheetah_3_balanced": "bthigh fthigh",
        "cheetah_3_front": "fthigh fshin",
        "cheetah_4_allback": "bthigh bshin bfoot",
        "cheetah_4_allfront": "fthigh fshin ffoot",
        "cheetah_4_back": "bthigh bshin fthigh",
        "cheetah_4_front": "bthigh fthigh fshin",
        "cheetah_5_back": "bthigh bshin bfoot fthigh",
        "cheetah_5_balanced": "bthigh bshin fthigh fshin",
        "cheetah_5_front": "bthigh fthigh fshin ffoot",
        "cheetah_6_back": "bthigh bshin bfoot fthigh fshin",
        "cheetah_6_front": "bthigh bshin fthigh fshin ffoot",
    }
    limbs = ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")
    return {
        name: Variant("cheetah_7_full", tuple(limb for limb in limbs if limb not in keep.split()))
        for name, keep in kept.items()
    }


VARIANTS: dict[str, Variant] = {
    "hopper_3": Variant("hopper_5", ("leg", "lower_leg"), torso_height=1.25),
    "hopper_4": Variant("hopper_5", ("lower_leg",), torso_height=1.25),
    **_walkers(),
    **_cheetahs(),
    "humanoid_2d_7_left_arm": Variant("humanoid_2d_9_full", ("left_upper_arm", "left_lower_arm")),
    "humanoid_2d_7_left_leg": Variant("humanoid_2d_9_full", ("left_thigh", "left_shin")),
    "humanoid_2d_7_lower_arms": Variant("humanoid_2d_9_full", ("right_lower_arm", "left_lower_arm")),
    "humanoid_2d_7_right_arm": Variant("humanoid_2d_9_full", ("right_upper_arm", "right_lower_arm")),
    "humanoid_2d_7_right_leg": Variant("humanoid_2d_9_full", ("right_thigh", "right_shin")),
    "humanoid_2d_8_left_knee": Variant("humanoid_2d_9_full", ("left_shin",)),
    "humanoid_2d_8_right_knee": Variant("humanoid_2d_9_full", ("right_shin",)),
}


def _vector(element: ET.Element, attribute: str) -> list[float]:
    return [float(v) for v in element.get(attribute, "0 0 0").split()]


def _format(values: list[float]) -> str:
    return " ".join(f"{v:.10g}" for v in values)


def _hinge(body: ET.Element) -> ET.Element:
    joints = body.findall("joint")
    if len(joints) != 1:
        raise ValueError(
            f"body {body.get('name')!r} must have exactly one joint to be removed, has {len(joints)}"
        )
    return joints[0]


def _splice_out(parent: ET.Element, body: ET.Element) -> None:
    """Remove ``body`` from ``parent``; its child bodies take its place, anchored at its joint."""
    if any(body.get(key) for key in ("quat", "euler", "axisangle", "xyaxes", "zaxis")):
        raise ValueError(f"body {body.get('name')!r} is rotated; removing it would need a frame change")
    anchor = [p + j for p, j in zip(_vector(body, "pos"), _vector(_hinge(body), "pos"), strict=True)]
    index = list(parent).index(body)
    for offset, child in enumerate(body.findall("body")):
        child_joint = _vector(_hinge(child), "pos")
        child.set("pos", _format([a - j for a, j in zip(anchor, child_joint, strict=True)]))
        parent.insert(index + 1 + offset, child)
    parent.remove(body)


def _remove_limbs(root: ET.Element, removed: tuple[str, ...]) -> None:
    """Remove limbs deepest first, so chains of removed limbs collapse onto the first kept ancestor."""
    parent_of = {child: parent for parent in root.iter() for child in parent}
    bodies = {body.get("name"): body for body in root.iter("body")}
    missing = sorted(set(removed) - set(bodies))
    if missing:
        raise ValueError(f"cannot remove unknown limbs {missing}")
    joints = {_hinge(bodies[name]).get("name") for name in removed}
    for body in reversed(list(root.iter("body"))):
        if body.get("name") in removed:
            _splice_out(parent_of[body], body)
    actuator = root.find("actuator")
    for motor in list(actuator):
        if motor.get("joint") in joints:
            actuator.remove(motor)


def _move_torso(root: ET.Element, height: float) -> None:
    torso = root.find("worldbody/body")
    position = _vector(torso, "pos")
    shift = height - position[2]
    torso.set("pos", _format([position[0], position[1], height]))
    height_joint = torso.findall("joint")[1]
    height_joint.set("ref", _format([float(height_joint.get("ref", "0")) + shift]))


def derive(name: str, variant: Variant, source_text: str) -> str:
    """The MJCF text of ``variant`` (called ``name``) from the text of its source body."""
    root = ET.fromstring(source_text)
    root.set("model", name)
    _remove_limbs(root, variant.removed)
    if variant.torso_height is not None:
        _move_torso(root, variant.torso_height)
    ET.indent(root, space="  ")
    removed = ", ".join(variant.removed) if variant.removed else "nothing"
    header = (
        f"<!-- Generated by `python -m swat_jax.morphology.generate`; do not edit.\n"
        f"     {name} is {variant.source} with these limbs removed: {removed}. -->\n"
    )
    return header + ET.tostring(root, encoding="unicode") + "\n"


def generate(directory: Path = MORPHOLOGY_DIR) -> dict[Path, str]:
    """Every variant's path and MJCF text, derived from the intact bodies in ``directory``."""
    sources = {v.source: (directory / f"{v.source}.xml").read_text() for v in VARIANTS.values()}
    return {directory / f"{name}.xml": derive(name, v, sources[v.source]) for name, v in VARIANTS.items()}


@dataclasses.dataclass(frozen=True)
class GenerateCommand:
    """Write the benchmark's variant bodies (intact bodies with limbs removed) from each family's intact
    body, or with --check only compare them."""

    check: bool = False
    """Only compare; exit 1 if a file differs."""
    dir: Path = MORPHOLOGY_DIR
    """Folder of the intact bodies."""


def main(argv: list[str] | None = None) -> int:
    """Write (or check) the variant files; returns 1 when --check finds a stale one."""
    command = tyro.cli(GenerateCommand, args=argv, prog="python -m swat_jax.morphology.generate")
    stale = []
    for path, text in generate(command.dir).items():
        if not path.exists() or path.read_text() != text:
            stale.append(path.name)
            if not command.check:
                path.write_text(text)
    verb = "differ from the generator" if command.check else "written"
    print(
        f"{len(stale)} of {len(VARIANTS)} variant files {verb}" + (f": {', '.join(stale)}" if stale else "")
    )
    return 1 if command.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
