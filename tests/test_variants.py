"""Variants of a body: reproducible factors, consistent physics from MuJoCo's model editing, valid bodies."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from swat_jax.morphology import MorphologyError, load
from swat_jax.morphology.__main__ import main
from swat_jax.morphology.mjcf import compile_model
from swat_jax.morphology.variants import QUANTITIES, Variation, lowest_point, variant_spec, write_variants


def factors(morphology, **quantities: float) -> np.ndarray:
    """[limbs, 6] ones, with the named quantities set to the given factor on every limb."""
    table = np.ones((morphology.num_limbs, len(QUANTITIES)))
    for name, value in quantities.items():
        table[:, QUANTITIES.index(name)] = value
    return table


def anchors(model: mujoco.MjModel) -> np.ndarray:
    """[limbs, 3] each limb's joint anchor at qpos0 (the torso's origin for the torso)."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    hinge = {
        int(model.jnt_bodyid[j]): j
        for j in range(model.njnt)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
    }
    return np.array([data.xanchor[hinge[b]] if b > 1 else data.xpos[b] for b in range(1, model.nbody)])


def test_factors_are_reproducible_and_within_the_spread():
    draw = Variation(0.2, seed=3).factors(num_limbs=4, count=16)
    assert draw.shape == (16, 4, 6)
    assert np.array_equal(draw, Variation(0.2, seed=3).factors(4, 16))
    assert not np.array_equal(draw, Variation(0.2, seed=4).factors(4, 16))
    assert draw.min() >= 0.8 and draw.max() <= 1.2 and draw.std() > 0.05
    assert np.all(Variation(0.0).factors(4, 2) == 1.0)


@pytest.mark.parametrize("spread", [-0.1, 1.0, 1.5])
def test_a_spread_outside_0_1_is_refused(spread):
    with pytest.raises(ValueError, match=r"spread must lie in \[0, 1\)"):
        Variation(spread)


@pytest.mark.parametrize("body", ["hopper_3", "cheetah_4_front"])
def test_unit_factors_give_the_nominal_model(body):
    nominal = load(body)
    ours, theirs = variant_spec(nominal, factors(nominal)).compile(), compile_model(nominal)
    for field in (
        "body_mass",
        "body_inertia",
        "body_pos",
        "geom_size",
        "jnt_range",
        "dof_damping",
        "actuator_gear",
    ):
        np.testing.assert_allclose(
            getattr(ours, field), getattr(theirs, field), rtol=1e-6, atol=1e-9, err_msg=field
        )


@pytest.mark.parametrize("body", ["walker_7_main", "cheetah_7_full", "humanoid_2d_9_full"])
def test_longer_limbs_keep_their_children_attached_and_their_clearance(body):
    """Scaling every limb's length by 1.2 scales each parent-to-child anchor offset by 1.2 (the children
    hang where the limbs now end: geoms given by fromto and by pos and half-length alike), the shapes'
    lengths by 1.2, and the lowest point stays as high above the floor."""
    nominal = load(body)
    longer = variant_spec(nominal, factors(nominal, length=1.2)).compile()
    reference = compile_model(nominal)
    parents = np.array(nominal.parents[1:])
    offsets = lambda model: anchors(model)[1:] - anchors(model)[parents]  # noqa: E731
    np.testing.assert_allclose(offsets(longer), 1.2 * offsets(reference), atol=1e-6)
    np.testing.assert_allclose(longer.geom_size[1:, 1], 1.2 * reference.geom_size[1:, 1], rtol=1e-6)
    ratio = longer.body_mass[1:] / reference.body_mass[1:]
    assert np.all((ratio > 1.0) & (ratio < 1.2)), (
        "MuJoCo weighed the longer shapes (a capsule's caps keep their size)"
    )
    assert lowest_point(longer) == pytest.approx(lowest_point(reference), abs=1e-6)
    assert longer.qpos0[1] - longer.body_pos[1, 2] == pytest.approx(
        reference.qpos0[1] - reference.body_pos[1, 2]
    ), "the height joint reads the same world height (torso pos and the joint's ref moved together)"


def test_mass_radius_joint_and_motor_factors_reach_the_compiled_model():
    nominal = load("walker_3_main")
    reference = compile_model(nominal)
    heavier = variant_spec(nominal, factors(nominal, mass=1.3)).compile()
    np.testing.assert_allclose(heavier.body_mass[1:], 1.3 * reference.body_mass[1:], rtol=1e-6)
    np.testing.assert_allclose(heavier.body_inertia[1:], 1.3 * reference.body_inertia[1:], rtol=1e-6)
    thicker = variant_spec(nominal, factors(nominal, radius=1.1)).compile()
    np.testing.assert_allclose(thicker.geom_size[1:, 0], 1.1 * reference.geom_size[1:, 0], rtol=1e-6)
    assert np.all(thicker.body_mass[1:] > reference.body_mass[1:]), "MuJoCo recomputed the masses"
    other = variant_spec(nominal, factors(nominal, joint_range=0.9, damping=1.5, gear=0.8)).compile()
    limbs = reference.jnt_type == mujoco.mjtJoint.mjJNT_HINGE
    limbs[:3] = False
    np.testing.assert_allclose(other.jnt_range[limbs], 0.9 * reference.jnt_range[limbs], rtol=1e-6)
    np.testing.assert_allclose(other.dof_damping[3:], 1.5 * reference.dof_damping[3:], rtol=1e-6)
    np.testing.assert_allclose(other.actuator_gear[:, 0], 0.8 * reference.actuator_gear[:, 0], rtol=1e-6)
    (
        np.testing.assert_allclose(other.dof_damping[:3], reference.dof_damping[:3]),
        "the torso's joints keep theirs",
    )


def test_variants_are_bodies_of_the_same_tree_with_the_nominal_constants(tmp_path):
    nominal = load("hopper_3")
    variants = write_variants("hopper_3", 3, Variation(0.2, seed=1), tmp_path)
    assert [v.name for v in variants] == [f"hopper_3__s1v{i}" for i in range(3)]
    for variant in variants:
        assert variant.path.parent == tmp_path
        assert (variant.limb_names, variant.parents, variant.limb_motors) == (
            nominal.limb_names,
            nominal.parents,
            nominal.limb_motors,
        )
        assert variant.family == nominal.family, "hopper_3's own termination height, not the family's"
        assert variant.joint_ranges != nominal.joint_ranges
    again = write_variants("hopper_3", 3, Variation(0.2, seed=1), tmp_path / "again")
    assert [v.path.read_text() for v in again] == [v.path.read_text() for v in variants]


def test_a_variant_mujoco_refuses_names_the_body_the_quantity_and_the_factor(tmp_path, monkeypatch):
    weightless = factors(load("hopper_3"), mass=1e-30)
    monkeypatch.setattr(Variation, "factors", lambda self, num_limbs, count: weightless[None])
    with pytest.raises(MorphologyError, match="hopper_3") as error:
        write_variants("hopper_3", 1, Variation(0.2), tmp_path)
    message = str(error.value)
    assert "MuJoCo refuses variant 0" in message and "mass" in message and "thigh 1 1 1e-30" in message


def test_the_command_writes_the_variants_and_refuses_a_bad_spread(tmp_path, capsys):
    assert main(["variants", "hopper_3", "-k", "2", "--out", str(tmp_path), "--no-picture"]) == 0
    assert sorted(path.name for path in tmp_path.iterdir()) == ["hopper_3__s0v0.xml", "hopper_3__s0v1.xml"]
    assert "wrote 2 variants of hopper_3" in capsys.readouterr().out
    assert main(["variants", "hopper_3", "--out", str(tmp_path), "--variation", "1.5"]) == 2
    assert "spread must lie in [0, 1)" in capsys.readouterr().err
