"""The benchmark's environment sets (train and held-out test bodies), and folders of MJCF files.

Splits as AMORPHEUS and SWAT used them, and for the 3D bodies as SGRL did. The unions (WH++, WHH++,
CWH++, CWHH++) are built from the single-family sets, so a split is written down once.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from swat_jax.morphology.mjcf import MorphologyError, load
from swat_jax.morphology.types import Morphology


@dataclasses.dataclass(frozen=True)
class EnvironmentSet:
    """A named group of bodies trained together (``train``) and evaluated zero-shot (``test``)."""

    name: str
    train: tuple[str, ...]
    test: tuple[str, ...] = ()
    description: str = ""

    @property
    def title(self) -> str:
        """The set's short name for figure panels: its description without its parenthesis (or its name)."""
        return self.description.split(" (")[0] or self.name

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


def _sgrl(family: str, description: str, train: str, test: str = "", version: str = "") -> EnvironmentSet:
    """A 3D-SGRL set: ``3d_<family>[_v2]_<body>`` for each body name of ``train`` and ``test``."""
    prefix = f"3d_{family}{version}_"
    return EnvironmentSet(
        f"3d_{family}{version}",
        tuple(prefix + body for body in train.split()),
        tuple(prefix + body for body in test.split()),
        description,
    )


HOPPER_3D = _sgrl("hopper", "3D Hopper++ (SGRL)", "3_shin 4_lower_shin 5_full")
WALKER_3D = _sgrl(
    "walker",
    "3D Walker++ (SGRL)",
    "2_right_leg_left_knee 3_left_leg_right_foot 4_right_knee_left_foot 5_foot 5_left_knee 7_full",
    "3_left_knee_right_knee 6_right_foot",
)
HUMANOID_3D = _sgrl(
    "humanoid",
    "3D Humanoid++ (SGRL)",
    "7_left_arm 7_lower_arms 7_right_arm 7_right_leg 8_left_knee 9_full",
    "7_left_leg 8_right_knee",
)
CHEETAH_3D = _sgrl(
    "cheetah",
    "3D Cheetah++ (SGRL)",
    "10_tail_leftbleg 11_leftfleg 11_tail_rightfknee 12_rightbknee 12_tail_leftbfoot 13_rightffoot 13_tail "
    "14_full",
    "11_leftbkneen_rightffoot 12_tail_leftffoot",
)
NEAR_TARGETS_3D = tuple(
    _sgrl(
        s.name.removeprefix("3d_"),
        s.title + " with near targets (SGRL's v2)",
        " ".join(b.removeprefix(s.name + "_") for b in s.train),
        version="_v2",
    )
    for s in (HOPPER_3D, WALKER_3D, HUMANOID_3D, CHEETAH_3D)
)
"""The ``_v2`` sets: the same training bodies, a new target 10 to 20 m away each time one is reached
(SGRL has no ``_v2`` files of its held-out bodies)."""

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
        HOPPER_3D,
        WALKER_3D,
        HUMANOID_3D,
        CHEETAH_3D,
        _union(
            "3d_whh",
            "3D WHH++ = 3D Walker++, Humanoid++ and Hopper++ (SGRL)",
            WALKER_3D,
            HUMANOID_3D,
            HOPPER_3D,
        ),
        _union(
            "3d_cwhh",
            "3D CWHH++ = 3D Cheetah++, Walker++, Humanoid++ and Hopper++ (SGRL)",
            CHEETAH_3D,
            WALKER_3D,
            HUMANOID_3D,
            HOPPER_3D,
        ),
        *NEAR_TARGETS_3D,
    )
}


def folder_set(folder: str | Path) -> EnvironmentSet:
    """A custom set: every ``*.xml`` file directly in ``folder``, all for training, sorted by name.

    Every file is loaded first (:func:`check_folder_bodies`), so a bad file is reported here, with
    all the others, and not as a traceback once training or evaluation has started.
    """
    path = Path(folder).expanduser()
    if not path.is_dir():
        raise MorphologyError(path, "not a folder; a custom set is a folder of MJCF body files")
    bodies = tuple(str(p) for p in sorted(path.glob("*.xml")))
    if not bodies:
        raise MorphologyError(path, "no *.xml files in this folder; put one MJCF file per body in it")
    check_folder_bodies(path, bodies)
    return EnvironmentSet(path.name, bodies, description=f"MJCF files in {path}")


def check_folder_bodies(folder: Path, bodies: Sequence[str]) -> tuple[Morphology, ...]:
    """Load every body of a folder set; one MorphologyError lists every file that cannot be used.

    Besides each file's own problems, bodies whose families have limb-type vocabularies of
    different sizes are refused together: their per-limb observations differ in width, so one
    policy cannot take them all.
    """
    loaded, problems = [], []
    for body in bodies:
        try:
            loaded.append(load(body))
        except MorphologyError as error:
            problems.append(f"  {Path(body).name}: {error.problem}")
    if problems:
        raise MorphologyError(
            folder,
            f"{len(problems)} of its {len(bodies)} body files cannot be used; fix or move them:\n"
            + "\n".join(problems),
        )
    kinds = {(body.family.num_limb_types, body.family.three_d) for body in loaded}
    if len(kinds) > 1:
        lines = [
            f"  {body.path.name}: family {body.family.name}, {body.family.num_limb_types} limb types, "
            + ("3D" if body.family.three_d else "planar")
            for body in loaded
        ]
        raise MorphologyError(
            folder,
            "its bodies' families have limb-type vocabularies of different sizes, or planar and 3D bodies "
            "are mixed, so their per-limb observations differ in width and one policy cannot take them "
            "all; put the families in separate folders:\n" + "\n".join(lines),
        )
    return tuple(loaded)


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
