"""Datasets: simulation -> Blender renders -> ground truth, sharded and resumable.

    python -m factory.dataset build --garment shirt --motions walk,run --frames 8 --variations 5 --out out/ds
    python -m factory.dataset build ... --shard 0/4          # a deterministic quarter of the images
    python -m factory.dataset capture --garment shirt --motion walk --frames 12 --cameras 8 --out out/cap
    python -m factory.dataset preview out/ds --out out/ds/contact_sheet.png

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
  scenes/<motion>.npz          the frames to render: garment and body vertices
  jobs/<motion>-<shard>.json   render jobs (`factory.render`)
  images/<name>.png            RGB; <name>_depth.exr (Z, float32), <name>_camera.json (K, R, t)
  gt/<name>.npz                ground truth of every marker (`assets.pattern.observation.ImageGroundTruth`)
  samples/<name>.npz           training arrays: the Marker Localizer's cell targets (`cells`), the
                               96 x 96 recognizer crops with their IDs, the 112 x 112 crosspoint crops
                               with the crosspoints' crop coordinates and visibility
  meta/<name>.json             one finished image (written last: an image is done when this exists)
  manifest.jsonl, splits.json  every finished image with its files, split, motion, frame, variation

Sharding and resume: the images are ordered by (motion, frame, variation) and `--shard i/n` takes
every n-th from the i-th; an image whose `meta/<name>.json` exists is not redone, so a killed run
resumes where it stopped, and several processes (or machines sharing the folder) can work on the
shards of one dataset at once.  Each shard rewrites `manifest.jsonl` from `meta/` when it finishes.
The work is tasks: one simulation per motion, then render + ground truth per `--shard-frames`
frames (a `Shard`, whose records in `meta/` are written together once all its files are there);
`--backend ray` runs them on a Ray cluster (`factory.raybackend`), the default in this process.

Capture (`capture`): a calibrated ring of cameras around the subject renders every frame of a
sequence: `cameras.json` (`assets.cameras`), images per camera (``cam00/f000012.png``...), ground
truth per image, and `garment.npz` (the ground-truth garment sequence: positions, faces, template):
the synthetic capture reconstruction is tested and measured on.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import importlib.util
import json
import logging
import os
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
from assets.fileio import load_json, load_npz, save_json, save_npz
from assets.garments import Template
from assets.pattern.observation import ImageGroundTruth, training_samples
from assets.garments.markers import MarkerSurface
from factory.groundtruth import image_ground_truth
from assets.garments.loading import load_template
from factory.dressing import DressingParams
from factory.simulate import SimulationConfig, simulate

log = logging.getLogger(__name__)

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


# ---- build -------------------------------------------------------------------------------------

def simulation_config(garment: str, motion: str, body: str = "default", frames: int = 1, seed: int = 0,
                      level_mm: int = DressingParams.level_mm, motion_speed: float = 1.0) -> SimulationConfig:
    """The simulation the factory makes of `motion` (`factory.simulate`'s defaults otherwise)."""
    return SimulationConfig(garment=garment, motion=motion, body=body, frames=frames, seed=seed,
                            motion_speed=motion_speed, dressing=replace(DressingParams(), level_mm=level_mm))


def reuse_simulation(source: str | Path, target: Path, config: SimulationConfig) -> None:
    """Copy a finished simulation folder (``sequence.npz``, ``dressed.npz``) to `target`, where
    `factory.simulate` takes it up (and continues it when it has fewer frames than needed).  A folder
    holding another simulation than `config`'s (which would silently be simulated again) is refused,
    naming the options that differ."""
    source = Path(source)
    if not (source / "sequence.npz").is_file():
        raise ValueError(f"{source}: no sequence.npz (not a finished simulation folder)")
    meta = json.loads(str(load_npz(source / "sequence.npz", only=("meta",))["meta"]))
    if meta.get("key") != config.key():
        differ = config.differences(meta.get("config", {})) or ["the simulator's version"]
        raise ValueError(f"{source / 'sequence.npz'}: another simulation than this one's (recorded there, not here: "
                         f"{'; '.join(differ)}); give the options it was made with (--garment, --motion, --body, "
                         "--seed, --level, --speed) or leave out --reuse-simulation")
    target.mkdir(parents=True, exist_ok=True)
    for name in ("sequence.npz", "dressed.npz"):
        if (source / name).is_file() and not (target / name).exists():
            shutil.copyfile(source / name, target / name)


def _simulation_of(config: DatasetConfig, motion: str, frames: int = 1) -> SimulationConfig:
    return simulation_config(config.garment, motion, config.body, frames, config.seed, config.level_mm,
                             config.motion_speed)


def _frames_of(config: DatasetConfig, transition_frames: int) -> list[int]:
    if config.frame_list:
        return sorted(set(int(f) for f in config.frame_list))
    return [transition_frames + k * config.frame_step for k in range(1, config.frames + 1)]


def _check_config(out: Path, config: DatasetConfig) -> None:
    path = out / "config.json"
    current = json.loads(json.dumps(asdict(config)))
    if path.exists():
        # a setting added since the folder was made has its default there
        defaults = json.loads(json.dumps(asdict(DatasetConfig(garment="", motions=()))))
        saved = {**defaults, **load_json(path)}
        if saved != current:
            raise ValueError(f"{path}: this folder holds a dataset built with other settings; use a new --out "
                             f"(differences: {sorted(k for k in current if saved.get(k) != current[k])})")
    else:
        save_json(path, current)


@dataclass(frozen=True)
class Shard:
    """One render + ground-truth task: the images of a few frames of one motion, rendered as
    ``jobs/<name>.json`` from ``scenes/<motion>.npz``.  `images` are render-job image specs
    (`factory.renderjob`); `splits` and `variations` run along them."""

    name: str
    motion: str
    level_mm: int
    images: tuple[dict, ...]
    splits: tuple[str, ...]
    variations: tuple[int, ...]


def prepare(config: DatasetConfig, out: Path, shard: tuple[int, int],
            simulations: dict[str, str | Path] | None = None) -> None:
    """Check the arguments and the folder's settings; take up reused simulations; write the template
    and its texture.  Everything the tasks read that is not per motion is on disk after this."""
    index, count = shard
    if not 0 <= index < count:
        raise ValueError(f"shard must be i/n with 0 <= i < n, got {index}/{count}")
    if config.variations < 1:
        raise ValueError(f"variations must be >= 1, got {config.variations}")
    out.mkdir(parents=True, exist_ok=True)
    _check_config(out, config)
    for motion, folder in (simulations or {}).items():
        reuse_simulation(folder, out / "sim" / motion, _simulation_of(config, motion))
    template = render_template(config.garment, config.render.texture_dpi, out)
    if not (out / "template.npz").exists():
        template.save(out / "template.npz", levels=(config.level_mm,))


def dataset_frames(config: DatasetConfig) -> list[int]:
    """The simulation frames every motion of the dataset renders."""
    return _frames_of(config, int(round(SimulationConfig(config.garment, "").transition_seconds * 120)))


def simulate_motion(config: DatasetConfig, out: str | Path, motion: str, progress: bool = False) -> Path:
    """Simulate (or take up) `motion` far enough for the dataset's frames; the ``sequence.npz`` path."""
    return simulate(_simulation_of(config, motion, max(dataset_frames(config)) + 1), Path(out) / "sim" / motion,
                    progress)


def plan_shards(config: DatasetConfig, out: Path, sequences: dict[str, Path], shard: tuple[int, int] = (0, 1),
                shard_frames: int = 1) -> list[Shard]:
    """The fixed camera, the splits (``splits.json``) and the scenes (``scenes/<motion>.npz``) of the
    simulated motions; returns this `shard`'s unfinished images grouped `shard_frames` frames of one
    motion per `Shard`."""
    if shard_frames < 1:
        raise ValueError(f"shard_frames must be >= 1, got {shard_frames}")
    index, count = shard
    frames = dataset_frames(config)
    template = load_template(config.garment, config.render.texture_dpi)
    plans = [(motion, load_npz(sequences[motion], required=("positions", "faces", "body_poses", "body_trans",
                                                             "body_betas", "meta"))) for motion in config.motions]
    level_mm = int(json.loads(str(plans[0][1]["meta"])).get("level_mm", 12))
    if not np.array_equal(template.level(level_mm).sewn_faces, plans[0][1]["faces"]):
        raise ValueError(f"{out}: the simulated mesh does not match the template's {level_mm} mm level")

    # one fixed camera for the whole dataset, fitted to the largest garment
    radius = 0.0
    for _, sequence in plans:
        for f in frames:
            x = sequence["positions"][f]
            radius = max(radius, float(np.linalg.norm(x - 0.5 * (x.min(0) + x.max(0)), axis=1).max()))
    camera = fixed_camera(radius + config.max_shift, config.render, config.fov_deg, config.fill).to_dict()
    splits = split_of_frames([(motion, f) for motion in config.motions for f in frames], config.seed)
    save_json(out / "splits.json", {s: [f"{m}/{f}" for (m, f), name in splits.items() if name == s] for s in SPLITS})

    from factory.render import bundled_environments

    envs = environments(bundled_environments())
    body = load_body(config.body)
    names = [(motion, f, v) for motion in config.motions for f in frames for v in range(config.variations)]
    pending = [n for k, n in enumerate(names)
               if k % count == index and not (out / "meta" / f"{_name(*n)}.json").exists()]
    log.info("shard %d/%d: %d images to do", index, count, len(pending))
    shards = []
    for motion, sequence in plans:
        mine = [n for n in pending if n[0] == motion]
        if not mine:
            continue
        scene = out / "scenes" / f"{motion}.npz"
        if not scene.exists():
            body_vertices = body.pose(sequence["body_poses"][frames], sequence["body_trans"][frames],
                                      sequence["body_betas"]).vertices
            write_scene(scene, sequence["positions"][frames], sequence["faces"], corner_uv(template, level_mm),
                        np.asarray(frames), body_vertices, body.faces)
        groups: dict[int, list[tuple[str, int, int]]] = {}
        for n in mine:
            groups.setdefault(frames.index(n[1]) // shard_frames, []).append(n)
        for chunk, group in groups.items():
            images = []
            for m, f, v in group:
                x = sequence["positions"][f]
                choice = variation(config, m, f, v, 0.5 * (x.min(0) + x.max(0)), envs)
                images.append({"name": _name(m, f, v), "frame": int(f), "camera": camera, **choice})
            shards.append(Shard(name=f"{motion}-{index}of{count}-{chunk:04d}", motion=motion, level_mm=level_mm, images=tuple(images),
                                splits=tuple(splits[(m, f)] for m, f, _ in group),
                                variations=tuple(v for _, _, v in group)))
    return shards


@functools.lru_cache(maxsize=4)
def _marker_surface(garment: str, dpi: float, level_mm: int) -> MarkerSurface:
    # a few seconds to build; a worker process making many shards builds it once
    return MarkerSurface.build(load_template(garment, dpi), level_mm)


#: fault injection for the fault-tolerance tests: a file path; the first shard task that finds it
#: missing creates it and ends its process abruptly in mid-shard, as a killed worker would
CRASH_ONCE_ENV = "FACTORY_CRASH_ONCE"


def _crash_once() -> None:
    marker = os.environ.get(CRASH_ONCE_ENV)
    if not marker:
        return
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return
    os._exit(70)


def make_shard(config: DatasetConfig, out: str | Path, shard: Shard, progress: bool = False, threads: int = 0) -> dict:
    """Render (with `threads` render threads, 0 for every core) and annotate the shard's unfinished images.  Every file of an image is written
    atomically; the images' records (``meta/<name>.json``, what the manifest is made of) are written
    last, only once every file of every image of the shard is there, so an interrupted shard leaves
    no record and a repeated one rewrites the same bytes.  Returns the timing of the work done:
    images, setup_s, render_s, groundtruth_s."""
    out = Path(out)
    todo = [k for k, image in enumerate(shard.images) if not (out / "meta" / f"{image['name']}.json").exists()]
    timing = {"images": len(todo), "setup_s": 0.0, "render_s": 0.0, "groundtruth_s": 0.0}
    if not todo:
        return timing
    job = out / "jobs" / f"{shard.name}.json"
    save_json(job, _job(config.render, Path("..") / "scenes" / f"{shard.motion}.npz", Path("..") / "texture.png",
                        [shard.images[k] for k in todo]))
    report = run_render_job(job, out / "images", progress, threads)
    if report is not None:
        timing["setup_s"] = report.setup_seconds
        timing["render_s"] = report.seconds - report.setup_seconds
    started = time.perf_counter()
    surface = _marker_surface(config.garment, config.render.texture_dpi, shard.level_mm)
    scene = load_npz(out / "scenes" / f"{shard.motion}.npz", only=("garment_positions", "frames"))
    row = {int(f): k for k, f in enumerate(scene["frames"])}
    records = []
    for k in todo:
        entry = shard.images[k]
        name = entry["name"]
        camera = Camera.from_dict(entry["camera"])
        transform = np.asarray(entry["transform"])
        x = scene["garment_positions"][row[entry["frame"]]].astype(np.float64) @ transform[:3, :3].T + transform[:3, 3]
        gt, samples = ground_truth_for(surface, x, out / "images" / f"{name}.png",
                                       out / "images" / f"{name}_depth.exr", camera)
        gt.save(out / "gt" / f"{name}.npz")
        save_npz(out / "samples" / f"{name}.npz", samples)
        _crash_once()
        records.append({
            "name": name, "split": shard.splits[k], "motion": shard.motion, "frame": entry["frame"],
            "variation": shard.variations[k], "image": f"images/{name}.png", "depth": f"images/{name}_depth.exr",
            "camera": f"images/{name}_camera.json", "gt": f"gt/{name}.npz", "samples": f"samples/{name}.npz",
            "markers_visible": int((gt.status > 0).sum()), "markers_full": int((gt.status == 2).sum()),
            "environment": entry["environment"], "transform": entry["transform"], "seed": entry["seed"],
        })
    for record in records:
        save_json(out / "meta" / f"{record['name']}.json", record)
    timing["groundtruth_s"] = time.perf_counter() - started
    return timing


class BuildProgress:
    """One bar for a whole build: tasks (simulations, shards) done of those known, images per hour."""

    def __init__(self, enabled: bool):
        self.started = time.perf_counter()
        self.images = 0
        self.retried = 0
        self.bar = tqdm(total=0, desc="dataset", unit="task", disable=not enabled)

    def add(self, tasks: int) -> None:
        self.bar.total += tasks
        self.bar.refresh()

    def done(self, images: int = 0, retried: int = 0) -> None:
        self.images += images
        self.retried += retried
        hours = (time.perf_counter() - self.started) / 3600
        self.bar.set_postfix(images=self.images, per_hour=f"{self.images / max(hours, 1e-9):.0f}", refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


class LocalBackend:
    """Every task in this process, one after the other (`--shard i/n` spreads a build over processes)."""

    def __enter__(self) -> "LocalBackend":
        return self

    def __exit__(self, *exc) -> None:
        return None

    def simulate(self, config: DatasetConfig, out: Path, bar: BuildProgress) -> dict[str, Path]:
        sequences = {}
        for motion in config.motions:
            sequences[motion] = simulate_motion(config, out, motion)
            bar.done()
        return sequences

    def make_shards(self, config: DatasetConfig, out: Path, shards: list[Shard], bar: BuildProgress) -> list[dict]:
        timings = []
        for shard in shards:
            timings.append(make_shard(config, out, shard))
            bar.done(timings[-1]["images"])
        return timings


BACKENDS = ("local", "ray")


def build(config: DatasetConfig, out: str | Path, shard: tuple[int, int] = (0, 1), progress: bool = True,
          simulations: dict[str, str | Path] | None = None, backend: str = "local", address: str | None = None,
          num_cpus: int | None = None, shard_frames: int = 1) -> Path:
    """Build (or resume) shard `shard` = (i, n) of the dataset in `out`; returns the manifest path.
    `simulations`: motion -> a finished simulation folder to reuse.  `backend`: "local" (this
    process) or "ray" (`factory.raybackend`: tasks on the Ray cluster at `address`, or on a local Ray
    instance of `num_cpus` CPUs); both run the same tasks: one simulation per motion, then one
    render + ground-truth `Shard` per `shard_frames` frames.  ``timing.json`` gets the images made,
    the failed task attempts retried and the times (wall, scene set-up, render, ground truth).  Ends
    with ``contact_sheet.png`` of a few finished images with their ground truth."""
    out = Path(out)
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    prepare(config, out, shard, simulations)
    if backend == "ray":
        from factory.raybackend import RayBackend

        runner = RayBackend(address, num_cpus)
    else:
        runner = LocalBackend()
    bar = BuildProgress(progress)
    try:
        with runner:
            bar.add(len(config.motions))
            sequences = runner.simulate(config, out, bar)
            shards = plan_shards(config, out, sequences, shard, shard_frames)
            bar.add(len(shards))
            timings = runner.make_shards(config, out, shards, bar)
    finally:
        bar.close()
    timing = {key: sum(t[key] for t in timings) for key in ("images", "setup_s", "render_s", "groundtruth_s")}
    timing.update(retried=bar.retried, wall_s=time.perf_counter() - bar.started)
    save_json(out / "timing.json", timing)
    log.info("%d images made, %d failed task attempts retried, %.0f s", timing["images"], timing["retried"],
             timing["wall_s"])
    manifest = write_manifest(out)
    if manifest.read_text().strip():
        preview(out, out / "contact_sheet.png")
    return manifest


def _name(motion: str, frame: int, v: int) -> str:
    return f"{motion}_f{frame:06d}_v{v}"


def _job(settings: RenderSettings, scene: Path, texture: Path, images: list[dict], position: bool = False) -> dict:
    return {
        "version": 1, "scene": str(scene), "texture": str(texture), "resolution": list(settings.resolution),
        "engine": {"name": settings.engine, "samples": settings.samples, "denoise": settings.denoise,
                   "device": settings.device},
        "passes": {"depth": True, "position": position}, "images": images,
    }


def write_manifest(out: Path) -> Path:
    """`manifest.jsonl` from every finished image in `meta/`, sorted by name, atomically."""
    from assets.fileio import atomic_path

    lines = [json.dumps(load_json(p), sort_keys=True) for p in sorted((out / "meta").glob("*.json"))]
    path = out / "manifest.jsonl"
    with atomic_path(path) as tmp:
        tmp.write_text("".join(line + "\n" for line in lines))
    return path


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
            motion_speed: float = 1.0) -> Path:
    """Render `frames` consecutive simulation frames from a ring of `cameras` (each fitting the garment
    in its view), with ground truth and ``contact_sheet.png``; returns the folder.  The garment is
    simulated on template level `level_mm` with the motion at `motion_speed` (or taken from the
    finished simulation folder `simulation`, which must be that simulation)."""
    out = Path(out)
    transition = int(round(SimulationConfig(garment, motion).transition_seconds * 120))
    start = transition if first_frame is None else first_frame
    picked = list(range(start, start + frames))
    sim_config = simulation_config(garment, motion, body, picked[-1] + 1, seed, level_mm, motion_speed)
    if simulation is not None:
        reuse_simulation(simulation, out / "sim", sim_config)
    out.mkdir(parents=True, exist_ok=True)
    render = replace(render, resolution=tuple(resolution))
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
        save_json(job, _job(render, Path("..") / "scene.npz", Path("..") / "texture.png", images))
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


def _render_settings(args: argparse.Namespace) -> RenderSettings:
    return RenderSettings(resolution=tuple(args.resolution), engine=args.engine, samples=args.samples,
                          denoise=not args.no_denoise, device=args.device, texture_dpi=args.texture_dpi)


def main(argv: list[str] | None = None) -> int:
    from assets.cli import run_cli

    parser = argparse.ArgumentParser(prog="python -m factory.dataset", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="simulate, render and annotate a training dataset")
    b.add_argument("--garment", required=True)
    b.add_argument("--motions", required=True, help="comma-separated motion names or files")
    b.add_argument("--body", default="default")
    b.add_argument("--frames", type=int, default=DatasetConfig.frames, help="frames per motion")
    b.add_argument("--frame-step", type=int, default=DatasetConfig.frame_step, help="simulation frames between them")
    b.add_argument("--frame-list", help="explicit comma-separated simulation frames instead")
    b.add_argument("--variations", type=int, default=DatasetConfig.variations)
    b.add_argument("--seed", type=int, default=0)
    _add_simulation_args(b)
    b.add_argument("--shard", type=_shard, default=(0, 1), help="i/n: this process's share of the images")
    b.add_argument("--backend", choices=BACKENDS, default="local",
                   help="local: every task in this process; ray: Ray tasks (pip install '.[ray]')")
    b.add_argument("--address", help="ray: the cluster to join (e.g. HEAD_IP:6379 or auto); default: start a "
                   "local Ray instance")
    b.add_argument("--num-cpus", type=int, help="ray: CPUs of the local Ray instance (default: all)")
    b.add_argument("--shard-frames", type=int, default=1,
                   help="simulation frames (with their variations) per render + ground-truth task")
    b.add_argument("--reuse-simulation", action="append", default=[], metavar="MOTION=DIR",
                   help="a finished `factory.simulate` folder for a motion (repeatable), made with the same "
                   "--garment, --body, --seed, --level and --speed")
    b.add_argument("--out", type=Path, required=True)
    _add_render_args(b, "512")
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
    v = sub.add_parser("preview", help="contact sheet of a dataset or capture folder")
    v.add_argument("folder", type=Path)
    v.add_argument("--out", type=Path, required=True)
    v.add_argument("--count", type=int, default=6)
    args = parser.parse_args(argv)

    def action() -> None:
        if args.command == "build":
            frame_list = tuple(int(f) for f in args.frame_list.split(",")) if args.frame_list else None
            config = DatasetConfig(garment=args.garment, motions=tuple(m for m in args.motions.split(",") if m),
                                   body=args.body, frames=args.frames, frame_step=args.frame_step,
                                   frame_list=frame_list, variations=args.variations, seed=args.seed,
                                   level_mm=args.level, motion_speed=args.speed, render=_render_settings(args))
            started = time.perf_counter()
            reuse = dict(item.split("=", 1) for item in args.reuse_simulation if "=" in item)
            if len(reuse) != len(args.reuse_simulation):
                raise ValueError(f"--reuse-simulation takes MOTION=DIR, got {args.reuse_simulation}")
            manifest = build(config, args.out, args.shard, simulations=reuse, backend=args.backend,
                             address=args.address, num_cpus=args.num_cpus, shard_frames=args.shard_frames)
            entries = manifest.read_text().splitlines()
            timing = load_json(args.out / "timing.json")
            print(f"{len(entries)} images in {manifest} ({timing['images']} made now, {timing['retried']} failed "
                  f"task attempts retried, {time.perf_counter() - started:.0f} s); "
                  f"contact sheet {args.out / 'contact_sheet.png'}")
        elif args.command == "capture":
            folder = capture(args.garment, args.motion, args.out, frames=args.frames, first_frame=args.first_frame,
                             cameras=args.cameras, resolution=tuple(args.resolution),
                             render=_render_settings(args), body=args.body, radius=args.radius,
                             camera_height=args.height, seed=args.seed, simulation=args.reuse_simulation,
                             level_mm=args.level, motion_speed=args.speed)
            print(f"capture in {folder}: cameras.json, garment.npz, {args.cameras} camera folders; "
                  f"contact sheet {folder / 'contact_sheet.png'}")
        else:
            print(preview(args.folder, args.out, args.count))

    return run_cli(action, failures=(ValueError, RuntimeError))


if __name__ == "__main__":
    sys.exit(main())
