"""A synthetic multi-view capture: a calibrated ring of cameras around the subject renders every
frame of a sequence (`python -m factory.dataset capture`).

Its folder: `capture.json` (its settings and input files' digests: a rerun renders only what is
missing, and only for the same capture), `cameras.json` (`assets.cameras`), images per camera
(``cam00/f000012.png``, its depth EXR and camera JSON, ``cam00/render.json``) with their ground
truth (``f000012_gt.npz``), `garment.npz` (the ground-truth garment sequence: positions, faces,
frames, template level), `template.npz`, `texture.png`, `scene.npz`, the render jobs and the
simulation (``sim/``), and ``contact_sheet.png``: the synthetic capture reconstruction is tested and
measured on.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from assets.body import load_body
from assets.cameras import Camera, save_cameras
from assets.fileio import check_settings, load_npz, record_stage, save_json, save_npz
from assets.garments.markers import MarkerSurface
from factory.dressing import DressingParams
from factory.groundtruth import image_ground_truth
from factory.plan import (RenderSettings, check_betas, input_record, keyed_rng, reuse_simulation,
                          simulation_config)
from factory.preview import preview
from factory.scenes import corner_uv, read_depth, render_job_spec, render_template, run_render_job, write_scene
from factory.simulate import SimulationConfig, simulate

#: a capture's cameras fit the garment to this fraction of the image's narrow side
CAPTURE_FILL = 0.9


def camera_ring(count: int, radius: float, height: float, target: np.ndarray, width: int, height_px: int,
                focal_mm: float = 35.0) -> list[Camera]:
    """`count` cameras evenly on a horizontal circle of `radius` around `target` at `height`, looking at
    `target`; `focal_mm` on a 36 mm wide sensor."""
    cameras = []
    for c in range(count):
        angle = 2 * np.pi * c / count - np.pi / 2  # camera 0 in front of the subject (-Y)
        eye = np.array([target[0] + radius * np.cos(angle), target[1] + radius * np.sin(angle), height])
        cameras.append(Camera.look_at(eye, target, focal_mm=focal_mm, width=width, height=height_px,
                                      name=f"cam{c:02d}"))
    return cameras


def fitted_ring(count: int, radius: float, height: float, points: np.ndarray, width: int, height_px: int,
                fill: float = CAPTURE_FILL) -> list[Camera]:
    """A `camera_ring` looking at the centroid of `points` (N, 3), each camera's focal length chosen so
    the points span `fill` of the image (up to its edge, about the centre) in the limiting direction:
    markers as large as the resolution allows, nothing of the garment cut off."""
    centre = points.mean(axis=0)
    rig = camera_ring(count, radius, height, centre, width, height_px)
    fitted = []
    for camera in rig:
        pixels, z = camera.project(points)
        if not (z > 0).all():
            raise ValueError(f"camera ring of radius {radius} m is inside the garment: choose a larger radius")
        reach = np.abs(pixels - camera.K[:2, 2]).max(axis=0) / (np.array([width, height_px]) / 2)
        fitted.append(Camera.look_at(camera.center, centre, focal_mm=35.0 * fill / reach.max(), width=width,
                                     height=height_px, name=camera.name))
    return fitted


def capture(garment: str, motion: str, out: str | Path, frames: int = 12, first_frame: int | None = None,
            cameras: int = 8, resolution: tuple[int, int] = (1920, 1080), render: RenderSettings = RenderSettings(),
            body: str = "default", radius: float = 3.0, camera_height: float = 1.3, seed: int = 0,
            progress: bool = True, simulation: str | Path | None = None, level_mm: int = DressingParams.level_mm,
            motion_speed: float = 1.0, betas: tuple[float, ...] | None = None) -> Path:
    """Render `frames` consecutive simulation frames from a ring of `cameras` (each fitting the garment
    in its view), with ground truth and ``contact_sheet.png``; returns the folder.  The garment is
    simulated on template level `level_mm` with the motion at `motion_speed` on the body shaped by
    `betas` (None: the motion's or the body's own shape), or taken from the finished simulation folder
    `simulation`, which must be that simulation."""
    out = Path(out)
    betas = check_betas(betas, body)
    transition = int(round(SimulationConfig(garment, motion).transition_seconds * 120))
    start = transition if first_frame is None else first_frame
    picked = list(range(start, start + frames))
    sim_config = simulation_config(garment, motion, body, picked[-1] + 1, seed, level_mm, motion_speed, betas)
    render = replace(render, resolution=tuple(resolution))
    # the images of a rerun join those already rendered: only a rerun of the same capture may add to them
    settings = {"simulation": sim_config.key(), **input_record(sim_config.inputs()), "frames": picked,
                "cameras": cameras, "render": asdict(render), "radius": radius, "camera_height": camera_height,
                "seed": seed, "betas": betas}
    check_settings(out / "capture.json", settings)  # refused before a reused simulation is copied in
    if simulation is not None:
        reuse_simulation(simulation, out / "sim", sim_config)
    record_stage(out / "capture.json", settings)
    body_model = load_body(body)
    template = render_template(garment, render.texture_dpi, out)
    sim = simulate(sim_config, out / "sim", progress=progress)
    sequence = load_npz(sim, required=("positions", "faces", "body_poses", "body_trans", "body_betas", "meta"))
    level_mm = int(json.loads(str(sequence["meta"])).get("level_mm", 12))
    positions = sequence["positions"][picked]
    body_vertices = body_model.pose(sequence["body_poses"][picked], sequence["body_trans"][picked],
                                    sequence["body_betas"]).vertices
    rig = fitted_ring(cameras, radius, camera_height, positions.reshape(-1, 3), *render.resolution)
    save_cameras(out / "cameras.json", rig)
    save_npz(out / "garment.npz", {"positions": positions, "faces": sequence["faces"],
                                   "frames": np.asarray(picked), "level_mm": np.array(level_mm),
                                   "garment": np.array(garment), "motion": np.array(motion)})
    template.save(out / "template.npz", levels=(level_mm,))
    write_scene(out / "scene.npz", positions, sequence["faces"], corner_uv(template, level_mm), np.asarray(picked),
                body_vertices, body_model.faces)
    from factory.render import bundled_environments

    hdri = bundled_environments()[keyed_rng(seed, "capture").integers(len(bundled_environments()))]
    surface = MarkerSurface.build(template, level_mm)
    for cam in rig:
        folder = out / cam.name
        pending = [f for f in picked if not (folder / f"f{f:06d}_gt.npz").exists()]
        if not pending:
            continue
        images = [{"name": f"f{f:06d}", "frame": f, "camera": cam.to_dict(), "transform": np.eye(4).tolist(),
                   "environment": {"type": "hdri", "file": hdri, "rotation_deg": 0.0, "strength": 1.0},
                   "cloth": {"roughness": 0.8, "sheen": 0.5}, "skin": {"rgb": [0.85, 0.64, 0.52]},
                   "seed": seed} for f in pending]
        job = out / "jobs" / f"{cam.name}.json"
        save_json(job, render_job_spec(render, Path("..") / "scene.npz", Path("..") / "texture.png", images))
        run_render_job(job, folder, progress)
        for f in tqdm(pending, desc=f"ground truth {cam.name}", unit="image", disable=not progress):
            gt = image_ground_truth(surface, positions[picked.index(f)].astype(np.float64), cam,
                                    read_depth(folder / f"f{f:06d}_depth.exr"))
            gt.save(folder / f"f{f:06d}_gt.npz")
    preview(out, out / "contact_sheet.png")
    return out
