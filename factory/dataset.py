"""Datasets: simulation -> Blender renders -> ground truth: the plan, the capture and the CLI.

    python -m factory.dataset build --garment shirt --motions walk,run --frames 8 --variations 5 --out out/ds
    python -m factory.dataset build ... --shard 0/4          # a deterministic quarter of the images
    python -m factory.dataset build ... --betas 0.5,0.5,0.8  # another body shape (the body's shape_names)
    python -m factory.dataset build --recipe modules_reader --out out/datasets/modules_reader  # `factory.recipe`
    python -m factory.dataset capture --garment shirt --motion walk --frames 12 --cameras 8 --out out/cap
    python -m factory.dataset preview out/ds --out out/ds/contact_sheet.png
    python -m factory.dataset merge out/all out/ds --train out/ds_more   # more training images (`factory.merge`)

Training dataset (`build`), as in the reference: one fixed camera; per simulation frame
`variations` images (5), each with a random rotation about the vertical and a small tilt and
translation of garment and body, an environment chosen from 10 (Blender's eight bundled HDRIs and two
sky worlds) at a random rotation and strength, and jittered cloth and skin materials.  Every random
choice comes from a generator seeded by (seed, motion, frame, variation), so any image can be remade
alone.  Frames are split into train, validation and test at 22:2:1 **by simulation frame**: the
variations of one frame never straddle splits.

Layout of a dataset folder:
  config.json                  the build's settings (a rerun with other settings is refused)
  template.npz, texture.png    the garment template and its pattern texture at `texture_dpi`
  sim/<motion>/                the simulations (`factory.simulate`; reused when already there)
  sim/dressings/<key>.npz      the dressed garment the motions' simulations share
  scenes/<motion>.npz          the frames to render: garment and body vertices
  jobs/<motion>-<shard>.json   render jobs (`factory.render`)
  images/<name>.png            RGB; <name>_depth.exr (Z, float32), <name>_camera.json (K, R, t)
  gt/<name>.npz                ground truth of every marker (`assets.pattern.observation.ImageGroundTruth`)
  samples/<name>.npz           training arrays: the Marker Localizer's cell targets (`cells`), the
                               96 x 96 recognizer crops with their IDs, the 112 x 112 crosspoint crops
                               with the crosspoints' crop coordinates and visibility
  meta/<name>.json             one finished image (written last: an image is done when this exists)
  manifest.jsonl, splits.json  every finished image with its files, split, motion, frame, variation
                               and simulation (`factory.simulate.SimulationConfig.key()`)

The build itself (`factory.build`; `build --help`): one simulation task per motion, then render +
ground-truth tasks of `--shard-frames` frames; `--shard i/n` takes every n-th image from the i-th, a
killed run resumes where it stopped, several processes or machines sharing the folder can work on one
dataset at once, and `--backend ray` runs the tasks on a Ray cluster (`factory.raybackend`).

Capture (`capture`): a calibrated ring of cameras around the subject renders every frame of a
sequence: `cameras.json` (`assets.cameras`), images per camera (``cam00/f000012.png``...), ground
truth per image, and `garment.npz` (the ground-truth garment sequence: positions, faces, template):
the synthetic capture reconstruction is tested and measured on.  `capture.json` records its settings
and input files' digests: a rerun renders only what is missing, and only for the same capture.

This module holds the settings (`RenderSettings`, `DatasetConfig`), the plan (splits, per-image
variations, the fixed camera), what the build and the capture share (the simulation settings, render
jobs, scenes, ground truth of a rendered image), the capture, the contact sheet and the CLI.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from assets.body import load_body
from assets.cameras import Camera, save_cameras
from assets.fileio import copy_file, load_json, load_npz, check_settings, save_json, save_npz
from assets.garments import Template
from assets.pattern.observation import ImageGroundTruth, training_samples
from assets.garments.markers import MarkerSurface
from factory.groundtruth import image_ground_truth
from assets.garments.loading import load_template
from factory.dressing import DressingParams
from factory.limits import Limits, add_limit_options, limits_from_args
from factory.simulate import SimulationConfig, read_meta, simulate

PROJECT = Path(__file__).resolve().parents[1]
#: the reference's train : validation : test ratio, by simulation frame
SPLIT_RATIO = (22, 2, 1)
SPLITS = ("train", "val", "test")
#: the two sky worlds added to Blender's eight HDRIs (10 environments)
SKY_WORLDS = 2
#: a capture's cameras fit the garment to this fraction of the image's narrow side
CAPTURE_FILL = 0.9


@dataclass(frozen=True)
class RenderSettings:
    resolution: tuple[int, int] = (512, 512)  # width, height
    engine: str = "CYCLES"
    samples: int = 64
    denoise: bool = True
    device: str = "auto"
    #: pattern texture resolution; 100 DPI is 7.9 texels per 2 mm cell
    texture_dpi: float = 100.0


@dataclass(frozen=True)
class DatasetConfig:
    garment: str
    motions: tuple[str, ...]
    body: str = "default"
    #: the body's shape values (`BodyModel.shape_names`); None: each motion's own or the body's default
    betas: tuple[float, ...] | None = None
    #: frames per motion, `frame_step` simulation frames (1/120 s) apart after the dressing transition
    frames: int = 8
    frame_step: int = 12
    #: explicit simulation frame indices instead of `frames` x `frame_step` (tests, hand-picked frames)
    frame_list: tuple[int, ...] | None = None
    variations: int = 5
    seed: int = 0
    #: the simulation's template level (mm) and motion speed multiplier (`factory.simulate`'s --level, --speed)
    level_mm: int = DressingParams.level_mm
    motion_speed: float = 1.0
    render: RenderSettings = field(default_factory=RenderSettings)
    #: largest random tilt (degrees) and translation (m) of garment and body per variation
    max_tilt_deg: float = 10.0
    max_shift: float = 0.05
    #: the camera's horizontal field of view (degrees) and how much of the frame the garment fills
    fov_deg: float = 40.0
    fill: float = 0.85


# ---- plans -------------------------------------------------------------------------------------

def _rng(*keys: object) -> np.random.Generator:
    digest = hashlib.sha256(json.dumps([str(k) for k in keys]).encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def split_of_frames(units: list[tuple[str, int]], seed: int, ratio: tuple[int, int, int] = SPLIT_RATIO) -> dict:
    """(motion, frame) units -> split name, at `ratio` (train : val : test) over a seeded shuffle;
    with three or more units, validation and test get at least one each."""
    order = _rng("split", seed).permutation(len(units))
    n = len(units)
    total = sum(ratio)
    n_test = int(round(n * ratio[2] / total))
    n_val = int(round(n * ratio[1] / total))
    if n >= 3:
        n_test, n_val = max(1, n_test), max(1, n_val)
    names = ["test"] * n_test + ["val"] * n_val + ["train"] * (n - n_test - n_val)
    return {units[i]: names[k] for k, i in enumerate(order)}


def environments(bundled: list[str]) -> list[dict]:
    """The 10 environments: Blender's bundled HDRIs (by file name) and two skies."""
    return [{"type": "hdri", "file": name} for name in bundled] + [{"type": "sky"} for _ in range(SKY_WORLDS)]


def variation(config: DatasetConfig, motion: str, frame: int, v: int, centre: np.ndarray, envs: list[dict]) -> dict:
    """The random choices of one image: garment transform, environment, materials, seed."""
    rng = _rng(config.seed, motion, frame, v)
    tilt = np.clip(rng.normal(0.0, config.max_tilt_deg / 2, 2), -config.max_tilt_deg, config.max_tilt_deg)
    rotation = Rotation.from_euler("zxy", [rng.uniform(0.0, 360.0), tilt[0], tilt[1]], degrees=True).as_matrix()
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = rotation @ -centre + rng.uniform(-config.max_shift, config.max_shift, 3)
    env = dict(envs[int(rng.integers(len(envs)))])
    if env["type"] == "hdri":
        env.update(rotation_deg=float(rng.uniform(0.0, 360.0)), strength=float(rng.uniform(0.7, 1.3)))
    else:
        env.update(sun_elevation_deg=float(rng.uniform(15.0, 60.0)), sun_rotation_deg=float(rng.uniform(0.0, 360.0)),
                   strength=float(rng.uniform(0.03, 0.1)))  # brighter overexposes
    skin = np.array([[0.85, 0.64, 0.52], [0.62, 0.43, 0.32], [0.40, 0.26, 0.18], [0.93, 0.76, 0.66]])
    return {
        "transform": transform.tolist(), "environment": env,
        "cloth": {"roughness": float(rng.uniform(0.6, 0.95)), "sheen": float(rng.uniform(0.2, 0.8))},
        "skin": {"rgb": (skin[rng.integers(len(skin))] * rng.uniform(0.9, 1.1)).clip(0, 1).tolist()},
        "seed": int(rng.integers(2**31 - 1)),
    }


def fixed_camera(radius: float, settings: RenderSettings, fov_deg: float, fill: float) -> Camera:
    """The dataset's camera, in front of the origin (-Y, looking +Y), far enough that a sphere of
    `radius` around the origin fills `fill` of the narrower image side."""
    width, height = settings.resolution
    half = np.radians(fov_deg) / 2
    narrow = min(1.0, height / width)
    distance = radius / np.sin(np.arctan(np.tan(half) * narrow) * fill)
    sensor = 36.0
    focal = sensor / (2 * np.tan(half))
    return Camera.look_at((0.0, -distance, 0.0), (0.0, 0.0, 0.0), focal_mm=focal, sensor_mm=sensor,
                          width=width, height=height, name="fixed")


# ---- rendering ---------------------------------------------------------------------------------

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


# ---- simulations -------------------------------------------------------------------------------

def simulation_config(garment: str, motion: str, body: str = "default", frames: int = 1, seed: int = 0,
                      level_mm: int = DressingParams.level_mm, motion_speed: float = 1.0,
                      betas: tuple[float, ...] | None = None) -> SimulationConfig:
    """The simulation the factory makes of `motion` (`factory.simulate`'s defaults otherwise)."""
    return SimulationConfig(garment=garment, motion=motion, body=body, frames=frames, betas=betas, seed=seed,
                            motion_speed=motion_speed, dressing=replace(DressingParams(), level_mm=level_mm))


def check_betas(betas: str | tuple[float, ...] | None, body: str, option: str = "betas") -> tuple[float, ...] | None:
    """`betas` (numbers, or an option's comma-separated text) as the shape values of `body`: finite
    numbers, one per `shape_names` entry, within the body's range; None stays None (the motion's or the
    body's own shape).  A ValueError names `option` and the body's shape values."""
    if betas is None:
        return None
    model = load_body(body)
    expected = f"{model.num_betas} comma-separated numbers ({', '.join(model.shape_names)}) for body {body!r}"
    try:
        values = tuple(float(v) for v in (betas.split(",") if isinstance(betas, str) else betas))
    except (TypeError, ValueError):
        raise ValueError(f"{option}: expected {expected}, got {betas!r}") from None
    if len(values) != model.num_betas or not np.isfinite(values).all():
        raise ValueError(f"{option}: expected {expected}, got {betas!r}")
    try:
        model.shape_coefficients(np.asarray(values))
    except ValueError as exc:  # outside a shape grid's range
        raise ValueError(f"{option}: {exc}") from None
    return values


def reuse_simulation(source: str | Path, target: Path, config: SimulationConfig) -> None:
    """Copy a finished simulation folder (``sequence.npz``, ``dressed.npz``) to `target`, where
    `factory.simulate` takes it up (and continues it when it has fewer frames than needed).  A folder
    holding another simulation than `config`'s (which would silently be simulated again) is refused,
    naming the options that differ."""
    source = Path(source)
    if not (source / "sequence.npz").is_file():
        raise ValueError(f"{source}: no sequence.npz (not a finished simulation folder)")
    meta = read_meta(source / "sequence.npz", load_npz(source / "sequence.npz", only=("meta",)))
    if meta.get("key") != config.key():
        differ = config.differences(meta.get("config", {})) or ["the simulator's version"]
        raise ValueError(f"{source / 'sequence.npz'}: another simulation than this one's (recorded there, not here: "
                         f"{'; '.join(differ)}); give the options it was made with (--garment, --motion, --body, "
                         "--betas, --seed, --level, --speed) or leave out --reuse-simulation")
    for name in ("sequence.npz", "dressed.npz"):
        if (source / name).is_file() and not (target / name).exists():
            copy_file(source / name, target / name)


# ---- multi-view capture ------------------------------------------------------------------------

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
    settings = {"simulation": sim_config.key(), "inputs": sim_config.inputs(), "frames": picked, "cameras": cameras,
                "render": asdict(render), "radius": radius, "camera_height": camera_height, "seed": seed,
                "betas": betas}
    check_settings(out / "capture.json", settings)
    if simulation is not None:
        reuse_simulation(simulation, out / "sim", sim_config)
    out.mkdir(parents=True, exist_ok=True)
    save_json(out / "capture.json", settings)
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

    hdri = bundled_environments()[_rng(seed, "capture").integers(len(bundled_environments()))]
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


# ---- contact sheet -----------------------------------------------------------------------------

def draw_ground_truth(image: np.ndarray, gt: ImageGroundTruth, zoom: float = 1.0) -> np.ndarray:
    """The image (H, W, 3) uint8, resized by `zoom`, with every visible marker's outline (green: fully
    visible, orange: partially), its ID at the centre, and its visible crosspoints (magenta dots)."""
    import cv2

    h, w = image.shape[:2]
    canvas = cv2.resize(image[:, :, ::-1], (int(round(w * zoom)), int(round(h * zoom))), interpolation=cv2.INTER_AREA
                        if zoom < 1 else cv2.INTER_LINEAR)
    for m in np.flatnonzero(gt.status > 0):
        colour = (0, 200, 0) if gt.status[m] == 2 else (0, 160, 255)
        for x, y in gt.crosspoints_px[m][gt.crosspoint_visible[m]][::4] * zoom:
            canvas[min(int(y), canvas.shape[0] - 1), min(int(x), canvas.shape[1] - 1)] = (255, 0, 255)
        corners = gt.points_px[m, [1, 2, 4, 3]] * zoom  # TL, TR, BR, BL
        if np.isfinite(corners).all():
            cv2.polylines(canvas, [np.round(corners).astype(np.int32)], True, colour, 1, cv2.LINE_AA)
        if gt.point_visible[m, 0]:
            x, y = gt.points_px[m, 0] * zoom
            cv2.putText(canvas, str(int(gt.marker_id[m])), (int(x) - 8, int(y) + 3), cv2.FONT_HERSHEY_PLAIN, 0.7,
                        (255, 255, 255), 1, cv2.LINE_AA)
    return canvas[:, :, ::-1]


def contact_sheet(pairs: list[tuple[Path, Path]], png: str | Path, columns: int = 3, tile: int = 384,
                  labels: list[str] | None = None) -> Path:
    """Images with their ground truth drawn on top, tiled into one PNG: (image path, gt path) pairs,
    each tile `tile` pixels wide at the images' aspect, labelled with `labels` (default: file stems)."""
    import cv2

    from assets.fileio import atomic_path

    if not pairs:
        raise ValueError(f"{png}: no finished images to show")
    tiles = []
    for k, (image_path, gt_path) in enumerate(pairs):
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"{image_path}: not a readable image")
        drawn = np.ascontiguousarray(draw_ground_truth(image[:, :, ::-1], ImageGroundTruth.load(gt_path),
                                                       tile / image.shape[1]))
        label = labels[k] if labels else image_path.stem
        cv2.putText(drawn, label, (4, drawn.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(drawn)
    tile_h = max(t.shape[0] for t in tiles)
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * tile_h, columns * tile, 3), 255, np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, columns)
        sheet[r * tile_h:r * tile_h + t.shape[0], c * tile:c * tile + t.shape[1]] = t
    with atomic_path(png) as tmp:
        ok, data = cv2.imencode(".png", sheet[:, :, ::-1])
        tmp.write_bytes(data.tobytes())
    return Path(png)


def preview(folder: str | Path, png: str | Path, count: int = 6) -> Path:
    """A contact sheet of a dataset (`manifest.jsonl`) or a capture (`cameras.json`) folder."""
    folder = Path(folder)
    if (folder / "manifest.jsonl").exists():
        entries = [json.loads(line) for line in (folder / "manifest.jsonl").read_text().splitlines() if line]
        step = max(1, len(entries) // count)
        pairs = [(folder / e["image"], folder / e["gt"]) for e in entries[::step][:count]]
    elif (folder / "cameras.json").exists():
        pngs = sorted(p for p in folder.glob("cam*/f*.png"))
        step = max(1, len(pngs) // count)
        shown = pngs[::step][:count]
        pairs = [(p, p.with_name(f"{p.stem}_gt.npz")) for p in shown]
        return contact_sheet(pairs, png, labels=[f"{p.parent.name}/{p.stem}" for p in shown])
    else:
        raise ValueError(f"{folder}: neither a dataset (manifest.jsonl) nor a capture (cameras.json)")
    return contact_sheet(pairs, png)


# ---- CLI ---------------------------------------------------------------------------------------

def _resolution(text: str) -> tuple[int, int]:
    try:
        parts = [int(v) for v in text.lower().split("x")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be N or WxH, got {text!r}") from None
    if len(parts) == 1:
        parts *= 2
    if len(parts) != 2 or min(parts) < 8:
        raise argparse.ArgumentTypeError(f"resolution must be N or WxH with sides >= 8, got {text!r}")
    return parts[0], parts[1]


def _shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"shard must be i/n, got {text!r}") from None
    return i, n


def _add_render_args(p: argparse.ArgumentParser, resolution: str) -> None:
    p.add_argument("--resolution", type=_resolution, default=_resolution(resolution), help="N or WxH pixels")
    p.add_argument("--engine", choices=("CYCLES", "EEVEE", "WORKBENCH"), default="CYCLES")
    p.add_argument("--samples", type=int, default=RenderSettings.samples)
    p.add_argument("--no-denoise", action="store_true")
    p.add_argument("--device", choices=("auto", "CPU", "GPU"), default="auto")
    p.add_argument("--texture-dpi", type=float, default=RenderSettings.texture_dpi)


def _add_simulation_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--level", type=int, default=DressingParams.level_mm,
                   help="template level (mm) the garment is simulated on (factory.simulate --level)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="built-in motions: speed multiplier (factory.simulate --speed)")
    p.add_argument("--betas", metavar="V,V,...",
                   help="the body's shape values, one per shape name (the default body: gender,weight,height, each "
                   "in [0, 1]); default: the motion's own shape, else the body's default")


def _check_sizes(args: argparse.Namespace, limits: Limits, last_frame: int, images_per_frame: tuple[str, int]) -> None:
    """The sizes a build or capture asks for within `limits`, before anything is made: image pixels,
    samples, the last simulation frame and (option, value) images per frame (variations or cameras)."""
    width, height = args.resolution
    limits.check("pixels", width * height, f"an image of {width} x {height} pixels", "--resolution")
    if args.samples < 1:
        raise ValueError(f"--samples: expected >= 1, got {args.samples}")
    limits.check("samples", args.samples, "the render samples", "--samples")
    limits.check("frames", last_frame, "the last simulation frame", "--frames")
    option, count = images_per_frame
    if count < 1:
        raise ValueError(f"{option}: expected >= 1, got {count}")
    limits.check(option.lstrip("-"), count, f"the number of {option.lstrip('-')}", option)


def _render_settings(args: argparse.Namespace) -> RenderSettings:
    return RenderSettings(resolution=tuple(args.resolution), engine=args.engine, samples=args.samples,
                          denoise=not args.no_denoise, device=args.device, texture_dpi=args.texture_dpi)


def main(argv: list[str] | None = None) -> int:
    import factory.build  # it imports this module: imported when the CLI runs, not at import time
    import factory.merge
    from assets.cli import run_cli
    from factory.recipe import build_recipe

    parser = argparse.ArgumentParser(prog="python -m factory.dataset", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="simulate, render and annotate a training dataset",
                       description=factory.build.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("--recipe", help="build a recipe's data (networks/recipes/NAME.toml, or a .toml file): its "
                   "training and held-out parts, each a dataset folder under --out (`factory.recipe`); the "
                   "recipe gives what --garment .. --texture-dpi give otherwise")
    b.add_argument("--train-only", action="store_true", help="--recipe: its training parts only")
    b.add_argument("--garment", help="the garment (required without --recipe)")
    b.add_argument("--motions", help="comma-separated motion names or files (required without --recipe)")
    b.add_argument("--body", default="default")
    b.add_argument("--frames", type=int, default=DatasetConfig.frames, help="frames per motion")
    b.add_argument("--frame-step", type=int, default=DatasetConfig.frame_step, help="simulation frames between them")
    b.add_argument("--frame-list", help="explicit comma-separated simulation frames instead")
    b.add_argument("--variations", type=int, default=DatasetConfig.variations)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--fill", type=float, default=DatasetConfig.fill,
                   help="how much of the narrower image side the garment fills (default %(default)s); smaller: "
                   "smaller markers")
    b.add_argument("--fov", type=float, default=DatasetConfig.fov_deg,
                   help="the camera's horizontal field of view, degrees (default %(default)s)")
    _add_simulation_args(b)
    b.add_argument("--shard", type=_shard, default=(0, 1), help="i/n: this process's share of the images")
    b.add_argument("--backend", choices=factory.build.BACKENDS, default="local",
                   help="local: every task in this process; ray: Ray tasks (pip install '.[ray]')")
    b.add_argument("--address", help="ray: the cluster to join (e.g. HEAD_IP:6379 or auto); default: start a "
                   "local Ray instance")
    b.add_argument("--num-cpus", type=int, help="ray: CPUs of the local Ray instance (default: all)")
    b.add_argument("--shard-frames", type=int, default=1,
                   help="simulation frames (with their variations) per render + ground-truth task")
    b.add_argument("--reuse-simulation", action="append", default=[], metavar="MOTION=DIR",
                   help="a finished `factory.simulate` folder for a motion (repeatable), made with the same "
                   "--garment, --body, --betas, --seed, --level and --speed")
    b.add_argument("--out", type=Path, required=True)
    _add_render_args(b, "512")
    add_limit_options(b, ("pixels", "samples", "frames", "variations"))
    c = sub.add_parser("capture", help="render a sequence from a calibrated ring of cameras")
    c.add_argument("--garment", required=True)
    c.add_argument("--motion", required=True)
    c.add_argument("--body", default="default")
    c.add_argument("--frames", type=int, default=12)
    c.add_argument("--first-frame", type=int, help="default: the first frame after the dressing transition")
    c.add_argument("--cameras", type=int, default=8)
    c.add_argument("--radius", type=float, default=3.0, help="ring radius (m)")
    c.add_argument("--height", type=float, default=1.3, help="ring height (m), about chest height")
    c.add_argument("--seed", type=int, default=0)
    _add_simulation_args(c)
    c.add_argument("--reuse-simulation", type=Path, metavar="DIR",
                   help="a finished `factory.simulate` folder made with the same options")
    c.add_argument("--out", type=Path, required=True)
    _add_render_args(c, "1920x1080")
    add_limit_options(c, ("pixels", "samples", "frames", "cameras"))
    m = sub.add_parser("merge", help="merge dataset folders into one (more training images beside a held-out split)",
                       description=factory.merge.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    m.add_argument("out", type=Path, help="the merged dataset folder")
    m.add_argument("sources", type=Path, nargs="*", help="dataset folders whose splits are kept")
    m.add_argument("--train", type=Path, action="append", default=[], metavar="SRC",
                   help="a dataset folder whose images all go to the train split (repeatable)")
    v = sub.add_parser("preview", help="contact sheet of a dataset or capture folder")
    v.add_argument("folder", type=Path)
    v.add_argument("--out", type=Path, required=True)
    v.add_argument("--count", type=int, default=6)
    args = parser.parse_args(argv)

    def action() -> None:
        if args.command == "build" and args.recipe is not None:
            if args.garment is not None or args.motions is not None:
                raise ValueError("--recipe gives the garments and motions; leave out --garment and --motions")
            started = time.perf_counter()
            folders = build_recipe(args.recipe, args.out, args.shard, holdout=not args.train_only,
                                   backend=args.backend, address=args.address, num_cpus=args.num_cpus,
                                   shard_frames=args.shard_frames)
            print(f"recipe {args.recipe}: {len(folders)} dataset folders in {args.out} "
                  f"({time.perf_counter() - started:.0f} s); {args.out / 'recipe.json'} lists them")
        elif args.command == "build":
            if args.garment is None or args.motions is None:
                raise ValueError("give --garment and --motions, or --recipe")
            try:
                frame_list = tuple(int(f) for f in args.frame_list.split(",")) if args.frame_list else None
            except ValueError:
                raise ValueError(f"--frame-list: expected comma-separated frame numbers, got {args.frame_list!r}") \
                    from None
            if args.frames < 1 or args.frame_step < 1 or min(frame_list or [0]) < 0:
                raise ValueError("--frames and --frame-step must be >= 1 and --frame-list's frames >= 0")
            transition = int(round(SimulationConfig(args.garment, "").transition_seconds * 120))
            last = max(frame_list) if frame_list else transition + args.frames * args.frame_step
            _check_sizes(args, limits_from_args(args), last, ("--variations", args.variations))
            config = DatasetConfig(garment=args.garment, motions=tuple(m for m in args.motions.split(",") if m),
                                   body=args.body, betas=check_betas(args.betas, args.body, "--betas"),
                                   frames=args.frames, frame_step=args.frame_step,
                                   frame_list=frame_list, variations=args.variations, seed=args.seed,
                                   level_mm=args.level, motion_speed=args.speed, render=_render_settings(args),
                                   fov_deg=args.fov, fill=args.fill)
            started = time.perf_counter()
            reuse = dict(item.split("=", 1) for item in args.reuse_simulation if "=" in item)
            if len(reuse) != len(args.reuse_simulation):
                raise ValueError(f"--reuse-simulation takes MOTION=DIR, got {args.reuse_simulation}")
            manifest = factory.build.build(config, args.out, args.shard, simulations=reuse, backend=args.backend,
                                           address=args.address, num_cpus=args.num_cpus,
                                           shard_frames=args.shard_frames)
            entries = manifest.read_text().splitlines()
            timing = load_json(args.out / "timing.json")
            print(f"{len(entries)} images in {manifest} ({timing['images']} made now, {timing['retried']} failed "
                  f"task attempts retried, {time.perf_counter() - started:.0f} s); "
                  f"contact sheet {args.out / 'contact_sheet.png'}")
        elif args.command == "capture":
            if args.frames < 1 or (args.first_frame or 0) < 0:
                raise ValueError("--frames must be >= 1 and --first-frame >= 0")
            first = int(round(SimulationConfig(args.garment, "").transition_seconds * 120)) \
                if args.first_frame is None else args.first_frame
            _check_sizes(args, limits_from_args(args), first + args.frames, ("--cameras", args.cameras))
            folder = capture(args.garment, args.motion, args.out, frames=args.frames, first_frame=args.first_frame,
                             cameras=args.cameras, resolution=tuple(args.resolution),
                             render=_render_settings(args), body=args.body, radius=args.radius,
                             camera_height=args.height, seed=args.seed, simulation=args.reuse_simulation,
                             level_mm=args.level, motion_speed=args.speed,
                             betas=check_betas(args.betas, args.body, "--betas"))
            print(f"capture in {folder}: cameras.json, garment.npz, {args.cameras} camera folders; "
                  f"contact sheet {folder / 'contact_sheet.png'}")
        elif args.command == "merge":
            sources = [factory.merge.Source(f) for f in args.sources] + [factory.merge.Source(f, True) for f in args.train]
            manifest = factory.merge.merge(args.out, sources)
            print(f"{len(manifest.read_text().splitlines())} images in {manifest}")
        else:
            print(preview(args.folder, args.out, args.count))

    return run_cli(action, failures=(ValueError, RuntimeError))


if __name__ == "__main__":
    sys.exit(main())
