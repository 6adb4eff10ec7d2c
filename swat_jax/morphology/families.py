"""The benchmark's family constants: limb-type vocabulary, reward, termination and reset noise.

One table row per family (docs/bodies-and-environments.md, "Environments (MuJoCo MJX)", states what they mean); the few
bodies whose numbers differ from their family's (termination heights that grow with leg length, and
the five Animal-Walkers, each with its own reward and termination) are listed below it by name.
The 3D families (SGRL's benchmark: a free torso, up to three hinges per limb, a target to walk
toward) have a second row each for their ``_v2`` bodies, whose targets are near.
A body's family is declared in its MJCF (``<custom><text name="swat_family" data="..."/></custom>``).
"""

from __future__ import annotations

import dataclasses
import math

from swat_jax.morphology.types import FamilySpec, ResetNoise, Reward, Target, Termination

MODULAR_LIMB_TYPES = (("torso",), ("thigh", "1"), ("leg", "shin", "2"), ("foot", "3"))
"""T = 4 types of Hopper/Walker/Cheetah/Humanoid++; humanoid arms match none (all-zero one-hot)."""
NERVENET_LIMB_TYPES = (("torso",), ("thigh",), ("leg",), ("foot",), ("head",), ("tail",))
"""T = 6 types of the Animal-Walkers (NerveNet) bodies."""
SGRL_LIMB_TYPES = (("torso",), ("thigh",), ("shin",), ("foot",))
"""T = 4 types of the 3D bodies; arms, tails and the 3D walkers' legs match none."""
FAR_TARGET = Target(distance=(10_000.0, 10_000.0), from_torso=False)
"""SGRL's first task: a point 10 km away, in effect a direction to walk in."""
NEAR_TARGET = Target(distance=(10.0, 20.0), from_torso=True)
"""SGRL's ``_v2`` task: a point 10 to 20 m away, and a new one each time the torso reaches it."""

ALIVE_REWARD = Reward(alive_bonus=1.0, control_cost=1e-3)
RUNNER_REWARD = Reward(alive_bonus=0.0, control_cost=0.1)
SMALL_NOISE = ResetNoise(qpos_uniform=0.005, qvel_scale=0.005)
CHEETAH_NOISE = ResetNoise(qpos_uniform=0.1, qvel_scale=0.1, qvel_gaussian=True)
NEVER = Termination()
UPRIGHT = 1.0
"""Largest torso pitch (rad) of the upright families."""


def _hopper(min_height: float) -> Termination:
    return Termination(height=(min_height, math.inf), max_abs_angle=UPRIGHT, bounded_state=True)


def _upright(low: float, high: float) -> Termination:
    return Termination(height=(low, high), max_abs_angle=UPRIGHT)


def _cheetah(*sites: tuple[str, float]) -> Termination:
    return Termination(bounded_state=True, site_min_heights=(("front", 0.7), ("back", 0.7), *sites))


def _hopper_3d(min_height: float) -> Termination:
    return Termination(height=(min_height, math.inf), max_tilt=UPRIGHT, bounded_state=True)


def _upright_3d(low: float, high: float) -> Termination:
    return Termination(height=(low, high), max_pitch_roll=UPRIGHT)


CHEETAH_3D = Termination(
    height=(0.26, math.inf),
    max_pitch_roll=1.35,
    height_bodies=("right_fthigh", "left_fthigh"),
    min_speed_squared=1.0,
)
"""The 3D cheetahs end when the torso or a front thigh comes within 0.26 of the floor, the torso
pitches or rolls past 1.35 rad, or the body all but stops."""
HUMANOID_3D_DROP = 0.165375
"""The 3D humanoids' torso frame sits this far below the 2D humanoid's, and so do their heights."""
WALKER_REWARD_3D = Reward(alive_bonus=1.0, control_cost=1e-3, heading_weight=1.0)
THREE_D: dict[str, tuple[Reward, Termination, ResetNoise]] = {
    "3d_hopper": (ALIVE_REWARD, _hopper_3d(0.95), SMALL_NOISE),
    "3d_walker": (WALKER_REWARD_3D, _upright_3d(0.8, 2.0), SMALL_NOISE),
    "3d_humanoid": (
        WALKER_REWARD_3D,
        _upright_3d(1.0 - HUMANOID_3D_DROP, 2.0 - HUMANOID_3D_DROP),
        SMALL_NOISE,
    ),
    "3d_cheetah": (Reward(alive_bonus=0.0, control_cost=1e-3, heading_weight=1.0), CHEETAH_3D, CHEETAH_NOISE),
}
"""Reward, termination and reset noise of each 3D family (its first and ``_v2`` rows share them)."""


FAMILIES: dict[str, FamilySpec] = {
    spec.name: spec
    for spec in (
        FamilySpec("hopper", MODULAR_LIMB_TYPES, ALIVE_REWARD, _hopper(0.7), SMALL_NOISE),
        FamilySpec("walker", MODULAR_LIMB_TYPES, ALIVE_REWARD, _upright(0.8, 2.0), SMALL_NOISE),
        FamilySpec("cheetah", MODULAR_LIMB_TYPES, RUNNER_REWARD, NEVER, CHEETAH_NOISE),
        FamilySpec("humanoid", MODULAR_LIMB_TYPES, ALIVE_REWARD, _upright(0.4, 2.1), SMALL_NOISE),
        FamilySpec("nervenet", NERVENET_LIMB_TYPES, ALIVE_REWARD, _upright(0.8, 2.0), SMALL_NOISE),
        *(
            FamilySpec(name + suffix, SGRL_LIMB_TYPES, *constants, target=target)
            for name, constants in THREE_D.items()
            for suffix, target in (("", FAR_TARGET), ("_v2", NEAR_TARGET))
        ),
    )
}
"""Family defaults; a new body declaring one of these families gets exactly these constants."""

BODY_OVERRIDES: dict[str, dict[str, object]] = {
    "hopper_3": dict(termination=_hopper(0.45)),
    "hopper_4": dict(termination=_hopper(0.6)),
    "hopper_5": dict(termination=_hopper(0.95)),
    **{
        f"walker_{n}_{k}": dict(termination=_upright(0.54, 1.74)) for n in (2, 3) for k in ("main", "flipped")
    },
    **{f"walker_4_{k}": dict(termination=_upright(0.664, 1.864)) for k in ("main", "flipped")},
    **{
        f"3d_hopper{version}_{body}": dict(termination=_hopper_3d(height))
        for version in ("", "_v2")
        for body, height in (("3_shin", 0.45), ("4_lower_shin", 0.6))
    },
    **{
        f"3d_walker{version}_{body}": dict(termination=_upright_3d(*heights))
        for version in ("", "_v2")
        for body, heights in (
            ("2_right_leg_left_knee", (0.54, 1.74)),
            ("3_left_knee_right_knee", (0.54, 1.74)),
            ("3_left_leg_right_foot", (0.664, 2.0)),
            ("4_right_knee_left_foot", (0.664, 1.864)),
            ("5_left_knee", (0.664, 2.0)),
        )
    },
    "nervenet_hopper": dict(
        termination=Termination(height=(0.7, math.inf), max_abs_angle=0.2, bounded_state=True)
    ),
    "nervenet_ostrich": dict(
        termination=dataclasses.replace(_upright(0.8, 2.0), site_min_heights=(("head", 1.1),))
    ),
    "nervenet_fullcheetah": dict(
        reward=dataclasses.replace(RUNNER_REWARD, alive_bonus=1.0),
        termination=_cheetah(),
        reset_noise=CHEETAH_NOISE,
    ),
    "nervenet_halfcheetah": dict(
        reward=dataclasses.replace(RUNNER_REWARD, alive_bonus=1.0),
        termination=_cheetah(("tip", 1.2)),
        reset_noise=CHEETAH_NOISE,
    ),
}
"""Per-body differences from the family row, keyed by body name (the MJCF file's stem)."""


def family_spec(family: str, body: str) -> FamilySpec:
    """The constants for ``body`` of ``family``: the family row with the body's overrides applied.

    Raises ValueError naming the valid families when ``family`` is unknown.
    """
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; valid families: {', '.join(FAMILIES)}")
    return dataclasses.replace(FAMILIES[family], **BODY_OVERRIDES.get(body, {}))
