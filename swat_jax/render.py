"""Videos of a body moving: roll out an environment, draw each state off-screen, write MP4 or GIF.

``rollout`` simulates one body under random or zero actions, ``render_frames`` draws a sequence of
poses with a side camera that follows the torso (and, for a 3D body, an arrow on the floor from the torso
toward its target, and the target itself when it is near), ``write_video`` writes the frames, and
``render_rollout`` does both with the body's own frame rate. From the shell::

    python -m swat_jax.render hopper_3 -o hopper.mp4 --steps 200

Rendering is headless, with the OpenGL backend named by ``MUJOCO_GL`` (default egl); see
swat_jax/morphology/picture.py for what to install when no context can be created.
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import tyro

from swat_jax.cli import run_command
from swat_jax.compilation_cache import enable_caches
from swat_jax.envs.body import BodyEnv, EnvState
from swat_jax.envs.physics import Physics
from swat_jax.morphology.mjcf import compile_model, load
from swat_jax.morphology.picture import (
    MAX_GEOMS,
    RenderingUnavailable,
    draw,
    gl_backend,
    render_context,
    side_camera,
)
from swat_jax.morphology.types import Morphology
from swat_jax.runs.config import require_positive

TORSO = 1
"""MuJoCo body index of the torso (body 0 is the world)."""
Actions = Literal["random", "zero"]
POLICIES: tuple[str, ...] = get_args(Actions)
"""Action choices of :func:`rollout`: uniform in [-1, 1] per limb and step, or all zeros."""
VIDEO_SUFFIXES = (".mp4", ".gif")
MAX_GIF_FPS = 50
"""GIF frame delays are whole hundredths of a second and viewers stretch delays under 0.02 s."""
RENDERING_STATUS = 1
"""Exit status when no OpenGL context can be created or the file cannot be written."""


def rollout(env: BodyEnv, steps: int, *, seed: int = 0, policy: str = "random") -> EnvState:
    """Simulate one episode of ``steps`` steps from a reset, jitted as one reset and one ``lax.scan``.

    The episode does not stop or reset when the body falls or the time limit passes: ``BodyEnv.step``
    never resets, so the body goes on being simulated (``terminated`` and ``truncated`` still say when
    the episode would have ended).

    Args:
        env: the body's environment.
        steps: number of environment steps (``steps * env.morphology.control_dt`` seconds).
        seed: seeds the reset noise and the random actions.
        policy: "random" (actions uniform in [-1, 1] per limb, independent across steps) or "zero".

    Returns:
        The states stacked on a leading time axis of length steps + 1, the reset state first
        (``data.qpos`` is [steps + 1, nq]).
    """
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; use one of {', '.join(POLICIES)}")
    if steps < 0:
        raise ValueError(f"steps must be 0 or more, got {steps}")

    def advance(state: EnvState, action: jax.Array) -> tuple[EnvState, EnvState]:
        state = env.step(state, action)
        return state, state

    def episode(key: jax.Array) -> EnvState:
        reset_key, action_key = jax.random.split(key)
        first = env.reset(reset_key)
        _, later = jax.lax.scan(advance, first, _actions(action_key, steps, env.action_shape, policy))
        return jax.tree.map(lambda start, rest: jnp.concatenate([start[None], rest]), first, later)

    return jax.jit(episode)(jax.random.key(seed))


def _actions(key: jax.Array, steps: int, shape: tuple[int, ...], policy: str) -> jax.Array:
    """[steps, *shape] float32 actions of ``policy`` (``shape``: the environment's action shape)."""
    if policy == "zero":
        return jnp.zeros((steps, *shape), jnp.float32)
    return jax.random.uniform(key, (steps, *shape), jnp.float32, minval=-1.0, maxval=1.0)


def render_frames(
    body: Morphology | str | Path,
    qpos: Any,
    *,
    width: int = 480,
    height: int = 360,
    targets: Any = None,
) -> np.ndarray:
    """Draw a sequence of poses from the side, the camera following the torso along x (and y).

    The camera looks at the torso's x at the torso's height in the first frame, so the floor stays in
    view when the body falls or jumps. All frames share one OpenGL context.

    Args:
        body: a loaded body, a benchmark body name or the path of an MJCF file.
        qpos: [T, nq] joint positions (NumPy or JAX), or a rollout: anything with ``.data.qpos`` of that
            shape, such as the stacked ``EnvState`` returned by :func:`rollout`.
        width: image width in pixels.
        height: image height in pixels.
        targets: [T, 2] a 3D body's target per frame (:func:`draw_target`); default: the rollout's
            ``.target``, if it has one.

    Returns:
        [T, height, width, 3] uint8 RGB frames, top row first.

    Raises:
        MorphologyError: the name or file is not a usable body.
        ValueError: qpos is not [T >= 1, nq] for this body, or the size is not positive.
        RenderingUnavailable: no OpenGL context could be created with the selected backend.
    """
    morphology = _morphology(body)
    model = compile_model(morphology)
    positions = _positions(qpos, morphology.name, model.nq)
    if targets is None:
        targets = getattr(qpos, "target", None)
    targets = None if targets is None else np.asarray(targets, np.float64).reshape(len(positions), 2)
    data = mujoco.MjData(model)
    scene = mujoco.MjvScene(model, maxgeom=MAX_GEOMS)
    option = mujoco.MjvOption()
    camera_height = _pose(model, data, positions[0]).xpos[TORSO, 2]
    with render_context(model, width, height) as context:
        frames = np.empty((len(positions), height, width, 3), np.uint8)
        for index, position in enumerate(positions):
            camera = following_camera(_pose(model, data, position), camera_height)
            mujoco.mjv_updateScene(model, data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
            if targets is not None:
                draw_target(scene, data.xpos[TORSO, :2], targets[index])
            frames[index] = draw(scene, context, width, height)
    return frames


TARGET_RGBA = np.array([0.9, 0.2, 0.2, 1.0], np.float32)
TARGET_ARROW = 1.5
"""Metres of the arrow toward the target (shorter when the target is nearer)."""
TARGET_SHOWN = 30.0
"""Targets nearer than this (metres) are drawn as a marker besides the arrow."""


def draw_target(scene: mujoco.MjvScene, torso: np.ndarray, target: np.ndarray) -> None:
    """Add to ``scene`` an arrow on the floor from the torso's (x, y) toward ``target`` (x, y), and a marker
    at the target when it is nearer than :data:`TARGET_SHOWN` (a 10 km target is a direction)."""
    offset = np.asarray(target, np.float64) - torso
    distance = float(np.linalg.norm(offset))
    if distance == 0 or scene.ngeom + 2 > scene.maxgeom:
        return
    start = np.array([torso[0], torso[1], 0.02])
    end = start + np.append(offset / distance * min(distance, TARGET_ARROW), 0.0)
    arrow = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(
        arrow, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), np.eye(3).ravel(), TARGET_RGBA
    )
    mujoco.mjv_connector(arrow, mujoco.mjtGeom.mjGEOM_ARROW, 0.05, start, end)
    scene.ngeom += 1
    if distance < TARGET_SHOWN:
        marker = scene.geoms[scene.ngeom]
        position = np.array([target[0], target[1], 0.1])
        mujoco.mjv_initGeom(
            marker, mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, 0.1), position, np.eye(3).ravel(), TARGET_RGBA
        )
        scene.ngeom += 1


def _morphology(body: Morphology | str | Path) -> Morphology:
    return body if isinstance(body, Morphology) else load(body)


def _pose(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray) -> mujoco.MjData:
    """``data`` set to joint positions ``qpos`` [nq], every position computed."""
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    return data


def following_camera(data: mujoco.MjData, height: float) -> mujoco.MjvCamera:
    """The side camera of the initial-pose picture, aimed at the torso's x and y at ``height`` metres."""
    camera = side_camera(data)
    camera.lookat[:] = (data.xpos[TORSO, 0], data.xpos[TORSO, 1], height)
    return camera


def _positions(qpos: Any, body: str, nq: int) -> np.ndarray:
    """[T, nq] float64 joint positions from an array or a rollout; ValueError naming the body otherwise."""
    source = qpos.data.qpos if hasattr(getattr(qpos, "data", None), "qpos") else qpos
    positions = np.asarray(source, np.float64)
    if positions.ndim != 2 or positions.shape[1] != nq or len(positions) == 0:
        raise ValueError(
            f"{body}: qpos must be [T, {nq}] (T >= 1 frames of the body's {nq} joint positions), "
            f"got shape {positions.shape}"
        )
    return positions


def video_path(path: str | Path) -> Path:
    """``path`` as a Path, checked to name a video this module writes; ValueError listing them otherwise."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(
            f"{path}: cannot write a video with suffix {path.suffix or '(none)'!r}; "
            f"use one of {', '.join(VIDEO_SUFFIXES)}"
        )
    return path


def write_video(frames: np.ndarray, path: str | Path, *, fps: float) -> None:
    """Write frames as an H.264 MP4 (yuv420p) or a GIF that loops forever, creating parent folders.

    An MP4 needs even width and height, so an odd last row or column is repeated. A GIF stores frame delays
    in hundredths of a second, and viewers slow down delays under 0.02 s, so it plays at most 50 fps.

    Args:
        frames: [T, H, W, 3] uint8 RGB frames.
        path: the file to write; its suffix (.mp4 or .gif) picks the format.
        fps: frames per second of playback.

    Raises:
        ValueError: the suffix is neither .mp4 nor .gif, the frames are not [T, H, W, 3] uint8, fps is
            not positive, or a GIF asks for more than 50 fps.
    """
    path = video_path(path)
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"frames must be [T >= 1, H, W, 3] uint8, got {frames.shape} {frames.dtype}")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    is_gif = path.suffix.lower() == ".gif"
    if is_gif and fps > MAX_GIF_FPS:
        raise ValueError(
            f"{path}: a GIF plays at most {MAX_GIF_FPS} fps (frame delays are whole hundredths of a second "
            f"and viewers slow down shorter ones), got fps {fps}; lower fps or write .mp4"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    if is_gif:
        iio.imwrite(path, frames, plugin="pillow", duration=1000 / fps, loop=0)
    else:
        _write_mp4(frames, path, fps)


def _write_mp4(frames: np.ndarray, path: Path, fps: float) -> None:
    """H.264 in yuv420p, which most players and browsers show; the ffmpeg executable is imageio-ffmpeg's."""
    with warnings.catch_warnings():
        # imageio-ffmpeg starts ffmpeg with subprocess, whose child execs at once; JAX's warning that a
        # fork may deadlock its threads is about children that go on running Python.
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        iio.imwrite(
            path,
            _even_size(frames),
            plugin="FFMPEG",
            fps=fps,
            codec="libx264",
            pixelformat="yuv420p",
            macro_block_size=1,
        )


def _even_size(frames: np.ndarray) -> np.ndarray:
    """[T, H', W', 3] with H' and W' rounded up to even by repeating the last row and column."""
    _, height, width, _ = frames.shape
    return np.pad(frames, ((0, 0), (0, height % 2), (0, width % 2), (0, 0)), mode="edge")


def default_fps(morphology: Morphology, path: str | Path) -> int:
    """Real time, round(1 / control_dt) (125 for the 0.008 s of most bodies), at most 50 for a GIF."""
    fps = round(1 / morphology.control_dt)
    return min(fps, MAX_GIF_FPS) if video_path(path).suffix.lower() == ".gif" else fps


def render_rollout(
    body: Morphology | str | Path,
    rollout: Any,
    path: str | Path,
    *,
    fps: float | None = None,
    width: int = 480,
    height: int = 360,
    targets: Any = None,
) -> Path:
    """Render a rollout of ``body`` (see :func:`render_frames`) and write it as a video.

    Args:
        body: a loaded body, a benchmark body name or the path of an MJCF file.
        rollout: [T, nq] joint positions or anything with ``.data.qpos`` of that shape.
        targets: [T, 2] a 3D body's target per frame (default: the rollout's, if it has them).
        path: the .mp4 or .gif file to write.
        fps: playback frame rate; default :func:`default_fps`, real time except for fast GIFs.
        width: frame width in pixels.
        height: frame height in pixels.

    Returns:
        The path written.
    """
    path = video_path(path)
    morphology = _morphology(body)
    frames = render_frames(morphology, rollout, width=width, height=height, targets=targets)
    write_video(frames, path, fps=default_fps(morphology, path) if fps is None else fps)
    return path


@dataclasses.dataclass(frozen=True)
class RenderCommand:
    """Simulate one body under random or zero actions and write a video of it, seen from the side by a
    camera that follows the torso. The body is not reset when it falls. Rendering is off-screen;
    MUJOCO_GL picks the OpenGL backend (egl, osmesa or glfw; default egl)."""

    body: tyro.conf.Positional[str]
    """Benchmark body name (python -m swat_jax.morphology list) or MJCF path."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """Video file to write: .mp4 or .gif."""
    steps: int = 200
    """Environment steps."""
    policy: Actions = "random"
    """Actions: uniform in [-1, 1] per limb and step, or zeros."""
    seed: int = 0
    """Seed of the reset noise and actions."""
    width: int = 480
    """Frame width in pixels."""
    height: int = 360
    """Frame height in pixels."""
    fps: int | None = None
    """Playback frames per second; None: real time (1 / the body's control step), at most 50 for GIF."""
    physics: Physics = "auto"
    """Physics of the rollout: auto (MuJoCo C on a CPU, MJX on a GPU), c, jax or warp."""

    def __post_init__(self) -> None:
        for flag in ("steps", "width", "height"):
            require_positive(f"--{flag}", getattr(self, flag))
        if self.fps is not None:
            require_positive("--fps", self.fps)


def run(command: RenderCommand) -> str:
    """Roll out, render and write the video the command asks for; returns what was written."""
    video_path(command.output)
    gl_backend()
    env = BodyEnv(command.body, physics=command.physics)
    fps = default_fps(env.morphology, command.output) if command.fps is None else command.fps
    states = rollout(env, command.steps, seed=command.seed, policy=command.policy)
    path = render_rollout(
        env.morphology, states, command.output, fps=fps, width=command.width, height=command.height
    )
    return (
        f"wrote {path}: {command.steps + 1} frames of {env.morphology.name}, {command.width} x "
        f"{command.height}, {fps} fps"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad body or option, 1 if rendering fails)."""
    enable_caches()
    try:
        return run_command(RenderCommand, run, argv, (ValueError,), prog="python -m swat_jax.render")
    except (RenderingUnavailable, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return RENDERING_STATUS


if __name__ == "__main__":
    sys.exit(main())
