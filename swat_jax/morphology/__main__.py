"""Look at the benchmark's bodies and environment sets.

  list    the environment sets (train and test bodies, most limbs in a set) and every benchmark body
  show    one body's limb tree (limb type, joint range in degrees, motor), the positions of its limbs in
          the pre-, in- and post-order of the tree (paper eq. 3) and its three limb-pair relations
          (normalised Laplacian, shortest-path distance / limbs, personalised PageRank; paper eq. 4);
          --json prints the same as one JSON object
  render  a PNG picture of one body in its initial pose, seen from the side (headless rendering uses
          MUJOCO_GL, default egl)
  variants  variants of one body (its limbs' physical quantities scaled by drawn factors) as MJCF files,
          and a picture of them side by side

A body is a benchmark name (see `list`) or the path of an MJCF file. Errors exit with status 2.
"""

from __future__ import annotations

import dataclasses
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import imageio.v3 as iio
import numpy as np
import tyro

from swat_jax.cli import run_command, strict_json
from swat_jax.morphology.encodings import (
    RELATION_NAMES,
    TRAVERSAL_NAMES,
    relation_features,
    traversal_positions,
)
from swat_jax.morphology.mjcf import benchmark_names, load
from swat_jax.morphology.picture import RenderingUnavailable, render_initial_pose
from swat_jax.morphology.sets import SETS, EnvironmentSet
from swat_jax.morphology.types import Morphology
from swat_jax.morphology.variants import Variation, write_variants

WRAP_WIDTH = 100
PICTURE_VARIANTS = 6
"""Bodies in the variants' picture: the nominal one and the first variants."""


def limb_depths(parents: Sequence[int]) -> list[int]:
    """Depth of each limb in the tree, 0 for the torso (parents precede their children)."""
    depths: list[int] = []
    for parent in parents:
        depths.append(0 if parent < 0 else depths[parent] + 1)
    return depths


def _wrapped(label: str, names: Sequence[str]) -> str:
    text = " ".join(names) if names else "-"
    return textwrap.fill(
        text, WRAP_WIDTH, initial_indent=f"    {label}", subsequent_indent=" " * (4 + len(label))
    )


def _set_lines(environment_set: EnvironmentSet, limbs: dict[str, int]) -> list[str]:
    most = max(limbs[body] for body in environment_set.split("all"))
    return [
        f"  {environment_set.name:<16} {environment_set.description}  (at most {most} limbs)",
        _wrapped(f"train ({len(environment_set.train)}): ", environment_set.train),
        _wrapped(f"test  ({len(environment_set.test)}): ", environment_set.test),
    ]


def list_text() -> str:
    """The environment sets and the benchmark bodies, as printed by ``list``."""
    bodies = {name: load(name) for name in benchmark_names()}
    limbs = {name: body.num_limbs for name, body in bodies.items()}
    lines = [f"Environment sets ({len(SETS)}):"]
    for environment_set in SETS.values():
        lines += _set_lines(environment_set, limbs)
    width = max(map(len, bodies))
    family_width = max(len(body.family.name) for body in bodies.values())
    lines += [
        "",
        f"Benchmark bodies ({len(bodies)}):",
        f"  {'name':<{width}}  {'family':<{family_width}} limbs",
    ]
    lines += [
        f"  {name:<{width}}  {body.family.name:<{family_width}} {body.num_limbs:>5}"
        for name, body in bodies.items()
    ]
    return "\n".join(lines)


def _tree_lines(morphology: Morphology) -> list[str]:
    depths = limb_depths(morphology.parents)
    width = max(2 * d + len(n) for d, n in zip(depths, morphology.limb_names, strict=True))
    lines = []
    for limb, name in enumerate(morphology.limb_names):
        label = f"{'  ' * depths[limb]}{name}"
        head = f"  [{limb}] {label:<{width}}  type {morphology.limb_type_name(limb):<6}"
        if morphology.parents[limb] < 0:
            root = "free joint" if morphology.family.three_d else "slides along x and z, hinge for pitch"
            lines.append(f"{head}  root: {root}")
            continue
        joints = ", ".join(
            f"{name} [{low:g}, {high:g}] deg motor {motor}"
            for name, (low, high), motor in zip(
                morphology.joint_names[limb],
                morphology.joint_ranges[limb],
                morphology.limb_motors[limb],
                strict=True,
            )
        )
        lines.append(f"{head}  {joints}")
    return lines


def _table(row_labels: Sequence[str], column_labels: Sequence[str], cells: list[list[str]]) -> list[str]:
    label_width = max(map(len, row_labels))
    width = max(max(map(len, column_labels)), *(len(c) for row in cells for c in row))
    header = " " * (2 + label_width) + "".join(f" {c:>{width}}" for c in column_labels)
    rows = [
        f"  {label:<{label_width}}" + "".join(f" {c:>{width}}" for c in row)
        for label, row in zip(row_labels, cells, strict=True)
    ]
    return [header, *rows]


def show_text(morphology: Morphology, *, reference_inorder: bool = False) -> str:
    """The limb tree, traversal positions and relation matrices of one body, as printed by ``show``."""
    names = morphology.limb_names
    traversals = traversal_positions(morphology.parents, reference_inorder=reference_inorder)
    relations = relation_features(morphology.parents)
    inorder = "reference code's in-order" if reference_inorder else "true binary in-order"
    lines = [
        f"{morphology.name}: family {morphology.family.name}, {morphology.num_limbs} limbs, "
        f"timestep {morphology.timestep:g} s x frame_skip {morphology.frame_skip}, "
        f"integrator {morphology.integrator}",
        f"file: {morphology.path}",
        "",
        "Limb tree:",
        *_tree_lines(morphology),
        "",
        f"Traversal positions (left-child right-sibling binary tree, {inorder}):",
        *_table(names, TRAVERSAL_NAMES, [[str(v) for v in row] for row in traversals]),
    ]
    for channel, relation in enumerate(RELATION_NAMES):
        matrix = relations[..., channel]
        lines += [
            "",
            f"Relation {relation}:",
            *_table(names, names, [[f"{v:.3f}" for v in row] for row in matrix]),
        ]
    return "\n".join(lines)


def show_json(morphology: Morphology, *, reference_inorder: bool = False) -> dict:
    """Everything ``show`` prints, as JSON-ready values (limbs in pre-order, ranges in degrees)."""
    traversals = traversal_positions(morphology.parents, reference_inorder=reference_inorder)
    relations = relation_features(morphology.parents).astype(np.float64)
    return {
        "name": morphology.name,
        "path": str(morphology.path),
        "family": morphology.family.name,
        "limbs": list(morphology.limb_names),
        "parents": list(morphology.parents),
        "limb_types": list(morphology.limb_types),
        "limb_type_names": [morphology.limb_type_name(limb) for limb in range(morphology.num_limbs)],
        "joints": [list(names) for names in morphology.joint_names],
        "joint_ranges": [[list(r) for r in ranges] for ranges in morphology.joint_ranges],
        "motors": [list(motors) for motors in morphology.limb_motors],
        "reference_inorder": reference_inorder,
        "traversals": {kind: traversals[:, column].tolist() for column, kind in enumerate(TRAVERSAL_NAMES)},
        "relations": {
            kind: np.round(relations[..., channel], 6).tolist() for channel, kind in enumerate(RELATION_NAMES)
        },
        "timestep": morphology.timestep,
        "frame_skip": morphology.frame_skip,
        "control_dt": morphology.control_dt,
        "integrator": morphology.integrator,
    }


def write_picture(body: str, output: Path, width: int, height: int) -> None:
    """Render ``body`` in its initial pose and write it to ``output`` as PNG."""
    iio.imwrite(output, render_initial_pose(body, width, height), extension=".png")


Body = tyro.conf.Positional[str]
"""A benchmark body name (see ``list``) or the path of an MJCF file."""


@dataclasses.dataclass(frozen=True)
class ListCommand:
    """Print every environment set (description, train and test bodies, most limbs in a body of the set),
    then every benchmark body with its family and limb count."""

    def text(self) -> str:
        return list_text()


@dataclasses.dataclass(frozen=True)
class ShowCommand:
    """Print one body's limb tree, the position of each limb in the pre-, in- and post-order traversals,
    and the laplacian, spd and ppr relation matrices (3 decimals)."""

    body: Body
    """Benchmark body name (see `list`) or MJCF file path."""
    reference_inorder: bool = False
    """Use the original code's in-order: a childless limb is listed after its next sibling's subtree."""
    json: bool = False
    """Print one JSON object instead of tables."""

    def text(self) -> str:
        morphology = load(self.body)
        if self.json:
            return strict_json(show_json(morphology, reference_inorder=self.reference_inorder))
        return show_text(morphology, reference_inorder=self.reference_inorder)


@dataclasses.dataclass(frozen=True)
class RenderCommand:
    """Render one body in its initial pose (qpos0), seen from the side, to a PNG file. Rendering is
    off-screen; MUJOCO_GL picks the OpenGL backend (egl, osmesa or glfw; default egl)."""

    body: Body
    """Benchmark body name (see `list`) or MJCF file path."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """PNG file to write."""
    width: int = 640
    """Image width in pixels."""
    height: int = 480
    """Image height in pixels."""

    def text(self) -> str:
        write_picture(self.body, self.output, self.width, self.height)
        return f"wrote {self.output} ({self.width} x {self.height})"


@dataclasses.dataclass(frozen=True)
class VariantsCommand:
    """Draw variants of one body (the same limbs, their lengths, radii, masses, joint ranges, damping and
    motor gears each scaled by a factor uniform in [1 - variation, 1 + variation]), write each as its own
    MJCF file in --out, and a PNG of the nominal body and the first variants side by side."""

    body: Body
    """Benchmark body name (see `list`) or MJCF file path."""
    out: Path
    """Folder to write the variants' MJCF files (<body>__s<seed>v<index>.xml) and <body>_variants.png."""
    count: Annotated[int, tyro.conf.arg(aliases=("-k",))] = 8
    """Number of variants."""
    variation: float = 0.2
    """Spread of the factors, in [0, 1): each is uniform in [1 - variation, 1 + variation]."""
    seed: int = 0
    """Seed of the draw: the same seed writes the same variants."""
    picture: bool = True
    """Also write the picture (needs OpenGL, like render)."""

    def text(self) -> str:
        variants = write_variants(self.body, self.count, Variation(self.variation, self.seed), self.out)
        lines = [f"wrote {len(variants)} variants of {load(self.body).name} in {self.out}"]
        if self.picture:
            shown = [load(self.body), *variants[: PICTURE_VARIANTS - 1]]
            picture = self.out / f"{shown[0].name}_variants.png"
            iio.imwrite(
                picture, np.hstack([render_initial_pose(body, 320, 400) for body in shown]), extension=".png"
            )
            lines.append(f"wrote {picture}: the nominal body, then variants 0-{len(shown) - 2}")
        return "\n".join(lines)


MorphologyCommand = (
    Annotated[ListCommand, tyro.conf.subcommand("list")]
    | Annotated[ShowCommand, tyro.conf.subcommand("show")]
    | Annotated[RenderCommand, tyro.conf.subcommand("render")]
    | Annotated[VariantsCommand, tyro.conf.subcommand("variants")]
)
"""``python -m swat_jax.morphology list|show|render|variants``."""


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad body, set, size or rendering failure)."""
    return run_command(
        MorphologyCommand,
        lambda command: command.text(),
        argv,
        (ValueError, RenderingUnavailable, OSError),
        prog="python -m swat_jax.morphology",
    )


if __name__ == "__main__":
    sys.exit(main())
