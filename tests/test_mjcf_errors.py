"""Bad body files get a MorphologyError that names the file, the element and what to do."""

from __future__ import annotations

import pytest

from swat_jax.morphology import MorphologyError, get_set, load

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


@pytest.fixture(autouse=True)
def _warnings_log_in_tmp_path(tmp_path, monkeypatch):
    """MuJoCo appends its warnings (a NaN in the XML) to MUJOCO_LOG.TXT in the working directory."""
    monkeypatch.chdir(tmp_path)


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
    assert body.limb_names == ("torso", "thigh") and body.limb_motors == ((), (0,))


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


def test_a_folder_is_not_a_body_file(tmp_path):
    expect_error(tmp_path, "is a folder, not a body file", "--env FOLDER")


def test_a_urdf_is_not_a_mujoco_file(tmp_path):
    path = tmp_path / "robot.urdf"
    path.write_text('<robot name="r"><link name="base"/></robot>')
    expect_error(path, "not a MuJoCo file", "root element is <robot>", "<mujoco>")


def test_a_missing_include_is_one_line(tmp_path):
    path = body_file(tmp_path, family=FAMILY + '<include file="scene.xml"/>')
    message = expect_error(path, "MuJoCo cannot compile this file", "'scene.xml'")
    assert "\n" not in message


@pytest.mark.parametrize("gear", ["0", "nan", "inf"])
def test_motor_gear_must_be_finite_and_nonzero(tmp_path, gear):
    motors = MOTOR.replace('gear="100"', f'gear="{gear}"')
    expect_error(body_file(tmp_path, motors=motors), "actuator of <joint name='thigh_joint'>", "gear")


@pytest.mark.parametrize(
    "joint",
    [
        '<joint name="thigh_joint" axis="0 -1 0" range="-150 0" limited="false"/>',
        '<joint name="thigh_joint" axis="0 -1 0"/>',
        '<joint name="thigh_joint" axis="0 -1 0" range="10 -10"/>',
    ],
)
def test_limb_joint_needs_a_range(tmp_path, joint):
    limbs = LEG.replace('<joint name="thigh_joint" axis="0 -1 0" range="-150 0"/>', joint)
    expect_error(
        body_file(tmp_path, limbs=limbs), "<joint name='thigh_joint'> has no range", 'range="LOW HIGH"'
    )


def test_torso_pitch_hinge_must_turn_about_y(tmp_path):
    joints = TORSO_JOINTS.replace('axis="0 1 0"', 'axis="1 0 0"')
    expect_error(
        body_file(tmp_path, torso_joints=joints), "'rooty' is a hinge with axis \"1 0 0\"", "hinge about y"
    )


@pytest.mark.parametrize("actuator", ["position", "velocity"])
def test_actuators_must_be_motors(tmp_path, actuator):
    motors = f'<{actuator} joint="thigh_joint"/>'
    expect_error(body_file(tmp_path, motors=motors), "is not a <motor>", "<motor joint=")


@pytest.mark.parametrize(
    ("limbs", "fragments"),
    [
        (LEG.replace('pos="0 0 -0.2"', 'pos="0 0 nan"'), ("<body name='thigh'> has pos \"0 0 nan\"",)),
        (
            LEG.replace('pos="0 0 -0.2"', 'pos="0 0 -0.2" euler="inf 0 0"'),
            ("<body name='thigh'> has orientation",),
        ),
        (LEG.replace('range="-150 0"', 'range="-150 0" damping="-1"'), ('damping "-1"', "at least 0")),
        (
            LEG.replace('size="0.05"', 'size="0.05" friction="nan 0.1 0.1"'),
            ("unnamed <geom> of <body name='thigh'>",),
        ),
        (
            LEG.replace('size="0.05"', 'size="0.05" mass="nan"'),
            ("<geom> in <body name='thigh'> has mass=\"nan\"",),
        ),
    ],
)
def test_numbers_mujoco_accepts_but_the_simulation_cannot_use(tmp_path, limbs, fragments):
    expect_error(body_file(tmp_path, limbs=limbs), *fragments)


def test_timestep_must_be_positive(tmp_path):
    family = FAMILY + '<option timestep="0"/>'
    expect_error(body_file(tmp_path, family=family), '<option timestep="0">', "positive")


def test_a_folder_set_lists_every_bad_file_at_once(tmp_path):
    good = body_file(tmp_path)
    (tmp_path / "no_range.xml").write_text(good.read_text().replace(' range="-150 0"', ""))
    (tmp_path / "servo.xml").write_text(good.read_text().replace("<motor ", "<position "))
    with pytest.raises(MorphologyError) as raised:
        get_set(tmp_path)
    message = str(raised.value)
    assert message.startswith(f"{tmp_path}: 2 of its 3 body files cannot be used")
    assert "\n  no_range.xml: limb joint <joint name='thigh_joint'> has no range" in message
    assert "\n  servo.xml: the unnamed actuator of <joint name='thigh_joint'> is not a <motor>" in message


def test_a_folder_set_refuses_families_of_different_observation_widths(tmp_path):
    body_file(tmp_path)
    (tmp_path / "nervenet.xml").write_text(
        body_file(tmp_path).read_text().replace('data="walker"', 'data="nervenet"')
    )
    with pytest.raises(MorphologyError, match="differ in width") as raised:
        get_set(tmp_path)
    assert "robot.xml: family walker, 4 limb types" in str(raised.value)
    assert "nervenet.xml: family nervenet, 6 limb types" in str(raised.value)
