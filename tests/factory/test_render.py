"""factory.render: real renders of a tiny scene through both entry points (bpy 5.0 module, Blender 3.4).

The scene: a 20 cm square garment (8 triangles, a red/blue checker texture) facing an OpenCV camera
that looks along world +Y from (0, -1, 1), in front of a 30 cm box "body".  Image 0 shows frame 10
(garment 1.0 m away), image 1 frame 20 (garment 0.9 m) moved 0.2 m further by its transform: 1.1 m.
"""

import ctypes.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

from assets.cameras import Camera
from factory.render import bundled_environments

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = "factory/render.py"
SIZE = 64
FOCAL_PX = 160.0
GARMENT_DEPTH = (1.0, 1.1)    # per image, metres along the view axis
GARMENT_BOX = (20, 44)        # pixel rows/cols inside the garment in both images (it spans 17.5..46.5 at 1.1 m)
CAMERA = Camera(K=[[FOCAL_PX, 0, SIZE / 2], [0, FOCAL_PX, SIZE / 2], [0, 0, 1]],
                R=[[1, 0, 0], [0, 0, -1], [0, 1, 0]], t=[0, 1, 1], width=SIZE, height=SIZE, name="front")


def _scene(folder: Path) -> None:
    """scene.npz and the texture: the garment square in the plane y = 0 (frame 10) or y = -0.1 (frame 20)."""
    grid = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 3), np.linspace(0.9, 1.1, 3)), axis=-1).reshape(-1, 2)
    quads = [(r * 3 + c, r * 3 + c + 1, r * 3 + c + 4, r * 3 + c + 3) for r in range(2) for c in range(2)]
    faces = np.array([(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads], dtype=np.int32)
    flat = np.column_stack([grid[:, 0], np.zeros(9), grid[:, 1]])
    positions = np.stack([flat, flat - [0, 0.1, 0]]).astype(np.float32)
    uv = ((grid - [-0.1, 0.9]) / 0.2)[faces].astype(np.float32)
    corners = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (0.15, 0.45) for z in (0.85, 1.15)])
    box_faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int32)
    np.savez(folder / "scene.npz", garment_positions=positions, garment_faces=faces, garment_uv=uv,
             frames=np.array([10, 20]), body_vertices=np.stack([corners, corners]).astype(np.float32),
             body_faces=box_faces)
    checks = (np.indices((64, 64)) // 16).sum(axis=0) % 2
    texture = np.where(checks[..., None] == 1, [255, 0, 0], [0, 0, 255]).astype(np.uint8)  # BGR: blue / red
    cv2.imwrite(str(folder / "texture.png"), texture)


def _job(folder: Path, engine: str, position: bool, scene: str = "scene.npz") -> Path:
    translate = np.eye(4)
    translate[1, 3] = 0.2
    common = {"camera": CAMERA.to_dict(), "cloth": {"roughness": 0.8, "sheen": 0.5},
              "skin": {"rgb": [0.8, 0.6, 0.5]}}
    images = [
        {"name": "f10", "frame": 10, "transform": np.eye(4).tolist(), "seed": 1, **common,
         "environment": {"type": "hdri", "file": bundled_environments()[0], "rotation_deg": 30.0, "strength": 1.0}},
        {"name": "f20", "frame": 20, "transform": translate.tolist(), "seed": 2, **common,
         "environment": {"type": "sky", "sun_elevation_deg": 35.0, "sun_rotation_deg": 120.0, "strength": 0.1}},
    ]
    job = {"version": 1, "scene": scene, "texture": "texture.png", "resolution": [SIZE, SIZE],
           "engine": {"name": engine, "samples": 4, "denoise": False, "device": "auto"},
           "passes": {"depth": True, "position": position}, "images": images}
    path = folder / f"job_{engine.lower()}.json"
    path.write_text(json.dumps(job))
    return path


def _command(runner: str) -> list[str]:
    if runner == "bpy":
        return [sys.executable, SCRIPT]
    blender = shutil.which("blender")
    if blender is None:
        pytest.fail("no `blender` executable on PATH: `apt-get install blender` (Debian's 3.4) to run these tests")
    return [blender, "-b", "-P", SCRIPT, "--"]


def _render(runner: str, job: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(_command(runner) + ["--job", str(job), "--out", str(out), "--no-progress", *extra],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


def _exr(path: Path) -> dict[str, np.ndarray]:
    return {name: channel.pixels for name, channel in OpenEXR.File(str(path)).channels().items()}


def _check_outputs(out: Path, position: bool) -> None:
    inner = slice(*GARMENT_BOX)
    for name, depth_m in zip(("f10", "f20"), GARMENT_DEPTH):
        rgb = cv2.imread(str(out / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert rgb.shape == (SIZE, SIZE, 3) and rgb.dtype == np.uint8
        garment = rgb[inner, inner].reshape(-1, 3).astype(int)
        red, blue = garment[:, 2] > garment[:, 0] + 30, garment[:, 0] > garment[:, 2] + 30
        assert red.mean() > 0.25 and blue.mean() > 0.25, f"{name}: the garment does not show the checker texture"

        depth = _exr(out / f"{name}_depth.exr")
        assert list(depth) == ["Z"] and depth["Z"].dtype == np.float32 and depth["Z"].shape == (SIZE, SIZE)
        z = depth["Z"]
        assert np.abs(z[inner, inner] - depth_m).max() < 0.01, f"{name}: garment depth off {depth_m} m"
        assert np.isposinf(z[:6, :6]).all(), f"{name}: background depth is not +inf"

        if position:
            xyz = _exr(out / f"{name}_position.exr")
            assert sorted(xyz) == ["X", "Y", "Z"]
            assert np.abs(xyz["Y"][inner, inner] - (depth_m - 1.0)).max() < 0.01  # the garment plane y
            assert np.isnan(xyz["X"][:6, :6]).all()
        else:
            assert not (out / f"{name}_position.exr").exists()

        camera = Camera.from_dict(json.loads((out / f"{name}_camera.json").read_text()))
        assert camera.to_dict() == CAMERA.to_dict()


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("render")
    _scene(folder)
    return folder


@pytest.mark.slow
@pytest.mark.parametrize("runner", ["bpy", "blender"])
def test_cycles_outputs_resume_and_force(scene_dir, tmp_path, runner):
    job = _job(scene_dir, "CYCLES", position=True)
    result = _render(runner, job, tmp_path)
    assert result.returncode == 0, result.stderr + result.stdout
    _check_outputs(tmp_path, position=True)
    assert not list(tmp_path.glob(".*")), "temporary files left behind"

    assert json.loads((tmp_path / "render.json").read_text()) == {
        "resolution": [SIZE, SIZE], "engine": "CYCLES", "samples": 4, "denoise": False, "device": "auto",
        "passes": {"depth": True, "position": True}}
    files = sorted(f for f in tmp_path.iterdir() if f.name != "render.json")
    mtimes = [f.stat().st_mtime_ns for f in files]
    result = _render(runner, job, tmp_path)
    assert result.returncode == 0, result.stderr
    assert "skipped" in result.stderr
    assert [f.stat().st_mtime_ns for f in files] == mtimes
    if runner == "bpy":  # refusing and forcing are the same code under both Blenders
        more = job.with_name("job_more_samples.json")
        more.write_text(json.dumps({**json.loads(job.read_text()), "engine": {
            "name": "CYCLES", "samples": 8, "denoise": False, "device": "auto"}}))
        result = _render(runner, more, tmp_path)  # its images exist, but were made with 4 samples
        assert result.returncode == 2 and "render.json" in result.stderr and "samples: 4 -> 8" in result.stderr
        assert [f.stat().st_mtime_ns for f in files] == mtimes
        result = _render(runner, more, tmp_path, "--force")
        assert result.returncode == 0, result.stderr
        assert all(a != f.stat().st_mtime_ns for a, f in zip(mtimes, files))
        assert json.loads((tmp_path / "render.json").read_text())["samples"] == 8


@pytest.mark.slow
@pytest.mark.skipif(ctypes.util.find_library("EGL") is None,
                    reason="Workbench and EEVEE need OpenGL through EGL: "
                           "libEGL (Mesa; apt-get install libegl1) not found")
@pytest.mark.parametrize("runner", ["bpy", "blender"])
@pytest.mark.parametrize("engine", ["WORKBENCH", "EEVEE"])
def test_raster_engines(scene_dir, tmp_path, runner, engine):
    result = _render(runner, _job(scene_dir, engine, position=False), tmp_path)
    assert result.returncode == 0, result.stderr + result.stdout
    _check_outputs(tmp_path, position=False)


@pytest.mark.parametrize("runner", ["bpy", "blender"])
def test_missing_scene_fails_naming_the_file(scene_dir, tmp_path, runner):
    job = _job(tmp_path, "CYCLES", position=False, scene=str(scene_dir / "nowhere.npz"))
    result = _render(runner, job, tmp_path / "out")
    assert result.returncode == 2
    assert "nowhere.npz" in result.stderr and "scene" in result.stderr and "Traceback" not in result.stderr


def test_position_needs_cycles(scene_dir, tmp_path):
    job = _job(scene_dir, "WORKBENCH", position=True)
    result = _render("bpy", job, tmp_path)
    assert result.returncode == 2 and "passes.position" in result.stderr


def test_bundled_environments():
    names = bundled_environments()
    assert len(names) == 8 and names == sorted(names) and "forest.exr" in names


@pytest.mark.slow
def test_threads_cap_the_render_and_leave_the_images_unchanged(scene_dir, tmp_path):
    """A Ray task renders with the CPUs it declared (`threads`); the pixels do not depend on it."""
    import bpy

    from factory.render import render_job

    job = _job(scene_dir, "CYCLES", position=False)
    render_job(job, tmp_path / "all", progress=False)
    assert bpy.context.scene.render.threads_mode == "AUTO"
    render_job(job, tmp_path / "one", progress=False, threads=1)
    assert (bpy.context.scene.render.threads_mode, bpy.context.scene.render.threads) == ("FIXED", 1)
    for name in ("f10", "f20"):
        pixels = [cv2.imread(str(tmp_path / run / f"{name}.png"), cv2.IMREAD_UNCHANGED) for run in ("all", "one")]
        np.testing.assert_array_equal(pixels[0], pixels[1])
        np.testing.assert_array_equal(*(_exr(tmp_path / run / f"{name}_depth.exr")["Z"] for run in ("all", "one")))
