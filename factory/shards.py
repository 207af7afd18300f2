"""The dataset build's tasks (`factory.build` runs them, `factory.raybackend` as Ray tasks): one
simulation per motion (`simulate_motion`), the plan of the render + ground-truth tasks
(`plan_shards`), one such task per `Shard` (`make_shard`), the build's progress bar and its
manifest (`write_manifest`).

A motion goes by its label in every file and folder name: a built-in motion's name, a motion file's
stem (`assets.motion.sources.motion_label`).  The images are ordered by (motion, frame, variation);
shard i of n takes every n-th from the i-th, and those not done yet are grouped `shard_frames`
frames of one motion per `Shard`.  Every file of an image is written atomically and the images'
records (``meta/<name>.json``) last, together, once every file of the shard is there: an image is
done when its record exists, an interrupted or retried task leaves no partial record, and a repeated
one rewrites the same bytes.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from assets.body import load_body
from assets.cameras import Camera
from assets.fileio import atomic_path, load_json, load_npz, save_json, save_npz
from assets.garments.loading import load_template
from assets.garments.markers import MarkerSurface
from assets.motion.sources import motion_label
from factory.plan import (SPLITS, DatasetConfig, environments, fixed_camera, simulation_config, split_of_frames,
                          variation)
from factory.scenes import corner_uv, ground_truth_for, render_job_spec, run_render_job, write_scene
from factory.simulate import SimulationConfig, simulate

log = logging.getLogger(__name__)


def simulation_of(config: DatasetConfig, motion: str, frames: int = 1) -> SimulationConfig:
    """The simulation of `motion` that dataset `config` asks for, `frames` long (its key ignores length)."""
    return simulation_config(config.garment, motion, config.body, frames, config.seed, config.level_mm,
                             config.motion_speed, config.betas)


def _frames_of(config: DatasetConfig, transition_frames: int) -> list[int]:
    if config.frame_list:
        return sorted(set(int(f) for f in config.frame_list))
    return [transition_frames + k * config.frame_step for k in range(1, config.frames + 1)]


@dataclass(frozen=True)
class Shard:
    """One render + ground-truth task: the images of a few frames of one motion (its spec; files and
    folders use its `motion_label`), rendered as ``jobs/<name>.json`` from ``scenes/<label>.npz``.
    `images` are render-job image specs (`factory.renderjob`); `splits` and `variations` run along them."""

    name: str
    motion: str
    level_mm: int
    images: tuple[dict, ...]
    splits: tuple[str, ...]
    variations: tuple[int, ...]


def motion_labels(motions: tuple[str, ...]) -> dict[str, str]:
    """{motion: its label} (`motion_label`); a ValueError when two motions would share folders."""
    labels = {motion: motion_label(motion) for motion in motions}
    seen: dict[str, str] = {}
    for motion, label in labels.items():
        if seen.setdefault(label, motion) != motion:
            raise ValueError(f"--motions: {seen[label]!r} and {motion!r} would share the name {label!r} in "
                             "the dataset's folders; rename one of the files")
    return labels


def dataset_frames(config: DatasetConfig) -> list[int]:
    """The simulation frames every motion of the dataset renders."""
    return _frames_of(config, int(round(SimulationConfig(config.garment, "").transition_seconds * 120)))


def simulate_motion(config: DatasetConfig, out: str | Path, motion: str, progress: bool = False) -> Path:
    """Simulate (or take up) `motion` far enough for the dataset's frames; the ``sequence.npz`` path.
    The motions share one dressing (``sim/dressings``)."""
    return simulate(simulation_of(config, motion, max(dataset_frames(config)) + 1),
                    Path(out) / "sim" / motion_label(motion),
                    progress, dressings=Path(out) / "sim" / "dressings")


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
    labels = motion_labels(config.motions)
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
    splits = split_of_frames([(labels[motion], f) for motion in config.motions for f in frames], config.seed)
    save_json(out / "splits.json", {s: [f"{m}/{f}" for (m, f), name in splits.items() if name == s] for s in SPLITS})

    from factory.render import bundled_environments

    envs = environments(bundled_environments())
    body = load_body(config.body)
    names = [(labels[motion], f, v) for motion in config.motions for f in frames for v in range(config.variations)]
    pending = [n for k, n in enumerate(names)
               if k % count == index and not (out / "meta" / f"{_name(*n)}.json").exists()]
    log.info("shard %d/%d: %d images to do", index, count, len(pending))
    shards = []
    for motion, sequence in plans:
        label = labels[motion]
        mine = [n for n in pending if n[0] == label]
        if not mine:
            continue
        scene = out / "scenes" / f"{label}.npz"
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
            shards.append(Shard(name=f"{label}-{index}of{count}-{chunk:04d}", motion=motion, level_mm=level_mm,
                                images=tuple(images), splits=tuple(splits[(m, f)] for m, f, _ in group),
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
    """Render (with `threads` render threads, 0 for every core) and annotate the shard's unfinished
    images.  Every file of an image is written atomically; the images' records (``meta/<name>.json``,
    what the manifest is made of) are written last, only once every file of every image of the shard
    is there, so an interrupted shard leaves no record and a repeated one rewrites the same bytes.
    Returns the timing of the work done: images, setup_s, render_s, groundtruth_s."""
    out = Path(out)
    todo = [k for k, image in enumerate(shard.images) if not (out / "meta" / f"{image['name']}.json").exists()]
    timing = {"images": len(todo), "setup_s": 0.0, "render_s": 0.0, "groundtruth_s": 0.0}
    if not todo:
        return timing
    job = out / "jobs" / f"{shard.name}.json"
    label = motion_label(shard.motion)
    save_json(job, render_job_spec(config.render, Path("..") / "scenes" / f"{label}.npz",
                                   Path("..") / "texture.png", [shard.images[k] for k in todo]))
    report = run_render_job(job, out / "images", progress, threads)
    if report is not None:
        timing["setup_s"] = report.setup_seconds
        timing["render_s"] = report.seconds - report.setup_seconds
    started = time.perf_counter()
    surface = _marker_surface(config.garment, config.render.texture_dpi, shard.level_mm)
    scene = load_npz(out / "scenes" / f"{label}.npz", only=("garment_positions", "frames"))
    row = {int(f): k for k, f in enumerate(scene["frames"])}
    records, simulation = [], simulation_of(config, shard.motion).key()
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
            "name": name, "split": shard.splits[k], "motion": label, "frame": entry["frame"],
            "variation": shard.variations[k], "image": f"images/{name}.png", "depth": f"images/{name}_depth.exr",
            "camera": f"images/{name}_camera.json", "gt": f"gt/{name}.npz", "samples": f"samples/{name}.npz",
            "markers_visible": int((gt.status > 0).sum()), "markers_full": int((gt.status == 2).sum()),
            "environment": entry["environment"], "transform": entry["transform"], "seed": entry["seed"],
            "simulation": simulation,
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


def _name(motion: str, frame: int, v: int) -> str:
    return f"{motion}_f{frame:06d}_v{v}"


def write_manifest(out: Path) -> Path:
    """`manifest.jsonl` from every finished image in `meta/`, sorted by name, atomically."""
    lines = [json.dumps(load_json(p), sort_keys=True) for p in sorted((out / "meta").glob("*.json"))]
    path = out / "manifest.jsonl"
    with atomic_path(path) as tmp:
        tmp.write_text("".join(line + "\n" for line in lines))
    return path
