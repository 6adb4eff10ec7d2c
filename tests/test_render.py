"""Videos of rollouts: `rollout`, `render_frames` with its torso-following camera, MP4 and GIF files, the CLI.

One jitted rollout of hopper_3 serves the whole module (MJX takes seconds to compile it).
"""

import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from subprocesses import python_path_environment

from swat_jax.envs.body import BodyEnv
from swat_jax.render import main, render_frames, render_rollout, rollout, write_video

# Reading an MP4 starts ffmpeg through subprocess (fork, then exec at once), which JAX warns about needlessly.
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")

REPO = Path(__file__).resolve().parents[1]
BODY = "hopper_3"
STEPS = 12
WIDTH, HEIGHT = 95, 71
"""Odd on purpose: an MP4 must round them up to even."""
HOPPER_FPS = 125
"""round(1 / control_dt) for hopper_3's 0.008 s control step."""


@pytest.fixture(scope="module")
def env() -> BodyEnv:
    return BodyEnv(BODY, physics="c")


@pytest.fixture(scope="module")
def states(env):
    return rollout(env, STEPS, seed=3)


@pytest.fixture(scope="module")
def frames(states) -> np.ndarray:
    return render_frames(BODY, states, width=WIDTH, height=HEIGHT)


def limb_pixels(image: np.ndarray) -> np.ndarray:
    """[H, W] mask of the orange limb material (red well above blue; sky and floor are blue)."""
    return image[..., 0].astype(int) > image[..., 2].astype(int) + 40


def body_centre(image: np.ndarray) -> tuple[float, float]:
    """(row, column) of the body's pixels; fails when the body is out of view."""
    rows, columns = np.nonzero(limb_pixels(image))
    assert len(rows) > 20, "the body is in view"
    return rows.mean(), columns.mean()


def test_rollout_stacks_the_reset_state_and_every_step(env, states):
    assert states.data.qpos.shape == (STEPS + 1, env.mj_model.nq)
    np.testing.assert_array_equal(states.episode_length, np.arange(STEPS + 1))
    np.testing.assert_allclose(states.data.qpos[0], env.mj_model.qpos0, atol=0.0051)
    assert np.all(np.abs(np.diff(states.data.qpos[:, 3:], axis=0)).sum(axis=1) > 0), (
        "random actions move the legs"
    )


def test_rollout_rejects_an_unknown_policy(env):
    with pytest.raises(ValueError, match=r"unknown policy 'greedy'; use one of random, zero"):
        rollout(env, STEPS, policy="greedy")


def test_frames_show_the_body_moving(states, frames):
    assert frames.shape == (STEPS + 1, HEIGHT, WIDTH, 3)
    assert frames.dtype == np.uint8
    changes = np.abs(np.diff(frames.astype(int), axis=0)).mean(axis=(1, 2, 3))
    assert np.all(changes > 0), "every step changes the picture"
    for frame in frames:
        body_centre(frame)
    np.testing.assert_array_equal(
        render_frames(BODY, np.asarray(states.data.qpos), width=WIDTH, height=HEIGHT), frames
    )


def test_camera_follows_the_torso_and_keeps_its_height(env):
    # The torso slides 6 m along x, far beyond the ~4 m a fixed camera at 3.5 m sees: the body only stays in
    # the middle third of every frame if the camera goes with it. The last pose drops the torso 0.3 m.
    qpos = np.tile(env.mj_model.qpos0, (5, 1))
    qpos[:, 0] = [0.0, 1.5, 3.0, 6.0, 6.0]
    qpos[4, 1] -= 0.3
    width, height = 120, 90
    images = render_frames(BODY, qpos, width=width, height=height)
    centres = np.array([body_centre(image) for image in images])
    assert np.all((centres[:, 1] > width / 3) & (centres[:, 1] < 2 * width / 3)), centres
    np.testing.assert_allclose(centres[1:4], centres[[0]].repeat(3, axis=0), atol=2.0)
    assert centres[4, 0] > centres[3, 0] + 5, "the camera stays at its height, so a lower torso sits lower"


def test_mp4_and_gif_hold_every_frame(tmp_path, states, frames):
    mp4 = render_rollout(BODY, states, tmp_path / "new" / "hopper.mp4", width=WIDTH, height=HEIGHT)
    gif = render_rollout(BODY, states, tmp_path / "hopper.gif", width=WIDTH, height=HEIGHT)
    assert mp4 == tmp_path / "new" / "hopper.mp4"
    video = iio.imread(mp4, plugin="FFMPEG")
    assert video.shape == (STEPS + 1, HEIGHT + 1, WIDTH + 1, 3), "an MP4 has even width and height"
    assert iio.immeta(mp4, plugin="FFMPEG")["fps"] == HOPPER_FPS
    assert np.abs(video[:, :HEIGHT, :WIDTH].astype(int) - frames).mean() < 6, "the MP4 holds the frames"
    animation = iio.imread(gif, index=None)
    assert animation.shape == (STEPS + 1, HEIGHT, WIDTH, 3)
    metadata = iio.immeta(gif, index=0)
    assert metadata["loop"] == 0, "the GIF loops forever"
    assert metadata["duration"] == 20, "a GIF of a 125 fps body plays at the GIF's most, 50 fps"
    assert np.abs(animation.astype(int) - frames).mean() < 6, "the GIF holds the frames"


def test_write_video_keeps_the_frame_rate(tmp_path, frames):
    write_video(frames, tmp_path / "slow.gif", fps=10)
    write_video(frames, tmp_path / "slow.mp4", fps=10)
    assert iio.immeta(tmp_path / "slow.gif", index=0)["duration"] == 100
    assert iio.immeta(tmp_path / "slow.mp4", plugin="FFMPEG")["fps"] == 10


def test_qpos_of_the_wrong_width_names_the_body_and_both_shapes(env):
    with pytest.raises(ValueError, match=r"hopper_3: qpos must be \[T, 5\] .* got shape \(3, 4\)"):
        render_frames(BODY, np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r"got shape \(5,\)"):
        render_frames(BODY, env.mj_model.qpos0)


def test_unsupported_video_files_are_refused(tmp_path, frames):
    with pytest.raises(
        ValueError, match=r"x\.avi: cannot write a video with suffix '\.avi'; use one of \.mp4, \.gif"
    ):
        write_video(frames, tmp_path / "x.avi", fps=10)
    with pytest.raises(
        ValueError, match=r"a GIF plays at most 50 fps .* got fps 125; lower fps or write \.mp4"
    ):
        write_video(frames, tmp_path / "x.gif", fps=125)
    assert list(tmp_path.iterdir()) == []


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "swat_jax.render", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=python_path_environment(REPO),
        check=False,
        timeout=600,
    )


def test_cli_writes_a_video(tmp_path, states):
    # As many steps as the `states` rollout, which has put the same program in JAX's compilation cache.
    output = tmp_path / "clips" / "hopper.gif"
    size = ["--width", "64", "--height", "48"]
    result = run_cli(BODY, "-o", str(output), "--steps", str(STEPS), *size, "--fps", "20")
    assert result.returncode == 0, result.stderr
    # mujoco.mjx prints to stdout when it cannot import its optional warp backend; the report comes last.
    report = f"wrote {output}: {STEPS + 1} frames of hopper_3, 64 x 48, 20 fps"
    assert result.stdout.splitlines()[-1] == report
    assert iio.imread(output, index=None).shape == (STEPS + 1, 48, 64, 3)


def test_cli_bad_body_exits_2_with_the_reason(tmp_path):
    result = run_cli("hoper_3", "-o", str(tmp_path / "x.mp4"))
    assert result.returncode == 2
    assert result.stderr.startswith("error: ") and "hoper_3" in result.stderr and "hopper_3" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "x.mp4").exists()


def test_cli_without_rendering_exits_1_before_simulating(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "nonsense")
    assert main([BODY, "-o", str(tmp_path / "x.mp4")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: MUJOCO_GL='nonsense'") and "egl" in err
    assert main([BODY, "-o", str(tmp_path / "x.avi")]) == 2
    assert "use one of .mp4, .gif" in capsys.readouterr().err


def test_a_3d_body_is_drawn_with_an_arrow_toward_its_target():
    """A 3D rollout (MuJoCo C) draws, besides the body, a red arrow on the floor from the torso toward the
    target, pointing the target's way; a near target (v2) also gets a marker."""
    body = "3d_hopper_v2_3_shin"
    states = rollout(BodyEnv(body, physics="c"), 2, seed=1)
    with_target = render_frames(body, states, width=160, height=120)
    plain = render_frames(body, np.asarray(states.data.qpos), width=160, height=120)
    drawn = np.abs(with_target.astype(int) - plain.astype(int)).sum(axis=-1) > 60
    assert drawn[0].sum() > 30, "the arrow and the marker are drawn"
    red = (with_target[..., 0] > 150) & (with_target[..., 1] < 90) & (with_target[..., 2] < 90)
    assert (drawn & red).sum() > 30, "in the target's red"
    turned = np.asarray(states.target).copy()
    turned[:] = 2 * np.asarray(states.data.qpos[:, :2]) - turned  # the target on the other side
    other_way = render_frames(body, states, width=160, height=120, targets=turned)
    assert np.abs(other_way.astype(int) - with_target.astype(int)).sum() > 0, "the arrow follows the target"
