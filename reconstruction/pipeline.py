"""The reconstruction pipeline: stages over one output folder, each resumable and rerunnable alone.

    detect       views (+ networks, or a factory capture's ground truth) -> detections/<camera>/f<frame>.npz
    triangulate  detections -> points/f<frame>.npz (`CapturedPoints`)
    refine       points -> refine/ (per-frame work, resumed) -> sequence.npz (`RefinedSequence`)
    export       sequence -> export/: npz, OBJ and PLY per frame, PC2, a review .blend
    evaluate     sequence + points against a factory capture's ground truth -> evaluation.json
                 (`reconstruction.evaluation`)

Layout of an output folder:
  run.json                      the settings every stage reads (template, level, where detections come
                                from); a rerun with other settings is refused, naming them
  detections/<camera>/f*.npz    `networks.Detections` per camera and frame (the cache: a rerun skips them)
  points/f*.npz                 `reconstruction.points.CapturedPoints` per frame
  points/triangulation.json     the `TriangulationConfig` they were made with (other settings: refused)
  refine/                       the post-processing's finished frames and its refine_run.json
                                (`reconstruction.refinement`)
  sequence.npz                  the complete, refined sequence
  export/                       `reconstruction.exports.export_sequence`'s files and the review .blend
                                (`write_review`: bpy, in a process of its own)
  evaluation.json               `evaluate`'s numbers

Every record of settings is `assets.fileio.record_stage`'s: a rerun with the same settings reuses what
is there, one with others is refused naming each differing setting (``name: old -> new``), so a
folder never mixes outputs made two ways.  A folder written by a version whose settings differ is
refused the same way: start a new one.

Detections come from the networks (`checkpoints`: localizer, recognizer, crosspoints) run on the views,
or, with ``detections="groundtruth"``, from a factory capture folder's ground truth with optional
noise and dropout (`reconstruction.groundtruth`): the source's name is in run.json, in every points
file and in the sequence.
"""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Sequence

from assets.cameras import MAX_IMAGE_PIXELS, Camera
from assets.fileio import check_json_object, load_json, record_stage, safe_name, save_json
from assets.garments import Template, load_template
from networks.config import (KEEP_OWN_CELLS, NEIGHBOUR_DEGREE, NEIGHBOUR_SIGMA_SIDES, SMOOTH_CROSSPOINTS_PX,
                             crop_px_problem, keep_own_problem, neighbour_fit_problem)
from reconstruction.evaluation import evaluate

log = logging.getLogger(__name__)

STAGES = ("detect", "triangulate", "refine", "export", "evaluate")
#: frames per second of a sequence whose capture does not say (the motion-capture rate of the reference)
DEFAULT_FPS = 120.0


@dataclass(frozen=True)
class RunSettings:
    """What a reconstruction folder was made with (``run.json``).

    template: a default garment name, a pattern JSON or a template .npz; level_mm: the template level
    the crosspoints are located on (triangulation); detections: "networks" or "groundtruth";
    noise_px, dropout, seed: the ground-truth mode's perturbation; checkpoints: the three networks'
    files (networks mode); initial_shape: a penetration-free garment shape npz the post-processing
    starts from (`reconstruction.refinement.load_initial_shape`; a factory capture's ``sim/dressed.npz``),
    or "" for the template's placement pose (a poor start: see `refine_sequence`); localizer_scale:
    networks mode, `networks.DetectorConfig.localizer_scale` (0.5 when the views' markers are 32 to
    64 px across; None, the default: chosen per view); grow_missing: networks mode,
    `networks.DetectorConfig.grow_missing` (the markers the localizer missed next to fully observed
    ones are added);
    smooth_crosspoints_px: networks mode, `networks.DetectorConfig.smooth_crosspoints_px` (None: off);
    keep_own_cells: networks mode, `networks.DetectorConfig.keep_own_cells` (None: a marker counted as
    cut takes all five points from its neighbours' estimate); neighbour_sigma_sides, neighbour_degree:
    networks mode, the same of `networks.DetectorConfig` (None and 0: one homography over the
    neighbourhood places grown and cut markers)."""

    template: str
    level_mm: int = 12
    detections: str = "networks"
    noise_px: float = 0.0
    dropout: float = 0.0
    seed: int = 0
    checkpoints: tuple[str, ...] = ()
    initial_shape: str = ""
    localizer_scale: float | None = None
    grow_missing: bool = True
    smooth_crosspoints_px: float | None = SMOOTH_CROSSPOINTS_PX
    keep_own_cells: float | None = KEEP_OWN_CELLS
    neighbour_sigma_sides: float | None = NEIGHBOUR_SIGMA_SIDES
    neighbour_degree: int = NEIGHBOUR_DEGREE

    def __post_init__(self) -> None:
        if self.detections not in ("networks", "groundtruth"):
            raise ValueError(f"detections must be 'networks' or 'groundtruth', got {self.detections!r}")
        if self.detections == "networks" and len(self.checkpoints) != 3:
            raise ValueError("the networks mode needs the three networks' checkpoints: localizer, recognizer, "
                             "crosspoints")
        if self.level_mm <= 0:
            raise ValueError(f"level_mm must be > 0, got {self.level_mm}")
        if self.localizer_scale is not None and not 0 < self.localizer_scale <= 4:
            raise ValueError(f"localizer_scale must be in (0, 4] or None (chosen per view), got {self.localizer_scale}")
        if self.initial_shape and not Path(self.initial_shape).is_file():
            raise ValueError(f"initial shape {self.initial_shape}: no such file")
        if problem := crop_px_problem("smooth_crosspoints_px", self.smooth_crosspoints_px):
            raise ValueError(problem)
        if problem := keep_own_problem(self.keep_own_cells):
            raise ValueError(problem)
        if problem := neighbour_fit_problem(self.neighbour_sigma_sides, self.neighbour_degree):
            raise ValueError(problem)

    @property
    def source(self) -> str:
        """The name every output carries of where its 2D observations came from."""
        if self.detections == "networks":
            return "detector(" + ", ".join(Path(c).name for c in self.checkpoints) + ")"
        return self.groundtruth_config().source

    def groundtruth_config(self):
        from reconstruction.groundtruth import GroundTruthConfig

        return GroundTruthConfig(noise_px=self.noise_px, dropout=self.dropout, seed=self.seed)


def start(out: str | Path, settings: RunSettings) -> Path:
    """Create (or reopen) the output folder with `settings` recorded in ``run.json``; a folder made
    with other settings is refused, naming them (its outputs would mix)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    record_stage(out / "run.json", asdict(settings))
    return out


def settings_of(out: str | Path) -> RunSettings:
    """The `RunSettings` recorded in `out`'s ``run.json``; a record that does not name exactly this
    version's settings is refused, naming the unknown and missing ones."""
    path = Path(out) / "run.json"
    if not path.is_file():
        raise ValueError(f"{out}: not a reconstruction folder (no run.json); run `detect` or `run` first")
    names = [f.name for f in fields(RunSettings)]
    data = check_json_object(load_json(path), names, str(path))
    if missing := [name for name in names if name not in data]:
        raise ValueError(f"{path}: missing setting(s) {', '.join(missing)}: a folder made by another version; "
                         "start a new one")
    try:
        return RunSettings(**{**data, "checkpoints": tuple(data["checkpoints"])})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _detection_path(out: Path, camera: Camera, frame: int) -> Path:
    return out / "detections" / safe_name(camera.name, f"camera {camera.name!r}") / f"f{frame:06d}.npz"


# ---- stages ------------------------------------------------------------------------------------

def run(out: str | Path, views: str | Path, settings: RunSettings, cameras: Sequence[Camera] | None = None,
        frames: Sequence[int] | None = None, device: str | None = None, triangulation=None, refinement=None,
        start_frame: int | None = None, texture: str | Path | None = None, fps: float = DEFAULT_FPS,
        evaluate_against: str | Path | None = None, progress: bool = True,
        max_image_pixels: int = MAX_IMAGE_PIXELS) -> dict | None:
    """Every stage into `out` (`start`, `detect`, `triangulate`, `refine`, `export`, and with
    `evaluate_against`, a factory capture folder, `evaluate`); returns the evaluation, or None.

    `device` is the detection's and the refinement's.  Each stage's arguments are its function's: triangulation is `triangulate`'s config (a
    `TriangulationConfig`), refinement `refine`'s (a `RefineConfig`); texture: default the views
    folder's ``texture.png`` when there is one (a factory capture's).  `evaluate_against` is checked
    before any stage runs."""
    if evaluate_against is not None:
        _check_factory_capture(evaluate_against)
    start(out, settings)
    detect(out, views, cameras, frames, device, progress, max_image_pixels=max_image_pixels)
    triangulate(out, config=triangulation, progress=progress)
    refine(out, config=refinement, start_frame=start_frame, progress=progress, device=device)
    if texture is None and (Path(views) / "texture.png").is_file():
        texture = Path(views) / "texture.png"
    export(out, texture=texture, fps=fps, progress=progress)
    return evaluate(out, evaluate_against) if evaluate_against is not None else None


def _check_factory_capture(folder: str | Path) -> None:
    """Refuse `folder` unless it is a factory capture (cameras, ground truth per camera, garment.npz)."""
    from reconstruction.groundtruth import GroundTruthCapture

    try:
        GroundTruthCapture(folder)
    except ValueError as exc:
        raise ValueError(f"evaluating needs a factory capture: {exc}") from exc
    if not (Path(folder) / "garment.npz").is_file():
        raise ValueError(f"evaluating needs a factory capture: {folder} has no garment.npz")


def detect(out: str | Path, views: str | Path, cameras: Sequence[Camera] | None = None,
           frames: Sequence[int] | None = None, device: str | None = None, progress: bool = True,
           max_image_pixels: int = MAX_IMAGE_PIXELS) -> list[int]:
    """Detections of every camera at every frame (or `frames`) into ``detections/``; returns the frames.

    views: one folder (or video) per camera (networks mode) or the factory capture folder
    (ground-truth mode); when `cameras` is None, the views folder's cameras.json is used (a factory
    capture's, in either mode), its cameras' images at most `max_image_pixels`."""
    out = Path(out)
    settings = settings_of(out)
    if settings.detections == "groundtruth":
        from reconstruction.groundtruth import GroundTruthCapture

        capture = GroundTruthCapture(views)
        cameras = list(cameras or capture.cameras)
        chosen = _frames(capture.frames, frames, views)
        config = settings.groundtruth_config()
        from tqdm import tqdm  # here, not at import: Blender's own Python may lack it
        for frame in tqdm(chosen, desc="detect (ground truth)", unit="frame", disable=not progress):
            if all(_detection_path(out, c, frame).exists() for c in cameras):
                continue
            for camera, found in zip(cameras, capture.detections(frame, config)):
                found.save(_detection_path(out, camera, frame))
    else:
        from reconstruction.views import Views

        if cameras is None and (Path(views) / "cameras.json").is_file():  # a folder laid out as a capture
            from reconstruction.cameras import read_cameras

            cameras = read_cameras(Path(views) / "cameras.json", max_image_pixels=max_image_pixels)
        if cameras is None:
            raise ValueError(f"the networks mode needs the cameras: give --cameras, or put cameras.json in {views}")
        cameras = list(cameras)
        chosen = _frames(Views.open(views, cameras).frames, frames, views)
        devices = [d.strip() for d in device.split(",")] if device else [None]
        todo = [f for f in chosen if not all(_detection_path(out, c, f).exists() for c in cameras)]
        if len(devices) == 1 or len(todo) < 2:
            _detect_networks(out, views, cameras, todo, devices[0], progress)
        else:
            _detect_on_devices(out, views, cameras, todo, devices, progress)
    save_json(out / "detections" / "cameras.json", {"cameras": [c.to_dict() for c in cameras]})
    return chosen


def _detect_networks(out: Path, views: str | Path, cameras: list[Camera], frames: Sequence[int], device: str | None,
                     progress: bool) -> None:
    """The networks mode's detections of `frames` on one device, each frame's files written when done."""
    from networks import Detector, DetectorConfig
    from reconstruction.views import Views

    if not frames:
        return
    settings = settings_of(out)
    opened = Views.open(views, cameras)
    # the garment's tables: its IDs only, and cut markers from their neighbours
    config = DetectorConfig(localizer_scale=settings.localizer_scale, grow_missing=settings.grow_missing,
                            smooth_crosspoints_px=settings.smooth_crosspoints_px, keep_own_cells=settings.keep_own_cells,
                            neighbour_sigma_sides=settings.neighbour_sigma_sides,
                            neighbour_degree=settings.neighbour_degree)
    detector = Detector.from_checkpoints(*settings.checkpoints, device=device,
                                         tables=load_template(settings.template).layout.tables(), config=config)
    from tqdm import tqdm
    for frame in tqdm(frames, desc=f"detect ({detector.device})", unit="frame", disable=not progress):
        for camera, found in zip(cameras, detector(opened.images(frame))):
            found.save(_detection_path(out, camera, frame))


def _detect_on_devices(out: Path, views: str | Path, cameras: list[Camera], frames: Sequence[int],
                       devices: Sequence[str], progress: bool) -> None:
    """`frames` sharded over `devices`, one spawned process each (frame i to device i mod n); the
    parent counts the frames whose files are all written.  A process that fails fails the call, naming
    its device; what the others wrote stays (a rerun detects only what is missing)."""
    import multiprocessing
    import time

    context = multiprocessing.get_context("spawn")  # CUDA cannot be used in a forked process
    workers = [context.Process(target=_detect_networks, args=(out, views, cameras, list(frames[i::len(devices)]),
                                                               name, False), name=f"detect {name}")
               for i, name in enumerate(devices)]
    for worker in workers:
        worker.start()
    try:
        from tqdm import tqdm
        with tqdm(total=len(frames), desc=f"detect ({len(devices)} devices)", unit="frame",
                  disable=not progress) as bar:
            while any(worker.is_alive() for worker in workers):
                time.sleep(0.5)
                bar.update(sum(all(_detection_path(out, c, f).exists() for c in cameras) for f in frames) - bar.n)
    finally:
        for worker in workers:
            worker.join()
    failed = [f"{name} (exit code {worker.exitcode})" for name, worker in zip(devices, workers) if worker.exitcode]
    if failed:
        raise RuntimeError(f"detection failed on {', '.join(failed)}; the frames of the others are kept")


def _frames(available: Sequence[int], wanted: Sequence[int] | None, where: str | Path) -> list[int]:
    if wanted is None:
        return list(available)
    missing = sorted(set(wanted) - set(available))
    if missing:
        raise ValueError(f"{where}: frames {missing} were asked for but are not there (it has {list(available)})")
    return sorted(set(wanted))


def detected_frames(out: Path, cameras: Sequence[Camera]) -> list[int]:
    """The frames every camera has detections for."""
    per_camera = [{int(p.stem[1:]) for p in (out / "detections" / c.name).glob("f*.npz") if p.stem[1:].isdigit()}
                  for c in cameras]
    return sorted(set.intersection(*per_camera)) if per_camera else []


def stage_cameras(out: Path) -> list[Camera]:
    """The cameras the detect stage used (``detections/cameras.json``)."""
    from assets.cameras import load_cameras

    path = out / "detections" / "cameras.json"
    if not path.is_file():
        raise ValueError(f"{out}: no detections yet (run the detect stage first)")
    return load_cameras(path, max_image_pixels=math.inf)  # written by the detect stage, which bounded them


def triangulate(out: str | Path, template: Template | None = None, config=None, progress: bool = True) -> list[Path]:
    """Captured points per detected frame into ``points/`` with `config` (a `TriangulationConfig`,
    default the default one) recorded in ``points/triangulation.json``; the frames already there are
    skipped.  A rerun with another config is refused, naming the differing settings (the points there
    are another run's, and the refine stage's record holds them): use another output folder with the
    same ``detections/`` and ``run.json``, or delete ``points/`` and what follows.  Points without a
    record (a folder of an older version) are all made again."""
    from networks.detections import Detections
    from reconstruction.correspondence import CrosspointMap
    from reconstruction.points import sequence_path
    from reconstruction.triangulation import TriangulationConfig, triangulate_frame

    out = Path(out)
    settings = settings_of(out)
    config = config or TriangulationConfig()
    cameras = stage_cameras(out)
    frames = detected_frames(out, cameras)
    if not frames:
        raise ValueError(f"{out / 'detections'}: no frame has detections from every camera")
    (out / "points").mkdir(exist_ok=True)
    reuse = record_stage(out / "points" / "triangulation.json", asdict(config))
    pending = [f for f in frames if not (reuse and sequence_path(out / "points", f).exists())]
    if pending:
        crosspoints = CrosspointMap.build(template or load_template(settings.template), settings.level_mm)
        from tqdm import tqdm
        for frame in tqdm(pending, desc="triangulate", unit="frame", disable=not progress):
            detections = [Detections.load(_detection_path(out, c, frame)) for c in cameras]
            points = triangulate_frame(crosspoints, cameras, detections, config, frame, settings.source)
            points.save(sequence_path(out / "points", frame))
    return [sequence_path(out / "points", f) for f in frames]


def refine(out: str | Path, template: Template | None = None, config=None, start_frame: int | None = None,
           progress: bool = True, frames: Sequence[int] | None = None, device: str | None = None) -> Path:
    """The complete, intersection-free sequence from the captured points: ``sequence.npz`` (of every
    triangulated frame, or of `frames` only: a window of the sequence).  device: where Newton's
    solves run (`refine_sequence`; None: the CPU; of a comma-separated list, the first)."""
    from reconstruction.points import load_sequence
    from reconstruction.refinement import RefineConfig, load_initial_shape, refine_sequence

    out = Path(out)
    settings = settings_of(out)
    captures = load_sequence(out / "points")
    if not captures:
        raise ValueError(f"{out / 'points'}: no captured points (run the triangulate stage first)")
    if frames is not None:
        wanted = set(_frames([p.frame for p in captures], frames, out / "points"))
        captures = [p for p in captures if p.frame in wanted]
    shape, shape_level = load_initial_shape(settings.initial_shape) if settings.initial_shape else (None, None)
    if shape is None:
        log.warning("%s: no initial shape in run.json; refine starts from the template's placement pose", out)
    sequence = refine_sequence(template or load_template(settings.template), captures, config or RefineConfig(),
                               start_frame=start_frame, progress=progress, out=out / "refine",
                               initial_shape=shape, initial_level_mm=shape_level,
                               device=device.split(",")[0].strip() if device else "cpu")
    sequence.save(out / "sequence.npz")
    return out / "sequence.npz"


def export(out: str | Path, template: Template | None = None, texture: str | Path | None = None,
           fps: float = DEFAULT_FPS, progress: bool = True) -> Path:
    """``export/`` from ``sequence.npz``: the sequence npz, OBJ (with the template's UVs and `texture`)
    and PLY per frame, a PC2 point cache and the review .blend with the cameras (`write_review`)."""
    from reconstruction.exports import export_sequence, from_refined
    from reconstruction.refinement import RefinedSequence

    out = Path(out)
    if not (out / "sequence.npz").is_file():
        raise ValueError(f"{out}: no sequence.npz (run the refine stage first)")
    stage_cameras(out)  # the detect stage's cameras are there and readable
    refined = RefinedSequence.load(out / "sequence.npz")
    sequence = from_refined(refined, template or load_template(settings_of(out).template), fps)
    cameras = out / "detections" / "cameras.json"
    export_sequence(out / "export", sequence, texture=texture, progress=progress,
                    review=lambda path: write_review(path, sequence, cameras, texture))
    return out / "export"


def write_review(path: str | Path, sequence, cameras: str | Path | None = None,
                 texture: str | Path | None = None) -> list[Path]:
    """The review .blend of `sequence` (a `reconstruction.exports.GarmentSequence`) at `path`, written by
    `reconstruction.review` in a process of its own (this interpreter, ``-m reconstruction.review``):
    bpy is loaded there, never here, and resets nothing a caller holds.  cameras: a cameras.json of
    the cameras to add; texture: the pattern PNG.  Returns the written paths (the .blend, and its
    ``.pc2`` mesh cache for a long sequence); RuntimeError with the review's own error when it fails
    (no bpy in this Python, for one)."""
    from reconstruction.exports import save_sequence_npz

    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".review.", dir=path.parent) as folder:
        save_sequence_npz(Path(folder) / "sequence.npz", sequence)
        command = [sys.executable, "-m", "reconstruction.review", str(Path(folder) / "sequence.npz"), str(path)]
        command += ["--cameras", str(Path(cameras).resolve())] if cameras is not None else []
        command += ["--texture", str(Path(texture).resolve())] if texture is not None else []
        root = str(Path(__file__).resolve().parents[1])  # the project, importable whatever the caller's folder
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (root, os.environ.get("PYTHONPATH"))))}
        done = subprocess.run(command, capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL)
    lines = done.stdout.strip().splitlines()
    if done.returncode or not lines:
        said = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"{path}: the review .blend was not written: {said}")
    return [Path(p) for p in json.loads(lines[-1])]


def sequence_of(out: str | Path, fps: float | None = None):
    """The `reconstruction.exports.GarmentSequence` of reconstruction folder `out`, to review: the export
    stage's ``export/sequence.npz`` when it is not older than the refined ``sequence.npz``, else the
    refined sequence with the UVs of the template named in ``run.json`` (`exports.from_refined`; a
    folder refined but not exported, or refined again since), at `fps` Hz (default `DEFAULT_FPS`).
    ValueError when the folder holds neither."""
    from reconstruction.exports import from_refined, load_sequence_npz
    from reconstruction.refinement import RefinedSequence

    out = Path(out)
    exported, refined = out / "export" / "sequence.npz", out / "sequence.npz"
    if exported.is_file() and (not refined.is_file() or exported.stat().st_mtime_ns >= refined.stat().st_mtime_ns):
        return load_sequence_npz(exported)
    if not refined.is_file():
        raise ValueError(f"{out}: no sequence.npz: run the reconstruction (its refine stage) first")
    return from_refined(RefinedSequence.load(refined), load_template(settings_of(out).template), fps or DEFAULT_FPS)
