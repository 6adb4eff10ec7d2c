"""A picture of one body in its initial pose, rendered off-screen with MuJoCo's OpenGL renderer.

The OpenGL backend comes from the ``MUJOCO_GL`` environment variable (``egl``, ``osmesa`` or ``glfw``),
``egl`` when it is unset. It is read when a picture is drawn, not when ``mujoco`` is imported, so setting
it any time before the first picture works. On a headless Debian or Ubuntu machine without a GPU, EGL
renders on the CPU (Mesa's llvmpipe) once these packages are installed:
``apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0``.
"""

from __future__ import annotations

import contextlib
import importlib
import os
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np

from swat_jax.morphology.mjcf import compile_model, load
from swat_jax.morphology.types import Morphology

DEFAULT_BACKEND = "egl"
INSTALL_HINTS = {
    "egl": "apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0",
    "osmesa": "apt-get install -y libosmesa6, or use MUJOCO_GL=egl",
    "glfw": "a display (X11 or Wayland); on a headless machine use MUJOCO_GL=egl",
}
"""How to make each backend work on Debian/Ubuntu."""
CAMERA_DISTANCE = 3.5
"""Metres from the body's centre of mass to the camera."""
CAMERA_ELEVATION = -10.0
"""Degrees; slightly from above."""
CAMERA_AZIMUTH = 90.0
"""Degrees; the camera looks along +y at the x-z plane the body moves in, +x to the right."""
MAX_GEOMS = 1000
"""Room for geoms in one scene, far more than any benchmark body has."""


class RenderingUnavailable(RuntimeError):
    """No OpenGL context could be created; the message names the backend and what to install."""


def gl_backend() -> str:
    """The OpenGL backend to use: ``MUJOCO_GL`` lower-cased, or ``egl`` when it is unset or empty."""
    backend = os.environ.get("MUJOCO_GL", "").strip().lower() or DEFAULT_BACKEND
    if backend not in INSTALL_HINTS:
        raise RenderingUnavailable(
            f"MUJOCO_GL={backend!r} is not a backend this renderer supports; "
            f"use one of {', '.join(INSTALL_HINTS)}"
        )
    return backend


@contextlib.contextmanager
def render_context(model: mujoco.MjModel, width: int, height: int) -> Iterator[mujoco.MjrContext]:
    """A current OpenGL context and a MuJoCo render context drawing into a ``width`` x ``height``
    off-screen buffer (``model``'s off-screen size grows to fit it).

    Raises:
        ValueError: width or height is not positive.
        RenderingUnavailable: no OpenGL context could be created with the selected backend.
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
    backend = gl_backend()
    try:
        gl = importlib.import_module(f"mujoco.{backend}").GLContext(width, height)
        gl.make_current()
        context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
    except Exception as error:
        raise RenderingUnavailable(
            f"cannot start OpenGL rendering with MUJOCO_GL={backend} ({type(error).__name__}: {error}); "
            f"to fix: {INSTALL_HINTS[backend]}"
        ) from error
    try:
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, context)
        yield context
    finally:
        context.free()
        gl.free()


def side_camera(data: mujoco.MjData) -> mujoco.MjvCamera:
    """A free camera at the torso's side, aimed at the body's centre of mass."""
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = data.subtree_com[1]
    camera.distance = CAMERA_DISTANCE
    camera.elevation = CAMERA_ELEVATION
    camera.azimuth = CAMERA_AZIMUTH
    return camera


def draw(scene: mujoco.MjvScene, context: mujoco.MjrContext, width: int, height: int) -> np.ndarray:
    """Render ``scene`` into the off-screen buffer of ``context`` and read it back.

    Returns:
        [height, width, 3] uint8 RGB image, top row first.
    """
    viewport = mujoco.MjrRect(0, 0, width, height)
    pixels = np.empty((height, width, 3), np.uint8)
    mujoco.mjr_render(viewport, scene, context)
    mujoco.mjr_readPixels(pixels, None, viewport, context)
    return np.ascontiguousarray(pixels[::-1])


def _initial_pose(morphology_or_path: Morphology | str | Path) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The compiled body with its state at qpos0 and all positions computed."""
    morphology = (
        morphology_or_path if isinstance(morphology_or_path, Morphology) else load(morphology_or_path)
    )
    model = compile_model(morphology)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def render_initial_pose(
    morphology_or_path: Morphology | str | Path, width: int = 640, height: int = 480
) -> np.ndarray:
    """Draw a body standing in its initial pose (qpos0), seen from the side.

    Args:
        morphology_or_path: a loaded body, a benchmark body name or the path of an MJCF file.
        width: image width in pixels.
        height: image height in pixels.

    Returns:
        [height, width, 3] uint8 RGB image, top row first.

    Raises:
        MorphologyError: the name or file is not a usable body.
        ValueError: width or height is not positive.
        RenderingUnavailable: no OpenGL context could be created with the selected backend.
    """
    model, data = _initial_pose(morphology_or_path)
    scene = mujoco.MjvScene(model, maxgeom=MAX_GEOMS)
    mujoco.mjv_updateScene(
        model, data, mujoco.MjvOption(), None, side_camera(data), mujoco.mjtCatBit.mjCAT_ALL, scene
    )
    with render_context(model, width, height) as context:
        return draw(scene, context, width, height)
