"""Immutable descriptions of one modular body and of its family's constants.

A body is a tree of limbs (MuJoCo bodies below the world); each limb becomes one
token of the policy (paper section 3). Everything the environment and the
networks need about a body is here, as plain Python values and NumPy arrays.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np


@dataclasses.dataclass(frozen=True)
class Reward:
    """Per-step reward: forward_weight * progress + heading_weight * v_heading + alive_bonus - control_cost * sum(a^2).

    Progress is dx/dt in the plane, and in 3D (a family with a :class:`Target`) the rate at which the
    torso's distance to the target shrinks; v_heading (3D only) is the torso's horizontal velocity along
    its heading at the start of the step.
    """

    alive_bonus: float
    control_cost: float
    forward_weight: float = 1.0
    heading_weight: float = 0.0


@dataclasses.dataclass(frozen=True)
class Termination:
    """When an episode ends early; every field set to None/False is not checked.

    Planar bodies: h = qpos[1] (torso height joint), angle = qpos[2] (torso pitch joint). 3D bodies (free
    torso): h = qpos[2], the torso's height. The body stays alive while every enabled condition holds.
    """

    height: tuple[float, float] | None = None
    """Open interval (lo, hi) for h; use math.inf for an unbounded side."""
    max_abs_angle: float | None = None
    """abs(angle) must stay below this."""
    bounded_state: bool = False
    """State finite and abs(qvel) and abs(qpos) below 100, the torso's position coordinates excepted
    (qpos[2:] planar, qpos[3:] in 3D)."""
    site_min_heights: tuple[tuple[str, float], ...] = ()
    """(site name, z) pairs: the site's world z must stay above z."""
    max_tilt: float | None = None
    """3D: the angle (rad) between the torso's z axis and the vertical must stay below this."""
    max_pitch_roll: float | None = None
    """3D: abs(pitch) and abs(roll) of the torso at the start of the step must stay below this."""
    height_bodies: tuple[str, ...] = ()
    """3D: h is the lowest of the torso's height and these limbs' frame heights (those the body has)."""
    min_speed_squared: float | None = None
    """3D: sum(qvel^2) must stay above this (a body that stops moving ends its episode)."""


@dataclasses.dataclass(frozen=True)
class ResetNoise:
    """Noise added to the initial qpos / qvel at reset."""

    qpos_uniform: float
    """qpos += U(-qpos_uniform, qpos_uniform)."""
    qvel_scale: float
    """qvel += U(-s, s) when qvel_gaussian is False, else N(0, s^2)."""
    qvel_gaussian: bool = False


@dataclasses.dataclass(frozen=True)
class Target:
    """The 3D task (SGRL): walk toward a point on the floor, placed at a random direction at reset and
    again each time the torso comes within ``reach`` of it."""

    distance: tuple[float, float]
    """The new point's distance, uniform in [low, high]: (10000, 10000) far away (SGRL's first task), or
    (10, 20) nearby (its ``_v2`` bodies)."""
    from_torso: bool
    """A point placed once the torso reached the last one is that far from the torso (True), or from the
    origin (False); at reset both are from the origin."""
    reach: float = 1.0


@dataclasses.dataclass(frozen=True)
class FamilySpec:
    """Constants shared by every body of a family (see families.py)."""

    name: str
    limb_type_rules: tuple[tuple[str, ...], ...]
    """Type t is the first rule whose substrings occur in the limb name; rule 0 is the torso.
    A name that matches no rule has type -1 (an all-zero one-hot)."""
    reward: Reward
    termination: Termination
    reset_noise: ResetNoise
    frame_skip: int = 4
    max_episode_steps: int = 1000
    target: Target | None = None
    """The 3D task; None: a planar body rewarded for moving along x."""

    @property
    def num_limb_types(self) -> int:
        return len(self.limb_type_rules)

    @property
    def three_d(self) -> bool:
        """The family's bodies have a free torso and walk toward a target (SGRL's 3D benchmark)."""
        return self.target is not None

    @property
    def motors_per_limb(self) -> int:
        """M, the actions of one limb token: one per hinge, 1 planar, up to 3 in 3D (x, y and z)."""
        return 3 if self.three_d else 1


@dataclasses.dataclass(frozen=True)
class Morphology:
    """One body: limbs in MJCF pre-order, limb 0 is the torso.

    Per-limb tuples all have length ``num_limbs``; the torso's joint fields are None.
    """

    name: str
    path: Path
    family: FamilySpec
    limb_names: tuple[str, ...]
    parents: tuple[int, ...]
    """Parent limb index per limb, -1 for the torso."""
    limb_types: tuple[int, ...]
    """Index into family.limb_type_rules, -1 when no rule matches."""
    joint_names: tuple[tuple[str, ...], ...]
    """The hinges of each limb, in MJCF order: one per limb planar, one to three in 3D; () for the torso."""
    joint_ranges: tuple[tuple[tuple[float, float], ...], ...]
    """The range of each limb's hinges, in degrees."""
    limb_motors: tuple[tuple[int, ...], ...]
    """The actuator driving each of a limb's hinges."""
    timestep: float
    integrator: str

    @property
    def num_limbs(self) -> int:
        return len(self.limb_names)

    @property
    def frame_skip(self) -> int:
        return self.family.frame_skip

    @property
    def control_dt(self) -> float:
        """Seconds per environment step (frame_skip x timestep)."""
        return self.frame_skip * self.timestep

    @property
    def motors_per_limb(self) -> int:
        """M, the actions of one limb token (the family's)."""
        return self.family.motors_per_limb

    def joint_range_array(self) -> np.ndarray:
        """Joint ranges in degrees, float32 [n, M, 2]; zeros where a limb has no hinge (the torso)."""
        ranges = np.zeros((self.num_limbs, self.motors_per_limb, 2), np.float32)
        for limb, limb_ranges in enumerate(self.joint_ranges):
            for slot, joint_range in enumerate(limb_ranges):
                ranges[limb, slot] = joint_range
        return ranges

    def motor_mask(self) -> np.ndarray:
        """[n, M] bool: the limb has a hinge (and its motor) in this action slot."""
        return (
            np.arange(self.motors_per_limb)[None, :] < np.array([len(j) for j in self.joint_names])[:, None]
        )

    def limb_type_name(self, limb: int) -> str:
        """The first key of the family's rule that typed ``limb`` (e.g. "thigh"), "none" for an untyped limb."""
        index = self.limb_types[limb]
        return self.family.limb_type_rules[index][0] if index >= 0 else "none"

    def children(self, limb: int) -> tuple[int, ...]:
        """Child limbs of ``limb`` in pre-order."""
        return tuple(i for i, p in enumerate(self.parents) if p == limb)
