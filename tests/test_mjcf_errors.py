"""Bad body files get a MorphologyError that names the file, the element and what to do."""

from __future__ import annotations

import pytest

from swat_jax.morphology import MorphologyError, load

FAMILY = '<custom><text name="swat_family" data="walker"/></custom>'
TORSO_JOINTS = """
      <joint name="rootx" type="slide" axis="1 0 0"/>
      <joint name="rootz" type="slide" axis="0 0 1"/>
      <joint name="rooty" type="hinge" axis="0 1 0"/>"""
LEG = """
      <body name="thigh" pos="0 0 -0.2">
        <joint name="thigh_joint" axis="0 -1 0" range="-150 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.05"/>
      </body>"""
MOTOR = '<motor joint="thigh_joint" gear="100"/>'


def body_file(tmp_path, *, family=FAMILY, torso_joints=TORSO_JOINTS, limbs=LEG, motors=MOTOR, extra_root=""):
    text = f"""<mujoco model="test">
  {family}
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="torso" pos="0 0 1">{torso_joints}
      <geom type="capsule" fromto="0 0 0.2 0 0 -0.2" size="0.05"/>{limbs}
    </body>{extra_root}
  </worldbody>
  <actuator>{motors}</actuator>
</mujoco>"""
    path = tmp_path / "robot.xml"
    path.write_text(text)
    return path


def expect_error(path, *fragments, **kwargs):
    with pytest.raises(MorphologyError) as raised:
        load(path, **kwargs)
    message = str(raised.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_the_template_is_valid(tmp_path):
    body = load(body_file(tmp_path))
    assert body.limb_names == ("torso", "thigh") and body.limb_motors == (-1, 0)


def test_missing_file(tmp_path):
    expect_error(tmp_path / "nope.xml", "no such file")


def test_unknown_benchmark_name_suggests_close_ones():
    with pytest.raises(MorphologyError, match="Did you mean walker_3_main") as raised:
        load("walker_3_mian")
    assert "python -m swat_jax.morphology list" in str(raised.value)


def test_malformed_xml(tmp_path):
    path = tmp_path / "broken.xml"
    path.write_text("<mujoco><worldbody><body name='torso'></worldbody></mujoco>")
    expect_error(path, "malformed XML at line 1")


def test_worldbody_without_a_body(tmp_path):
    path = tmp_path / "empty.xml"
    path.write_text(f"<mujoco>{FAMILY}<worldbody><geom type='plane' size='1 1 1'/></worldbody></mujoco>")
    expect_error(path, "<worldbody> has no <body>")


def test_more_than_one_root_body(tmp_path):
    second = '\n    <body name="box"><freejoint/><geom size="0.1"/></body>'
    expect_error(body_file(tmp_path, extra_root=second), "2 root bodies (torso, box)", "keep one")


def test_limb_without_a_joint(tmp_path):
    limbs = '<body name="thigh"><geom size="0.1"/></body>'
    expect_error(body_file(tmp_path, limbs=limbs, motors=""), "<body name='thigh'> has no joint")


def test_limb_with_two_actuated_joints(tmp_path):
    limbs = LEG.replace("</body>", '<joint name="twist" axis="1 0 0"/></body>')
    motors = MOTOR + '<motor joint="twist"/>'
    expect_error(
        body_file(tmp_path, limbs=limbs, motors=motors), "'thigh'> has 2 joints (thigh_joint, twist)"
    )


def test_motor_on_an_unknown_joint(tmp_path):
    motors = '<motor joint="knee_joint" gear="100"/>'
    expect_error(
        body_file(tmp_path, motors=motors),
        "(<motor joint='knee_joint'>) drives an unknown joint",
        "thigh_joint",
    )


def test_joint_without_a_motor(tmp_path):
    expect_error(body_file(tmp_path, motors=""), "joint 'thigh_joint' is driven by 0 motors")


@pytest.mark.parametrize(("element", "kind"), [("<freejoint/>", "free"), ('<joint type="ball"/>', "ball")])
def test_free_or_ball_joint_below_the_torso(tmp_path, element, kind):
    limbs = f'<body name="thigh">{element}<geom size="0.1"/></body>'
    expect_error(body_file(tmp_path, limbs=limbs, motors=""), f"'thigh'> has a {kind} joint", "need hinges")


def test_torso_must_be_planar(tmp_path):
    expect_error(body_file(tmp_path, torso_joints="<freejoint/>"), "torso <body name='torso'> has 1 joints")


def test_more_limbs_than_the_maximum(tmp_path):
    expect_error(body_file(tmp_path), "2 limbs, more than the maximum of 1", max_limbs=1)


def test_missing_family(tmp_path):
    expect_error(body_file(tmp_path, family=""), "no family declared", 'name="swat_family"', "walker")


def test_unknown_family(tmp_path):
    family = FAMILY.replace("walker", "spider")
    expect_error(body_file(tmp_path, family=family), "unknown family 'spider'", "nervenet")


def test_mujoco_compile_errors_name_the_file(tmp_path):
    limbs = LEG.replace('size="0.05"', 'size="-1"')
    expect_error(body_file(tmp_path, limbs=limbs), "MuJoCo cannot compile this file")
