"""The dataset build (`python -m factory.dataset build`): simulation tasks, shards, atomic records,
backends, resume.

`build(config, out, shard=(i, n))` makes (or finishes) shard i of n of the dataset that a
`factory.dataset.DatasetConfig` describes, in the folder `out` (its layout: `factory.dataset`):

1. `prepare`: the folder's ``config.json`` (a rerun with other settings is refused), reused
   simulations taken up, the template and its texture.
2. One simulation task per motion (`simulate_motion`: `factory.simulate`, which takes up or continues
   what ``sim/<motion>/`` holds).  A motion goes by its label in every file and folder name: a
   built-in motion's name, a motion file's stem (`assets.motion.sources.motion_label`).
3. `plan_shards`: the fixed camera, ``splits.json`` and ``scenes/<motion>.npz``; the images are ordered by
   (motion, frame, variation), shard i of n takes every n-th from the i-th, and those not done yet are
   grouped `shard_frames` frames of one motion per `Shard`.
4. One render + ground-truth task per `Shard` (`make_shard`).  Every file of an image is written
   atomically and the images' records (``meta/<name>.json``) last, together, once every file of the
   shard is there: an image is done when its record exists, an interrupted or retried task leaves no
   partial record, and a repeated one rewrites the same bytes.
5. ``timing.json``, ``manifest.jsonl`` rewritten from ``meta/`` (`write_manifest`), ``contact_sheet.png``.

Resume: a rerun plans only the images without a record, so a killed build continues where it stopped,
and several processes (or machines sharing the folder) can work on the shards of one dataset at once;
each rewrites the manifest when it finishes.  A backend runs the tasks: `LocalBackend` one after the
other in this process, `factory.raybackend.RayBackend` as Ray tasks with retries (`--backend ray`).
"""

from __future__ import annotations

import functools
import json
import logging
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from assets.body import load_body
from assets.cameras import Camera
from assets.fileio import load_json, load_npz, save_json, save_npz
from assets.garments.loading import load_template
from assets.garments.markers import MarkerSurface
from assets.motion.sources import motion_label
from factory.dataset import (SPLITS, DatasetConfig, check_betas, corner_uv, environments, fixed_camera,
                             ground_truth_for, preview, render_job_spec, render_template, reuse_simulation,
                             run_render_job, simulation_config, split_of_frames, variation, write_scene)
from factory.simulate import SimulationConfig, input_digests, simulate

log = logging.getLogger(__name__)

def _simulation_of(config: DatasetConfig, motion: str, frames: int = 1) -> SimulationConfig:
    return simulation_config(config.garment, motion, config.body, frames, config.seed, config.level_mm,
                             config.motion_speed, config.betas)


def _frames_of(config: DatasetConfig, transition_frames: int) -> list[int]:
    if config.frame_list:
        return sorted(set(int(f) for f in config.frame_list))
    return [transition_frames + k * config.frame_step for k in range(1, config.frames + 1)]


def _input_files(config: DatasetConfig) -> dict[str, str]:
    """{what: SHA-256} of the dataset's inputs given as files ("garment", "body", "motion <spec>")."""
    return input_digests(garment=config.garment, body=config.body,
                         **{f"motion {motion}": motion for motion in config.motions})


def _check_config(out: Path, config: DatasetConfig) -> None:
    """Record the settings and the input files' digests in ``config.json``, or refuse a folder that
    holds a dataset of other settings or of input files changed since (its images would be stale)."""
    path = out / "config.json"
    inputs = _input_files(config)
    current = json.loads(json.dumps({**asdict(config), **({"inputs": inputs} if inputs else {})}))
    if path.exists():
        # a setting added since the folder was made has its default there; a folder made before the
        # inputs' digests were recorded is taken as made from the files as they are
        defaults = json.loads(json.dumps({**asdict(DatasetConfig(garment="", motions=())),
                                          **({"inputs": inputs} if inputs else {})}))
        saved = load_json(path)
        if not isinstance(saved, dict):
            raise ValueError(f"{path}: expected a JSON object of dataset settings, got {type(saved).__name__}")
        saved = {**defaults, **saved}
        changed = [what for what, digest in inputs.items() if saved.get("inputs", {}).get(what, digest) != digest]
        if changed:
            raise ValueError(f"{path}: this dataset was built from other contents of {', '.join(changed)}; its "
                             "images would not match them: use a new --out")
        if saved != current:
            raise ValueError(f"{path}: this folder holds a dataset built with other settings; use a new --out "
                             f"(differences: {sorted(k for k in current if saved.get(k) != current[k])})")
    else:
        save_json(path, current)


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


def prepare(config: DatasetConfig, out: Path, shard: tuple[int, int],
            simulations: dict[str, str | Path] | None = None) -> None:
    """Check the arguments and the folder's settings; take up reused simulations; write the template
    and its texture.  Everything the tasks read that is not per motion is on disk after this."""
    index, count = shard
    if not 0 <= index < count:
        raise ValueError(f"shard must be i/n with 0 <= i < n, got {index}/{count}")
    if config.variations < 1:
        raise ValueError(f"variations must be >= 1, got {config.variations}")
    if not 0 < config.fill <= 1 or not 5 <= config.fov_deg <= 120:
        raise ValueError(f"fill must be in (0, 1] and fov_deg in [5, 120], got {config.fill} and {config.fov_deg}")
    check_betas(config.betas, config.body)
    labels = motion_labels(config.motions)
    for motion in simulations or {}:
        if motion not in config.motions:
            raise ValueError(f"--reuse-simulation {motion!r}=DIR: {motion!r} is not one of --motions "
                             f"({', '.join(config.motions)})")
    out.mkdir(parents=True, exist_ok=True)
    _check_config(out, config)
    for motion, folder in (simulations or {}).items():
        reuse_simulation(folder, out / "sim" / labels[motion], _simulation_of(config, motion))
    template = render_template(config.garment, config.render.texture_dpi, out)
    if not (out / "template.npz").exists():
        template.save(out / "template.npz", levels=(config.level_mm,))


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
    return simulate(_simulation_of(config, motion, max(dataset_frames(config)) + 1),
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
    records, simulation = [], _simulation_of(config, shard.motion).key()
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


def write_manifest(out: Path) -> Path:
    """`manifest.jsonl` from every finished image in `meta/`, sorted by name, atomically."""
    from assets.fileio import atomic_path

    lines = [json.dumps(load_json(p), sort_keys=True) for p in sorted((out / "meta").glob("*.json"))]
    path = out / "manifest.jsonl"
    with atomic_path(path) as tmp:
        tmp.write_text("".join(line + "\n" for line in lines))
    return path
