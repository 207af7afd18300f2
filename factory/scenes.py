"""What the dataset build and the capture share to render: scene files, render jobs, the template's
texture, and the ground truth of a rendered image from its depth EXR."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import numpy as np

from assets.cameras import Camera
from assets.fileio import save_npz
from assets.garments import Template
from assets.garments.loading import load_template
from assets.garments.markers import MarkerSurface
from assets.pattern.observation import ImageGroundTruth, training_samples
from factory.groundtruth import image_ground_truth
from factory.plan import RenderSettings

PROJECT = Path(__file__).resolve().parents[1]


def run_render_job(job: Path, out: Path, progress: bool = True, threads: int = 0):
    """Render a job in this process when the bpy module imports (returns `factory.render.RenderReport`),
    else with a Blender executable (returns None); `threads` render threads, 0 for every core."""
    if importlib.util.find_spec("bpy") is None:
        blender = shutil.which("blender")
        if blender is None:
            raise RuntimeError("rendering needs the bpy module (pip install bpy) or a Blender executable on PATH")
        subprocess.run([blender, "-b", "--factory-startup", "-P", str(PROJECT / "factory" / "render.py"), "--",
                        "--job", str(job), "--out", str(out), "--threads", str(threads)], check=True)
        return
    from factory.render import render_job

    return render_job(job, out, progress=progress, threads=threads)


def write_scene(path: Path, positions: np.ndarray, faces: np.ndarray, uv: np.ndarray, frames: np.ndarray,
                body_vertices: np.ndarray | None, body_faces: np.ndarray | None) -> None:
    arrays = {"garment_positions": positions.astype(np.float32), "garment_faces": faces.astype(np.int32),
              "garment_uv": uv.astype(np.float32), "frames": frames.astype(np.int64)}
    if body_vertices is not None:
        arrays.update(body_vertices=body_vertices.astype(np.float32), body_faces=body_faces.astype(np.int32))
    save_npz(path, arrays)


def render_template(garment: str, dpi: float, out: Path) -> Template:
    """The garment's template with its sheet laid out at `dpi`, and the texture PNG beside it."""
    from assets.pattern.raster import write_png

    template = load_template(garment, dpi)
    if not (out / "texture.png").exists():
        write_png(out / "texture.png", template.layout.render(template.pattern, progress=True), dpi)
    return template


def corner_uv(template: Template, level_mm: int) -> np.ndarray:
    """(F, 3, 2) texture coordinates per corner of the sewn faces (seams have one UV per side)."""
    level = template.level(level_mm)
    return level.uv[level.faces]


def read_exr(path: Path) -> dict[str, np.ndarray]:
    """A float EXR written by `factory.render` -> {channel name: (H, W) float32}."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as exr:
            return {name: np.asarray(c.pixels, dtype=np.float32) for name, c in exr.channels().items()}
    except Exception as exc:  # OpenEXR raises plain RuntimeError for unreadable files
        raise ValueError(f"{path}: not a readable EXR ({exc})") from exc


def read_depth(path: Path) -> np.ndarray:
    """A depth EXR written by `factory.render` -> (H, W) float32 (+inf on the background)."""
    channels = read_exr(path)
    if "Z" not in channels:
        raise ValueError(f"{path}: no 'Z' channel (has {sorted(channels)})")
    return channels["Z"]


def ground_truth_for(surface: MarkerSurface, positions: np.ndarray, image_path: Path,
                     depth_path: Path, camera: Camera) -> tuple[ImageGroundTruth, dict[str, np.ndarray]]:
    import cv2

    image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{image_path}: not a readable image")
    image = image[:, :, ::-1].copy()
    gt = image_ground_truth(surface, positions, camera, read_depth(depth_path))
    return gt, training_samples(image, gt, surface.spec)


def render_job_spec(settings: RenderSettings, scene: Path, texture: Path, images: list[dict],
                    position: bool = False) -> dict:
    """The render job (`factory.renderjob`'s format) of `images` in `settings`, depth pass always,
    position pass when asked; `scene` and `texture` relative to the job file's folder."""
    return {
        "version": 1, "scene": str(scene), "texture": str(texture), "resolution": list(settings.resolution),
        "engine": {"name": settings.engine, "samples": settings.samples, "denoise": settings.denoise,
                   "device": settings.device},
        "passes": {"depth": True, "position": position}, "images": images,
    }
