"""The 43 benchmark bodies: they load on the pinned MuJoCo, match the reference's compiled numbers,
are reproduced by the generator, and are described correctly by ``load``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from reference_numbers import assert_same_numbers, summarize

from swat_jax.morphology import benchmark_names, get_set, load
from swat_jax.morphology.generate import VARIANTS, generate
from swat_jax.morphology.paths import MORPHOLOGY_DIR

REFERENCE = json.loads((Path(__file__).parent / "data" / "reference_numbers.json").read_text())
LIMB_COUNTS = {
    **{f"hopper_{n}": n for n in (3, 4, 5)},
    **{f"walker_{n}_{k}": n for n in range(2, 8) for k in ("main", "flipped")},
    **{name: int(name.split("_")[1]) for name in REFERENCE if name.startswith("cheetah")},
    **{name: int(name.split("_")[2]) for name in REFERENCE if name.startswith("humanoid")},
    "nervenet_fullcheetah": 13,
    "nervenet_halfcheetah": 8,
    "nervenet_halfhumanoid": 7,
    "nervenet_hopper": 4,
    "nervenet_ostrich": 9,
}
SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)


def test_every_benchmark_body_is_shipped():
    planar = [name for name in benchmark_names() if not name.startswith("3d_")]
    assert set(planar) == set(REFERENCE) == set(LIMB_COUNTS)
    assert len(planar) == 43


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_body_matches_the_benchmark(name):
    """Tree, masses, inertias, joints, geoms, contacts, motors, sites and options equal the reference's
    compiled values. Slide-joint anchors are the one exception: ours sit at the torso origin, the
    reference's at the world origin, and a slide joint's anchor does not enter the dynamics."""
    ours = summarize(mujoco.MjModel.from_xml_path(str(MORPHOLOGY_DIR / f"{name}.xml")))
    reference = json.loads(json.dumps(REFERENCE[name]))
    for joint in (*ours["joints"], *reference["joints"]):
        if joint["type"] == SLIDE:
            joint.pop("pos")
    assert_same_numbers(ours, reference, name)


def test_generator_reproduces_the_checked_in_variants():
    generated = generate()
    assert len(generated) == len(VARIANTS) == 34
    for path, text in generated.items():
        assert path.read_text() == text, f"{path.name} differs: run `make morphologies`"


def test_generator_splices_children_onto_the_first_kept_ancestor():
    hopper_3 = load("hopper_3")
    assert hopper_3.limb_names == ("torso", "thigh", "foot") and hopper_3.parents == (-1, 0, 1)
    model = mujoco.MjModel.from_xml_path(str(hopper_3.path))
    foot = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "foot")
    np.testing.assert_allclose(model.body_pos[foot], [0.065, 0, -0.45])


@pytest.mark.parametrize("name", sorted(LIMB_COUNTS))
def test_load_describes_every_body(name):
    body = load(name)
    n = LIMB_COUNTS[name]
    assert body.num_limbs == n and len(body.parents) == n and body.parents[0] == -1
    assert body.limb_names[0] == "torso"
    assert sorted(m for (m,) in body.limb_motors[1:]) == list(range(n - 1)) and body.limb_motors[0] == ()
    assert body.joint_ranges[0] == () and all(lo < hi for ((lo, hi),) in body.joint_ranges[1:])
    assert body.frame_skip == 4 and body.family.max_episode_steps == 1000
    cheetah = name.startswith("cheetah")
    assert (body.timestep, body.integrator) == ((0.01, "EULER") if cheetah else (0.002, "RK4"))
    assert math.isclose(body.control_dt, 0.04 if cheetah else 0.008)
    assert body.family.num_limb_types == (6 if name.startswith("nervenet") else 4)


def test_motor_order_can_differ_from_body_order():
    ostrich = load("nervenet_ostrich")
    assert ostrich.limb_names[:3] == ("torso", "tail", "head")
    assert ostrich.limb_motors == ((), (6,), (7,), (0,), (1,), (2,), (3,), (4,), (5,))
    model = mujoco.MjModel.from_xml_path(str(ostrich.path))
    for (joint,), (motor,) in zip(ostrich.joint_names[1:], ostrich.limb_motors[1:], strict=True):
        assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.actuator_trnid[motor, 0]) == joint


@pytest.mark.parametrize(
    ("name", "types"),
    [
        ("walker_7_main", (0, 1, 2, 3, 1, 2, 3)),
        ("hopper_5", (0, 1, 2, 2, 3)),
        ("humanoid_2d_9_full", (0, 1, 2, 1, 2, -1, -1, -1, -1)),
        ("nervenet_ostrich", (0, 5, 4, 1, 2, 3, 1, 2, 3)),
        ("nervenet_halfcheetah", (0, 4, 1, 2, 3, 1, 2, 3)),
    ],
)
def test_limb_types_follow_the_name_rules(name, types):
    assert load(name).limb_types == types


@pytest.mark.parametrize(
    ("name", "height", "angle", "sites", "alive_bonus", "control_cost"),
    [
        ("hopper_3", (0.45, math.inf), 1.0, (), 1.0, 1e-3),
        ("hopper_5", (0.95, math.inf), 1.0, (), 1.0, 1e-3),
        ("walker_3_flipped", (0.54, 1.74), 1.0, (), 1.0, 1e-3),
        ("walker_4_main", (0.664, 1.864), 1.0, (), 1.0, 1e-3),
        ("walker_6_main", (0.8, 2.0), 1.0, (), 1.0, 1e-3),
        ("humanoid_2d_8_left_knee", (0.4, 2.1), 1.0, (), 1.0, 1e-3),
        ("cheetah_4_front", None, None, (), 0.0, 0.1),
        ("nervenet_hopper", (0.7, math.inf), 0.2, (), 1.0, 1e-3),
        ("nervenet_ostrich", (0.8, 2.0), 1.0, (("head", 1.1),), 1.0, 1e-3),
        ("nervenet_halfcheetah", None, None, (("front", 0.7), ("back", 0.7), ("tip", 1.2)), 1.0, 0.1),
    ],
)
def test_family_constants_reach_each_body(name, height, angle, sites, alive_bonus, control_cost):
    spec = load(name).family
    assert spec.termination.height == height and spec.termination.max_abs_angle == angle
    assert spec.termination.site_min_heights == sites
    assert (spec.reward.alive_bonus, spec.reward.control_cost) == (alive_bonus, control_cost)
    model = mujoco.MjModel.from_xml_path(str(load(name).path))
    for site, _ in sites:
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site) >= 0


def test_cheetahs_reset_with_the_large_noise():
    assert load("cheetah_2_back").family.reset_noise == load("nervenet_fullcheetah").family.reset_noise
    noise = load("cheetah_2_back").family.reset_noise
    assert (noise.qpos_uniform, noise.qvel_scale, noise.qvel_gaussian) == (0.1, 0.1, True)
    noise = load("walker_2_main").family.reset_noise
    assert (noise.qpos_uniform, noise.qvel_scale, noise.qvel_gaussian) == (0.005, 0.005, False)


@pytest.mark.parametrize(
    ("name", "train", "test", "max_limbs"),
    [
        ("hopper", 3, 0, 5),
        ("walker", 4, 2, 7),
        ("cheetah", 12, 3, 7),
        ("humanoid", 6, 2, 9),
        ("wh", 10, 4, 9),
        ("whh", 13, 4, 9),
        ("cwh", 22, 7, 9),
        ("cwhh", 25, 7, 9),
        ("animal_walkers", 5, 0, 13),
    ],
)
def test_environment_sets(name, train, test, max_limbs):
    env_set = get_set(name)
    assert (len(env_set.train), len(env_set.test)) == (train, test)
    assert not set(env_set.train) & set(env_set.test)
    assert max(LIMB_COUNTS[b] for b in env_set.split("all")) == max_limbs


def test_union_sets_are_unions_of_their_families():
    cwhh = get_set("CWHH++")
    parts = [get_set(n) for n in ("cheetah", "walker", "humanoid", "hopper")]
    assert set(cwhh.train) == set().union(*(p.train for p in parts))
    assert set(cwhh.test) == set().union(*(p.test for p in parts))


def test_unknown_set_lists_the_valid_ones():
    with pytest.raises(ValueError, match=r"valid sets: hopper, walker.*animal_walkers"):
        get_set("walkers")


def test_a_folder_of_mjcf_files_is_a_set(tmp_path):
    for name in ("walker_2_main", "hopper_3"):
        (tmp_path / f"{name}.xml").write_text((MORPHOLOGY_DIR / f"{name}.xml").read_text())
    (tmp_path / "assets").symlink_to(MORPHOLOGY_DIR / "assets")
    env_set = get_set(tmp_path)
    assert [Path(b).stem for b in env_set.train] == ["hopper_3", "walker_2_main"]
    assert [load(b).num_limbs for b in env_set.train] == [3, 2]
