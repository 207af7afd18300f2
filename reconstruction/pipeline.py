"""The reconstruction pipeline: stages over one output folder, each resumable and rerunnable alone.

    detect       views (+ networks, or a factory capture's ground truth) -> detections/<camera>/f<frame>.npz
    triangulate  detections -> points/f<frame>.npz (`CapturedPoints`)
    refine       points -> refine/ (per-frame work, resumed) -> sequence.npz (`RefinedSequence`)
    export       sequence -> export/: npz, OBJ and PLY per frame, PC2, a review .blend
    evaluate     sequence + points against a factory capture's ground truth -> evaluation.json

Layout of an output folder:
  run.json                      the settings every stage reads (template, level, where detections come
                                from); a later stage or a rerun with other settings is refused
  detections/<camera>/f*.npz    `networks.Detections` per camera and frame (the cache: a rerun skips them)
  points/f*.npz                 `reconstruction.points.CapturedPoints` per frame
  refine/                       the post-processing's finished frames (`reconstruction.refine`)
  sequence.npz                  the complete, refined sequence
  export/                       `reconstruction.export.export_sequence`'s files
  evaluation.json               `evaluate`'s numbers

Detections come from the networks (`checkpoints`: localizer, recognizer, crosspoints) run on the views,
or, with ``detections="groundtruth"``, from a factory capture folder's ground truth with optional
noise and dropout (`reconstruction.groundtruth`): the source's name is in run.json, in every points
file and in the sequence.
"""

from __future__ import annotations

import logging
import math
from dataclasses import MISSING, asdict, dataclass, fields
from pathlib import Path
from typing import Sequence

import numpy as np

from assets.cameras import MAX_IMAGE_PIXELS, Camera
from assets.fileio import load_json, safe_name, save_json
from assets.garments import Template, load_template
from networks.config import (KEEP_OWN_CELLS, NEIGHBOUR_DEGREE, NEIGHBOUR_SIGMA_SIDES, SMOOTH_CROSSPOINTS_PX,
                             crop_px_problem, keep_own_problem, neighbour_fit_problem, without_removed)

log = logging.getLogger(__name__)

STAGES = ("detect", "triangulate", "refine", "export", "evaluate")
#: what `evaluate`'s fractions measure, written beside them in evaluation.json
DEFINITIONS = {
    "garment_coverage": "triangulated crosspoints / all crosspoints on the garment's fabric (the rest is "
                        "filled by the physics pass)",
    "captured_fraction": "triangulated crosspoints / crosspoints visible in at least two cameras' ground "
                         "truth (a detection measure, not coverage)",
}
#: frames per second of a sequence whose capture does not say (the motion-capture rate of the reference)
DEFAULT_FPS = 120.0


@dataclass(frozen=True)
class RunSettings:
    """What a reconstruction folder was made with (``run.json``).

    template: a default garment name, a pattern JSON or a template .npz; level_mm: the template level
    the crosspoints are located on (triangulation); detections: "networks" or "groundtruth";
    noise_px, dropout, seed: the ground-truth mode's perturbation; checkpoints: the three networks'
    files (networks mode); initial_shape: a penetration-free garment shape npz the post-processing
    starts from (`reconstruction.refine.load_initial_shape`; a factory capture's ``sim/dressed.npz``),
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
            raise ValueError("the networks mode needs three checkpoints: localizer, recognizer, crosspoints")
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


#: what a folder written before a setting existed was made with, where that is not the setting's
#: default (otherwise the default): detections before the Detector grew missed markers had none, and
#: before it smoothed crosspoints they were the network's raw outputs, before cut markers kept
#: their own points all five came from the neighbours' estimate, and before the neighbour placement
#: bent with the cloth it was one homography over the neighbourhood
BEFORE = {"grow_missing": False, "smooth_crosspoints_px": None, "keep_own_cells": None,
          "neighbour_sigma_sides": None, "neighbour_degree": 0}
#: settings that measurements removed, with the only value a run.json may still name (what the
#: product now does): one round of growth, one crosspoint pass (docs/journal/2026-11-28-crop-options-removed.md)
RUN_REMOVED_FIELDS: dict[str, object] = {"grow_rounds": 1, "crosspoint_shift_px": None}


def _recorded(path: Path) -> dict:
    """run.json at `path` without the removed settings; one naming another value is refused by name."""
    return without_removed(load_json(path), RUN_REMOVED_FIELDS, str(path))


def start(out: str | Path, settings: RunSettings) -> Path:
    """Create (or reopen) the output folder with `settings`; a folder made with other settings is refused
    (its outputs would mix)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    record = {**asdict(settings), "checkpoints": list(settings.checkpoints)}
    path = out / "run.json"
    if path.exists():
        # a folder written before a setting existed holds that setting's default
        recorded = _recorded(path)
        saved = {**{f.name: f.default for f in fields(RunSettings) if f.default is not MISSING}, **BEFORE,
                 **recorded, "checkpoints": list(recorded.get("checkpoints", ()))}
        if saved != record:
            differ = sorted(k for k in set(saved) | set(record) if saved.get(k) != record.get(k))
            raise ValueError(f"{path}: this folder was made with other settings ({', '.join(differ)}); "
                             "use another --out")
    else:
        save_json(path, record)
    return out


def settings_of(out: str | Path) -> RunSettings:
    path = Path(out) / "run.json"
    if not path.is_file():
        raise ValueError(f"{out}: not a reconstruction folder (no run.json); run `detect` or `run` first")
    data = {**BEFORE, **_recorded(path)}
    data["checkpoints"] = tuple(data.get("checkpoints", ()))
    try:
        return RunSettings(**data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _detection_path(out: Path, camera: Camera, frame: int) -> Path:
    return out / "detections" / safe_name(camera.name, f"camera {camera.name!r}") / f"f{frame:06d}.npz"


# ---- stages ------------------------------------------------------------------------------------

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
    """Captured points per detected frame into ``points/`` (frames already there are skipped)."""
    from networks.detections import Detections
    from reconstruction.correspondence import CrosspointMap
    from reconstruction.points import sequence_path
    from reconstruction.triangulate import TriangulationConfig, triangulate_frame

    out = Path(out)
    settings = settings_of(out)
    cameras = stage_cameras(out)
    frames = detected_frames(out, cameras)
    if not frames:
        raise ValueError(f"{out / 'detections'}: no frame has detections from every camera")
    pending = [f for f in frames if not sequence_path(out / "points", f).exists()]
    if pending:
        crosspoints = CrosspointMap.build(template or load_template(settings.template), settings.level_mm)
        from tqdm import tqdm
        for frame in tqdm(pending, desc="triangulate", unit="frame", disable=not progress):
            detections = [Detections.load(_detection_path(out, c, frame)) for c in cameras]
            points = triangulate_frame(crosspoints, cameras, detections, config or TriangulationConfig(), frame,
                                       settings.source)
            points.save(sequence_path(out / "points", frame))
    return [sequence_path(out / "points", f) for f in frames]


def refine(out: str | Path, template: Template | None = None, config=None, start_frame: int | None = None,
           progress: bool = True, frames: Sequence[int] | None = None) -> Path:
    """The complete, intersection-free sequence from the captured points: ``sequence.npz`` (of every
    triangulated frame, or of `frames` only: a window of the sequence)."""
    from reconstruction.points import load_sequence
    from reconstruction.refine import RefineConfig, load_initial_shape, refine_sequence

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
                               initial_shape=shape, initial_level_mm=shape_level)
    sequence.save(out / "sequence.npz")
    return out / "sequence.npz"


def export(out: str | Path, template: Template | None = None, texture: str | Path | None = None,
           fps: float = DEFAULT_FPS, progress: bool = True) -> Path:
    """``export/`` from ``sequence.npz``: the sequence npz, OBJ (with the template's UVs and `texture`)
    and PLY per frame, a PC2 point cache and the review .blend with the cameras."""
    from reconstruction.export import export_sequence, from_refined
    from reconstruction.refine import RefinedSequence

    out = Path(out)
    if not (out / "sequence.npz").is_file():
        raise ValueError(f"{out}: no sequence.npz (run the refine stage first)")
    refined = RefinedSequence.load(out / "sequence.npz")
    sequence = from_refined(refined, template or load_template(settings_of(out).template), fps)
    export_sequence(out / "export", sequence, texture=texture, cameras=stage_cameras(out), progress=progress)
    return out / "export"


def evaluate(out: str | Path, groundtruth: str | Path) -> dict:
    """Accuracy of the folder's points and sequence against a factory capture's ground truth, whichever
    mode made the detections (networks or ground truth).

    Per frame: the garment coverage (the crosspoints on the garment's fabric that were triangulated,
    over all of them: the share the cameras and the detections captured; physics filled the rest);
    the captured fraction (of the crosspoints seen by at least two cameras in the ground truth, the
    share that were triangulated: a detection measure, not coverage); the median and 95th-percentile
    3D error of the triangulated points (mm); the error of filled regions (the refined surface at the
    crosspoints that were not triangulated, mm); intersecting triangle pairs before and after
    post-processing (refine's diagnostics); and the temporal jitter (mean magnitude of the second
    difference over frames of the refined surface at every crosspoint, mm per frame^2) beside the
    ground truth's own.  Writes ``evaluation.json``: the
    summary (medians over frames), the `DEFINITIONS` of its fractions and the rows per frame."""
    from reconstruction.correspondence import CrosspointMap
    from reconstruction.groundtruth import GroundTruthCapture
    from reconstruction.points import load_sequence
    from reconstruction.refine import RefinedSequence

    out = Path(out)
    capture = GroundTruthCapture(groundtruth)
    captures = {p.frame: p for p in load_sequence(out / "points")}
    refined = RefinedSequence.load(out / "sequence.npz") if (out / "sequence.npz").exists() else None
    truth_map = capture.crosspoint_map
    every_key = truth_map.unflat(np.arange(truth_map.num_crosspoints))
    refined_map = CrosspointMap.build(capture.template, refined.level_mm) if refined is not None else None
    on_fabric = truth_map.face >= 0
    rows, surfaces, truths = [], [], []
    for frame in sorted(captures):
        points = captures[frame]
        seen = _seen_twice(capture, frame, truth_map)
        truth = capture.crosspoints(frame, points.key)
        error_mm = 1e3 * np.linalg.norm(points.xyz - truth, axis=1)
        flat = truth_map.flat(points.key)
        triangulated = np.isin(flat, seen)
        covered = np.zeros(truth_map.num_crosspoints, dtype=bool)
        covered[flat] = True
        row = {"frame": int(frame),
               "garment_coverage": float((covered & on_fabric).sum() / max(1, on_fabric.sum())),
               "captured_fraction": float(triangulated.sum() / max(1, len(seen))),
               "points": len(points), "error_mm_median": _q(error_mm, 50), "error_mm_p95": _q(error_mm, 95)}
        if refined is not None and frame in refined.frames.tolist():
            t = refined.frames.tolist().index(frame)
            surface = refined_map.points(refined.positions[t].astype(np.float64), every_key)
            exact = capture.crosspoints(frame, every_key)
            filled = ~np.isin(np.arange(truth_map.num_crosspoints), truth_map.flat(points.key))
            filled_mm = 1e3 * np.linalg.norm(surface - exact, axis=1)[filled]
            diagnostics = refined.diagnostics[t]
            row.update({"filled_error_mm_median": _q(filled_mm, 50), "filled_error_mm_p95": _q(filled_mm, 95),
                        "intersections_before": diagnostics.get("intersections_before"),
                        "intersections_after": diagnostics.get("intersections_after")})
            surfaces.append(surface)
            truths.append(exact)
        rows.append(row)
    summary = {"frames": len(rows), "source": next(iter(captures.values())).source if captures else None}
    for key in ("garment_coverage", "captured_fraction", "error_mm_median", "error_mm_p95", "filled_error_mm_median",
                "filled_error_mm_p95"):
        values = [r[key] for r in rows if r.get(key) is not None]
        summary[key] = float(np.median(values)) if values else None
    after = [r["intersections_after"] for r in rows if r.get("intersections_after") is not None]
    summary["intersections_after_max"] = max(after) if after else None
    if len(surfaces) >= 3:
        summary["jitter_mm"] = _jitter(np.stack(surfaces))
        summary["jitter_mm_groundtruth"] = _jitter(np.stack(truths))
    result = {"summary": summary, "definitions": DEFINITIONS, "frames": rows}
    save_json(out / "evaluation.json", result)
    return result


def _seen_twice(capture, frame: int, crosspoints) -> np.ndarray:
    """Flat indices of the crosspoints visible in at least two cameras' ground truth at `frame`."""
    counts = np.zeros(crosspoints.num_crosspoints, dtype=np.int64)
    k = None
    for c in range(len(capture.cameras)):
        gt = capture.ground_truth(frame, c)
        k = gt.crosspoints_px.shape[1]
        rows, cols = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        marker = np.repeat(gt.marker_id, k * k)
        key, known = crosspoints.lookup(marker, np.tile(rows.ravel(), len(gt.marker_id)),
                                        np.tile(cols.ravel(), len(gt.marker_id)))
        visible = gt.crosspoint_visible.reshape(-1) & known
        flat = np.unique(crosspoints.flat(key[visible]))
        counts[flat] += 1
    return np.flatnonzero(counts >= 2)


def _q(values: np.ndarray, q: float) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.percentile(values, q)) if len(values) else None


def _jitter(surfaces: np.ndarray) -> float:
    """Mean |x[t+1] - 2 x[t] + x[t-1]| over frames and points, mm."""
    second = surfaces[2:] - 2 * surfaces[1:-1] + surfaces[:-2]
    return float(1e3 * np.nanmean(np.linalg.norm(second, axis=-1)))
