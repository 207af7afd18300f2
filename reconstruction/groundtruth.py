"""The ``--detections groundtruth`` mode: the factory's exact 2D observations in place of the networks.

A synthetic capture folder (`factory.dataset.capture`) holds, per camera and frame, the ground truth
of every marker in the image (``<camera>/f<frame:06d>_gt.npz``, an
`assets.pattern.observation.ImageGroundTruth`).  `GroundTruthCapture.detections` turns it into the
`networks.detections.Detections` the Detector would output: the visible crosspoints only, confidence
1, with optional Gaussian pixel noise, dropout and wrong marker IDs (the recognizer's mistakes),
seeded per (seed, camera, frame) so any view can be remade alone.  This measures triangulation and
post-processing on their own; everything made from these detections says so through
`GroundTruthConfig.source` (for example ``groundtruth(noise=0.3px, dropout=0.1, unit=crosspoint,
seed=0)``), which later stages write into their outputs (`CapturedPoints.source`).

The folder's ground-truth garment (``garment.npz``: sewn-mesh positions (T, V, 3) at ``level_mm``,
``faces``, ``frames``; ``template.npz``) is read too, for measuring: `GroundTruthCapture.crosspoints`
at crosspoints, `GroundTruthCapture.garment_positions` on any template level and `vertex_errors` of a
reconstructed sequence, vertex by vertex.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Sequence

import numpy as np

from assets.cameras import Camera, load_cameras
from assets.fileio import load_npz
from assets.garments.template import Template
from assets.pattern.observation import ImageGroundTruth
from assets.pattern.table import localization_rc
from assets.pattern.spec import PatternSpec
from networks.detections import Detections
from reconstruction.correspondence import CrosspointMap
from reconstruction.hierarchy import Hierarchy
from reconstruction.views import check_synchronised

_GT_FILE = re.compile(r"^f(\d+)_gt\.npz$")
DROPOUT_UNITS = ("crosspoint", "marker")


@dataclass(frozen=True)
class GroundTruthConfig:
    """How ground-truth observations are degraded.

    noise_px: standard deviation of the Gaussian noise added to each crosspoint's x and y, pixels.
    dropout: fraction of `unit`s removed at random ('crosspoint': each detected marker crosspoint
    independently; 'marker': whole markers).  id_error: fraction of the detected markers whose ID is
    replaced by one drawn from the garment's IDs (a recognizer's mistakes; the points stay).  seed:
    with the camera index and frame number, seeds the noise, dropout and ID errors of one view."""

    noise_px: float = 0.0
    dropout: float = 0.0
    unit: str = "crosspoint"
    seed: int = 0
    id_error: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.noise_px) and self.noise_px >= 0):
            raise ValueError(f"GroundTruthConfig.noise_px must be >= 0 pixels, got {self.noise_px}")
        if not 0 <= self.dropout < 1:
            raise ValueError(f"GroundTruthConfig.dropout must be a fraction in [0, 1), got {self.dropout}")
        if not 0 <= self.id_error < 1:
            raise ValueError(f"GroundTruthConfig.id_error must be a fraction in [0, 1), got {self.id_error}")
        if self.unit not in DROPOUT_UNITS:
            raise ValueError(f"GroundTruthConfig.unit must be one of {DROPOUT_UNITS}, got {self.unit!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"GroundTruthConfig.seed must be an integer >= 0, got {self.seed!r}")

    @property
    def source(self) -> str:
        """The name every output made from these detections carries."""
        ids = f", id_error={self.id_error:g}" if self.id_error > 0 else ""
        return (f"groundtruth(noise={self.noise_px:g}px, dropout={self.dropout:g}, unit={self.unit}{ids}, "
                f"seed={self.seed})")

    def rng(self, camera: int, frame: int) -> np.random.Generator:
        """The generator of one view (camera index, frame number)."""
        return np.random.default_rng([self.seed, camera, frame])


def ground_truth_detections(gt: ImageGroundTruth, config: GroundTruthConfig, rng: np.random.Generator,
                            garment_ids: np.ndarray | None = None) -> Detections:
    """One image's ground truth -> the `Detections` a perfect detector would give, degraded by
    `config` (noise, dropout, ID errors drawn from `garment_ids`) with `rng`.

    Markers keep their visible crosspoints (minus dropout); markers left with none are removed.
    points_px are the (noisy) localization crosspoints; `partial` marks markers whose five
    localization points are not all visible; confidence is 1."""
    if config.id_error > 0 and (garment_ids is None or len(garment_ids) < 2):
        raise ValueError("ground_truth_detections: id_error needs the garment's marker IDs (garment_ids)")
    m, k = gt.num_markers, gt.crosspoints_px.shape[1]
    visible = gt.crosspoint_visible.copy()
    keep_marker = np.ones(m, dtype=bool)
    if config.dropout > 0:
        if config.unit == "marker":
            keep_marker = rng.random(m) >= config.dropout
        else:
            visible &= rng.random((m, k, k)) >= config.dropout
    crosspoints = gt.crosspoints_px.astype(np.float64)
    if config.noise_px > 0:
        noise = rng.normal(0.0, config.noise_px, crosspoints.shape)
        crosspoints = np.where(gt.crosspoint_visible[..., None], crosspoints + noise, crosspoints)
    keep = keep_marker & visible.any(axis=(1, 2))
    rc = localization_rc(PatternSpec(crosspoints_per_side=k))
    crosspoints = crosspoints[keep].astype(np.float32)
    marker_id = gt.marker_id[keep].astype(np.int64)
    if config.id_error > 0:  # drawn last: the other degradations stay those of id_error 0
        wrong = rng.random(len(marker_id)) < config.id_error
        marker_id[wrong] = rng.choice(np.asarray(garment_ids, dtype=np.int64), int(wrong.sum()))
    return Detections(
        marker_id=marker_id,
        confidence=np.ones(int(keep.sum()), np.float32),
        points_px=crosspoints[:, rc[:, 0], rc[:, 1]],
        crosspoints_px=crosspoints,
        crosspoint_visible=visible[keep],
        partial=~gt.point_visible[keep].all(axis=1),
    )


class GroundTruthCapture:
    """A factory capture folder read for ground-truth detections and ground-truth garment points.

    cameras: from ``cameras.json``; frames: the frame numbers every camera has ground truth for."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        if not (self.folder / "cameras.json").is_file():
            raise ValueError(f"{self.folder}: not a capture folder (no cameras.json)")
        self.cameras: list[Camera] = load_cameras(self.folder / "cameras.json")
        found = {}
        for camera in self.cameras:
            folder = self.folder / camera.name
            if not folder.is_dir():
                raise ValueError(f"{folder}: missing the folder of camera {camera.name!r} named in cameras.json")
            found[camera.name] = [int(m.group(1)) for p in folder.iterdir() if (m := _GT_FILE.match(p.name))]
            if not found[camera.name]:
                raise ValueError(f"{folder}: no ground truth files (f<frame>_gt.npz)")
        self.frames: list[int] = check_synchronised(found)

    def ground_truth(self, frame: int, camera: int) -> ImageGroundTruth:
        """The saved ground truth of camera index `camera` at frame number `frame`."""
        path = self.folder / self.cameras[camera].name / f"f{frame:06d}_gt.npz"
        gt = ImageGroundTruth.load(path)
        if (gt.width, gt.height) != (self.cameras[camera].width, self.cameras[camera].height):
            raise ValueError(f"{path}: ground truth of a {gt.width} x {gt.height} image, camera "
                             f"{self.cameras[camera].name!r} has {self.cameras[camera].width} x "
                             f"{self.cameras[camera].height}")
        return gt

    def detections(self, frame: int, config: GroundTruthConfig = GroundTruthConfig()) -> list[Detections]:
        """Every camera's ground-truth detections at frame number `frame`, in camera order."""
        if frame not in self.frames:
            raise ValueError(f"{self.folder}: no ground truth for frame {frame} (frames: {self.frames})")
        ids = self.garment_ids if config.id_error > 0 else None
        return [ground_truth_detections(self.ground_truth(frame, c), config, config.rng(c, frame), ids)
                for c in range(len(self.cameras))]

    @cached_property
    def garment_ids(self) -> np.ndarray:
        """(M,) int64: the marker IDs printed on the garment (its template's panels)."""
        return np.concatenate([t.marker_ids for t in self.template.layout.tables()]).astype(np.int64)

    # ---- the ground-truth garment ----------------------------------------------------------------
    @cached_property
    def garment(self) -> dict[str, np.ndarray]:
        """``garment.npz``: positions (T, V, 3) sewn-mesh vertices (metres), faces (F, 3), frames (T,),
        level_mm ()."""
        path = self.folder / "garment.npz"
        data = load_npz(path, required=("positions", "faces", "frames", "level_mm"))
        positions = data["positions"]
        if positions.ndim != 3 or positions.shape[0] != len(data["frames"]) or positions.shape[2] != 3:
            raise ValueError(f"{path}: positions must be (T, V, 3) with T = len(frames) = {len(data['frames'])}, "
                             f"got {positions.shape}")
        return data

    @cached_property
    def template(self) -> Template:
        return Template.load(self.folder / "template.npz")

    @cached_property
    def crosspoint_map(self) -> CrosspointMap:
        """The crosspoints on the ground-truth garment's level."""
        return CrosspointMap.build(self.template, self.level_mm)

    def crosspoints(self, frame: int, key: np.ndarray) -> np.ndarray:
        """The ground-truth positions (N, 3) metres of crosspoints `key` (N, 2) at frame number `frame`
        (interpolated in the garment's sewn mesh; NaN off the fabric)."""
        return self.crosspoint_map.points(self.garment_positions([frame])[0], key)

    @property
    def level_mm(self) -> int:
        """The template level of the ground-truth garment (the simulation's)."""
        return int(self.garment["level_mm"])

    @cached_property
    def _hierarchy(self) -> Hierarchy:
        return Hierarchy(self.template, (self.level_mm,))

    def garment_positions(self, frames: Sequence[int], level_mm: int | None = None) -> np.ndarray:
        """The ground-truth garment (T, V, 3) metres at frame numbers `frames` (T,) on the sewn mesh of
        template level `level_mm` (default: its own, `level_mm`).  Another level is reached through the
        template's barycentric map between the levels in the sewing pattern (`Hierarchy.transfer`): a
        finer level's vertices lie on the ground-truth mesh, a coarser level's vertices are sampled
        from it."""
        known = self.garment["frames"].tolist()
        missing = [int(f) for f in frames if int(f) not in known]
        if missing:
            raise ValueError(f"{self.folder / 'garment.npz'}: no positions for frames {missing} (frames: {known})")
        positions = self.garment["positions"][[known.index(int(f)) for f in frames]].astype(np.float64)
        if level_mm is None or int(level_mm) == self.level_mm:
            return positions
        return self._hierarchy.transfer(positions, self.level_mm, int(level_mm))


def vertex_errors(capture: GroundTruthCapture, positions: np.ndarray, frames: Sequence[int],
                  level_mm: int) -> np.ndarray:
    """Per-vertex distance (T, V) metres of a reconstruction, positions (T, V, 3) on the sewn mesh of
    template level `level_mm` at capture frame numbers `frames` (T,), from the ground truth of
    `capture` on that level (`GroundTruthCapture.garment_positions`)."""
    truth = capture.garment_positions(frames, level_mm)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape != truth.shape:
        raise ValueError(f"vertex_errors: positions {positions.shape}, but the ground truth of {len(truth)} frames "
                         f"on the {level_mm} mm level of {capture.folder / 'template.npz'} is {truth.shape}: not a "
                         "reconstruction of this capture's garment at that level")
    return np.linalg.norm(positions - truth, axis=-1)

