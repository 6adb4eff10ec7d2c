"""The `python -m swat_jax.morphology` command: list, show (tables and JSON), render, and its errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from subprocesses import python_path_environment

from swat_jax.morphology import SETS, benchmark_names
from swat_jax.morphology.__main__ import limb_depths, main

REPO = Path(__file__).resolve().parents[1]
REQUIRED_KEYS = {
    "name",
    "family",
    "limbs",
    "parents",
    "limb_types",
    "joint_ranges",
    "motors",
    "traversals",
    "relations",
    "timestep",
    "frame_skip",
    "integrator",
}


def show_json(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    """Run `show --json` in-process and parse its stdout."""
    assert main(["show", "--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


def test_show_json_hopper_3(capsys):
    shown = show_json(capsys, "hopper_3")
    assert shown.keys() >= REQUIRED_KEYS
    assert shown["name"] == "hopper_3"
    assert shown["family"] == "hopper"
    assert shown["limbs"] == ["torso", "thigh", "foot"]
    assert shown["parents"] == [-1, 0, 1]
    assert shown["limb_types"] == [0, 1, 3]
    assert shown["joint_ranges"] == [[], [[-150, 0]], [[-45, 45]]]
    assert shown["motors"] == [[], [0], [1]]
    assert shown["traversals"] == {"pre": [0, 1, 2], "in": [2, 1, 0], "post": [2, 1, 0]}
    np.testing.assert_allclose(shown["relations"]["ppr"][0], [0.3953, 0.3913, 0.2134], atol=1e-4)
    np.testing.assert_allclose(shown["relations"]["spd"][0], [0, 1 / 3, 2 / 3], atol=1e-6)
    np.testing.assert_allclose(np.diag(shown["relations"]["laplacian"]), [1, 1, 1], atol=1e-6)
    assert shown["timestep"] == pytest.approx(0.002)
    assert shown["frame_skip"] == 4
    assert shown["integrator"] == "RK4"


def test_show_json_ostrich_motors(capsys):
    shown = show_json(capsys, "nervenet_ostrich")
    assert len(shown["limbs"]) == 9
    assert shown["motors"] == [[], [6], [7], [0], [1], [2], [3], [4], [5]]
    for kind in ("laplacian", "spd", "ppr"):
        assert np.asarray(shown["relations"][kind]).shape == (9, 9)
    for kind in ("pre", "in", "post"):
        assert sorted(shown["traversals"][kind]) == list(range(9))


def test_show_json_accepts_a_file_path(capsys):
    shown = show_json(capsys, str(REPO / "morphologies" / "walker_2_main.xml"))
    assert shown["name"] == "walker_2_main"
    assert shown["limbs"][0] == "torso"


@pytest.mark.parametrize(("body", "changes"), [("walker_3_main", True), ("hopper_3", False)])
def test_reference_inorder_changes_only_bodies_with_childless_siblings(capsys, body, changes):
    standard = show_json(capsys, body)["traversals"]
    reference = show_json(capsys, "--reference-inorder", body)["traversals"]
    assert (reference["in"] != standard["in"]) is changes
    assert reference["pre"] == standard["pre"]
    assert reference["post"] == standard["post"]


def test_show_tables_hopper_3(capsys):
    assert main(["show", "hopper_3"]) == 0
    out = capsys.readouterr().out
    tree = out[out.index("Limb tree:") : out.index("Traversal")]
    assert "thigh_joint [-150, 0] deg motor 0" in tree
    assert "foot_joint [-45, 45] deg motor 1" in tree
    assert "    foot " in tree, "foot is at depth 2 and indented below thigh"
    for relation in ("laplacian", "spd", "ppr"):
        assert f"Relation {relation}:" in out
    assert "torso 0.395 0.391 0.213" in out
    assert "-0.707" in out


def test_limb_depths():
    assert limb_depths([-1, 0, 1, 0, 3, 4]) == [0, 1, 2, 1, 2, 3]


def test_list_names_every_set_and_body(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in SETS:
        assert name in out
    assert len(benchmark_names()) == 95
    for body in benchmark_names():
        assert body in out
    assert "at most 13 limbs" in out, "animal_walkers' largest body, nervenet_fullcheetah, has 13 limbs"


@pytest.mark.parametrize("command", ["show", "render"])
def test_bad_name_is_an_error_with_a_suggestion(capsys, tmp_path, command):
    args = [command, "hoper_3"] + (["-o", str(tmp_path / "x.png")] if command == "render" else [])
    assert main(args) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("error: ")
    assert "hopper_3" in captured.err
    assert "Traceback" not in captured.err
    assert captured.out == ""


def render(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], body: str, width: int, height: int
) -> np.ndarray:
    """Run `render` in-process and read back the PNG it wrote."""
    output = tmp_path / f"{body}.png"
    assert main(["render", body, "-o", str(output), "--width", str(width), "--height", str(height)]) == 0, (
        capsys.readouterr().err
    )
    assert output.read_bytes().startswith(b"\x89PNG")
    return iio.imread(output)


def limb_pixels(image: np.ndarray) -> np.ndarray:
    """[H, W] mask of the orange limb material (red well above blue; sky and floor are blue)."""
    return image[..., 0].astype(int) > image[..., 2].astype(int) + 40


def test_render_writes_a_png_of_each_body(tmp_path, capsys):
    hopper = render(tmp_path, capsys, "hopper_3", 160, 120)
    cheetah = render(tmp_path, capsys, "cheetah_7_full", 160, 120)
    assert hopper.shape == (120, 160, 3)
    assert hopper.dtype == np.uint8
    assert len(np.unique(hopper.reshape(-1, 3), axis=0)) > 10
    assert np.abs(hopper.astype(int) - cheetah.astype(int)).mean() > 1.0
    for image in (hopper, cheetah):
        rows, columns = np.nonzero(limb_pixels(image))
        assert len(rows) > 100, "the body is in view"
        assert abs(columns.mean() - 80) < 20, "the camera is aimed at the body"


def test_render_larger_than_the_default_framebuffer(tmp_path, capsys):
    assert render(tmp_path, capsys, "walker_2_main", 800, 90).shape == (90, 800, 3)


def test_render_bad_size_or_backend_is_an_error(tmp_path, capsys, monkeypatch):
    output = tmp_path / "x.png"
    assert main(["render", "hopper_3", "-o", str(output), "--width", "0"]) == 2
    assert capsys.readouterr().err.startswith("error: image size must be positive")
    monkeypatch.setenv("MUJOCO_GL", "nonsense")
    assert main(["render", "hopper_3", "-o", str(output)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "MUJOCO_GL" in err and "egl" in err
    assert not output.exists()


def test_help_runs_as_a_module():
    result = subprocess.run(
        [sys.executable, "-m", "swat_jax.morphology", "--help"],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=python_path_environment(REPO),
        check=False,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    for command in ("list", "show", "render"):
        assert command in result.stdout
