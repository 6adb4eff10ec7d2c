"""The benchmark's environment sets (train and held-out test bodies), and folders of MJCF files.

Splits as AMORPHEUS and SWAT used them (BENCHMARK.md, "Environment sets"). The unions (WH++, WHH++,
CWH++, CWHH++) are built from the single-family sets, so a split is written down once.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from swat_jax.morphology.mjcf import MorphologyError


@dataclasses.dataclass(frozen=True)
class EnvironmentSet:
    """A named group of bodies trained together (``train``) and evaluated zero-shot (``test``)."""

    name: str
    train: tuple[str, ...]
    test: tuple[str, ...] = ()
    description: str = ""

    def split(self, split: str) -> tuple[str, ...]:
        """The bodies of ``split`` ('train', 'test' or 'all')."""
        splits = {"train": self.train, "test": self.test, "all": self.train + self.test}
        if split not in splits:
            raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(splits)}")
        return splits[split]


def _union(name: str, description: str, *parts: EnvironmentSet) -> EnvironmentSet:
    return EnvironmentSet(
        name,
        train=tuple(b for p in parts for b in p.train),
        test=tuple(b for p in parts for b in p.test),
        description=description,
    )


_CHEETAH_TEST = ("cheetah_3_balanced", "cheetah_5_back", "cheetah_6_front")
_CHEETAHS = (
    "cheetah_2_back", "cheetah_2_front", "cheetah_3_back", "cheetah_3_balanced", "cheetah_3_front",
    "cheetah_4_allback", "cheetah_4_allfront", "cheetah_4_back", "cheetah_4_front", "cheetah_5_back",
    "cheetah_5_balanced", "cheetah_5_front", "cheetah_6_back", "cheetah_6_front", "cheetah_7_full",
)  # fmt: skip

HOPPER = EnvironmentSet("hopper", ("hopper_3", "hopper_4", "hopper_5"), description="Hopper++")
WALKER = EnvironmentSet(
    "walker",
    ("walker_2_main", "walker_4_main", "walker_5_main", "walker_7_main"),
    ("walker_3_main", "walker_6_main"),
    "Walker++",
)
CHEETAH = EnvironmentSet(
    "cheetah", tuple(c for c in _CHEETAHS if c not in _CHEETAH_TEST), _CHEETAH_TEST, "Cheetah++"
)
HUMANOID = EnvironmentSet(
    "humanoid",
    tuple(
        f"humanoid_2d_{b}"
        for b in ("7_left_arm", "7_lower_arms", "7_right_arm", "7_right_leg", "8_left_knee", "9_full")
    ),
    ("humanoid_2d_7_left_leg", "humanoid_2d_8_right_knee"),
    "Humanoid++",
)
ANIMAL_WALKERS = EnvironmentSet(
    "animal_walkers",
    (
        "nervenet_fullcheetah",
        "nervenet_halfcheetah",
        "nervenet_halfhumanoid",
        "nervenet_hopper",
        "nervenet_ostrich",
    ),
    description="Animal-Walkers (NerveNet bodies, 21-value limb observation)",
)

SETS: dict[str, EnvironmentSet] = {
    s.name: s
    for s in (
        HOPPER,
        WALKER,
        CHEETAH,
        HUMANOID,
        _union("wh", "WH++ = Walker++ and Humanoid++", WALKER, HUMANOID),
        _union("whh", "WHH++ = Walker++, Humanoid++ and Hopper++", WALKER, HUMANOID, HOPPER),
        _union("cwh", "CWH++ = Cheetah++, Walker++ and Humanoid++", CHEETAH, WALKER, HUMANOID),
        _union(
            "cwhh", "CWHH++ = Cheetah++, Walker++, Humanoid++ and Hopper++", CHEETAH, WALKER, HUMANOID, HOPPER
        ),
        ANIMAL_WALKERS,
    )
}


def folder_set(folder: str | Path) -> EnvironmentSet:
    """A custom set: every ``*.xml`` file directly in ``folder``, all for training, sorted by name."""
    path = Path(folder).expanduser()
    if not path.is_dir():
        raise MorphologyError(path, "not a folder; a custom set is a folder of MJCF body files")
    bodies = tuple(str(p) for p in sorted(path.glob("*.xml")))
    if not bodies:
        raise MorphologyError(path, "no *.xml files in this folder; put one MJCF file per body in it")
    return EnvironmentSet(path.name, bodies, description=f"MJCF files in {path}")


def get_set(name_or_folder: str | Path) -> EnvironmentSet:
    """A benchmark set by name, or a folder of MJCF files; unknown names raise ValueError listing the valid ones."""
    key = str(name_or_folder).lower().replace("+", "").replace("-", "_")
    if key in SETS:
        return SETS[key]
    if Path(name_or_folder).expanduser().is_dir():
        return folder_set(name_or_folder)
    raise ValueError(
        f"unknown environment set {str(name_or_folder)!r}; valid sets: {', '.join(SETS)}, or a folder of MJCF files"
    )
