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
    """Per-step reward: forward_weight * dx/dt + alive_bonus - control_cost * sum(a^2)."""

    alive_bonus: float
    control_cost: float
    forward_weight: float = 1.0


@dataclasses.dataclass(frozen=True)
class Termination:
    """When an episode ends early; every field set to None/False is not checked.

    h = qpos[1] (torso height joint), angle = qpos[2] (torso pitch joint).
    The body stays alive while every enabled condition holds.
    """

    height: tuple[float, float] | None = None
    """Open interval (lo, hi) for h; use math.inf for an unbounded side."""
    max_abs_angle: float | None = None
    """abs(angle) must stay below this."""
    bounded_state: bool = False
    """State finite and abs(qpos[2:]), abs(qvel) below 100."""
    site_min_heights: tuple[tuple[str, float], ...] = ()
    """(site name, z) pairs: the site's world z must stay above z."""


@dataclasses.dataclass(frozen=True)
class ResetNoise:
    """Noise added to the initial qpos / qvel at reset."""

    qpos_uniform: float
    """qpos += U(-qpos_uniform, qpos_uniform)."""
    qvel_scale: float
    """qvel += U(-s, s) when qvel_gaussian is False, else N(0, s^2)."""
    qvel_gaussian: bool = False


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

    @property
    def num_limb_types(self) -> int:
        return len(self.limb_type_rules)


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
    joint_names: tuple[str | None, ...]
    """The hinge joint of each non-torso limb."""
    joint_ranges: tuple[tuple[float, float] | None, ...]
    """Joint range of each non-torso limb, in degrees."""
    limb_motors: tuple[int, ...]
    """Index of the actuator driving each limb's joint, -1 for the torso."""
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

    def joint_range_array(self) -> np.ndarray:
        """Joint ranges in degrees, float32 [num_limbs, 2]; zeros for the torso."""
        return np.array([r if r is not None else (0.0, 0.0) for r in self.joint_ranges], np.float32)

    def limb_type_name(self, limb: int) -> str:
        """The first key of the family's rule that typed ``limb`` (e.g. "thigh"), "none" for an untyped limb."""
        index = self.limb_types[limb]
        return self.family.limb_type_rules[index][0] if index >= 0 else "none"

    def children(self, limb: int) -> tuple[int, ...]:
        """Child limbs of ``limb`` in pre-order."""
        return tuple(i for i, p in enumerate(self.parents) if p == limb)
