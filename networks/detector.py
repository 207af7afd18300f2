"""`Detector`: images -> markers (ID, five points, confidence) with their crosspoints in image pixels.

The three networks are chained through the pattern's one crop mapping (`assets.pattern.crop_homography`
/ `unwarp`, the same that made their training crops)::

    1. Marker Localizer on the whole image (resized by `localizer_scale`, or by a scale chosen per
       image from the markers that coarse passes find, padded to a multiple of 8) -> `decode_localizer`
       -> five points and a presence probability per marker.
    2. Each marker's recognizer crop (96 x 96, `RECOGNIZER_CROP`) -> Marker Recognizer -> softmax; the ID is the
       argmax (over the garment's IDs when `tables` are given) and
       ``confidence = presence probability x softmax probability of that ID``.  A module reader
       (`MarkerModuleReader`, trained with ``recognizer_classes="modules"``) gives code-module logits
       instead, decoded against the codebook's IDs (the garment's when `tables` are given) under all
       four rotations (`networks.codes.CodeDecoder`); the probability is the decoded ID's posterior.
    3. With the garment's `tables`, each ID is checked against the IDs its detected neighbours imply
       on the layout (`networks.neighbours.vote_ids`) and replaced where they agree on another;
       the confidence of a replaced ID uses the recognizer's probability of that ID.
    4. Markers whose five points are not a homography of the canonical layout (residual above
       `max_layout_residual_cells`, a non-convex or mirrored quad) or leave the image are cut; with the
       garment's `tables`, their points are re-estimated from the fully visible neighbours on the
       pattern (`networks.neighbours.estimate_from_neighbours`, `partial=True`).  The ID comes from
       the raw points (the recognizer sees the visible part).
    5. Each marker's crosspoint crop (112 x 112, `CROSSPOINT_CROP`) and the
       reference texture of its ID -> Crosspoint Localizer; visible = sigmoid > `visibility_threshold`;
       the visible crosspoints near a cubic field fitted to them take its value
       (`smooth_crosspoints_px`); crop (x, y) mapped to image pixels through the inverse crop
       homography, and those outside the image hidden.

The crops are cut as each network's checkpoint says (`assets.pattern.CropGeometry`, carried by the
network as `crops`): the recognizer's `crops.recognizer`, the crosspoint network's `crops.crosspoints`.
All crops of one call go through the recognizer and crosspoint networks in batches of `batch_size`,
under `torch.inference_mode()`, on `device`: on the CPU OpenCV cuts them (`unwarp_markers`, exactly the
training crops); on a GPU each image is moved there once, the crops are cut there and the
crosspoints smoothed and mapped there (`networks.device_geometry`: the same homographies and fits).
Pixels are continuous image coordinates (x right, y down, pixel centres at integer + 0.5).

A `Detector` keeps nothing of a call: `Detector.detect` returns the detections with the localizer
scale of each image and the seconds of each stage (`DetectorResult`), so one Detector serves several
threads or calls at once (the cache of reference textures only grows, one texture per ID).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np
import torch
from torch import nn

from assets.pattern import (
    RECOGNIZER_CROP,
    CropSpec,
    MarkerTable,
    PatternSpec,
    crop_homography,
    generate_codebook,
    reference_textures,
    unwarp,
)
from assets.pattern.observation import is_convex_layout
from networks.checkpoint import check_pattern, checkpoint_spec, load_checkpoint
from networks.codes import CodeDecoder
from networks.config import (KEEP_OWN_CELLS, NEIGHBOUR_DEGREE, NEIGHBOUR_SIGMA_SIDES, SMOOTH_CROSSPOINTS_PX,
                             crop_px_problem, keep_own_problem, marker_px_problem, neighbour_fit_problem)
from networks.decode import decode_localizer
from networks.detections import Detections
from networks.device_geometry import (crop_to_image_on_device, images_on_device, smooth_crosspoints_on_device,
                                      unwarp_markers_on_device)
from networks.homography import (
    crop_to_image,
    inside_image,
    layout_residual,
    smooth_crosspoints,
)
from networks.localizer_scale import search_scales
from networks.neighbours import MarkerLayout, estimate_from_neighbours, predict_missing, vote_ids
from networks.models import CELL, normalize
from networks.tasks import reads_modules


@dataclass(frozen=True)
class DetectorConfig:
    """Post-processing numbers of the Detector (ours: the reference gives none for these).

    presence_threshold: a localizer cell is a marker centre where sigmoid(presence) exceeds it.
    nms_radius_px: markers whose centres are closer are merged (None: `decode_localizer`'s default), in
      the localizer's pixels (after `localizer_scale`).
    max_layout_residual_cells: five points further than this (in cells of the marker, 24 per side)
      from the best homography of the canonical layout mark the marker as cut.  Curved cloth bends
      even a fully visible marker off a homography: on the factory's rendered shirt (40 images, 3,682
      fully visible markers about 19 px across) the ground-truth points themselves exceed 1 cell for
      42% of them, 4 cells for 2.5%, while 73% of the partly visible markers exceed 4 cells.
    consistency_cells: a cut marker's own point joins its neighbours' homography fit when within
      this many cells of their prediction.
    keep_own_cells: a cut marker keeps each of its own points (in the image) within this many cells
      of its neighbours' estimate; only the points further off are replaced by the estimate (None:
      all five are).  On the 20 held-out renders the estimate of the markers marked cut is worse
      than the localizer's own points wherever the truth can be seen (centre median 2.5 px against
      0.8, 28% of centres moved more than 4 px), while 12 cells keeps 98% of centres within 4 px.
    neighbour_sigma_sides, neighbour_degree: how a marker is placed from its detected neighbours' points,
      in the completion of cut markers and the growth of missed ones
      (`networks.neighbours.place_from_neighbours`; `networks.config.NEIGHBOUR_SIGMA_SIDES` says why
      these defaults); None and 0 fit one homography to the whole neighbourhood.
    visibility_threshold: a crosspoint is visible where sigmoid(visibility) exceeds it.
    image_batch_size: images per localizer forward pass (padded to the largest of the batch).
    restrict_to_tables: with tables, the recognised ID is the most probable ID on the garment.
    vote_ids: with tables, correct IDs by their neighbours' votes (`networks.neighbours.vote_ids`,
      fully observed markers vote; `vote_min`, `vote_min_partial` and `vote_tolerance` are its
      min_votes, min_votes_partial and tolerance).
    localizer_scale: the localizer sees the image resized by this factor (area resampling), so that
      markers fall in the size range it was trained on (the synthesizer's `marker_px`, 16 to 32 px
      by default): 0.5 for a camera whose markers are 32 to 64 px across.  Its points are mapped back
      to full-resolution pixels; the recognizer and crosspoint crops are always cut from the full
      image, so only the localizer's input shrinks (and its cost, by the factor squared).  None (the
      default): chosen per image (`networks.localizer_scale.search_scales`): the localizer looks at
      the image at scales from 1/16 (cheap) to 1 until one finds markers with confidence; the
      median side of those markers gives the scale that makes it `localizer_marker_px`, where the
      image is localized again.  A `DetectorResult` gives the scale of each image.
    localizer_marker_px: the marker side (pixels, the square root of its area) that the automatic
      scale aims at: the best fixed scales measured were 0.4 on the 8-camera capture's 55 px markers
      (22 px), 0.75 on 1024 px renders' 32 px markers (24 px) and 1 on 512 px renders' 19.6 px ones.
    grow_missing: with tables, markers the localizer missed next to fully observed ones (a hidden
      centre, a fold, too oblique) are placed by at least `grow_min_neighbours` of them
      (`networks.neighbours.predict_missing`), get their layout ID and go through the crosspoint
      network; one is kept when at least `grow_min_visible` of its crosspoints (a share of K x K)
      are visible.  They are flagged `partial`, with `id_support` -1.
    smooth_crosspoints_px: each marker's visible crosspoints within this many crop pixels of a cubic
      field fitted to them (in its crop, `networks.homography.smooth_crosspoints`) take the field's
      value, averaging out the network's noise while folds keep theirs; None: off (the network's raw
      outputs, as the reference).  0.5 (the default) lowered the crop error on held-out renders 0.406
      -> 0.372 px (test split) and 0.525 -> 0.505 px (val), on exact synthesized crops 0.339 -> 0.300
      px, and the 8-camera capture's error median 0.180 -> 0.166 mm at the same coverage and p95.
    """

    presence_threshold: float = 0.5
    nms_radius_px: float | None = None
    max_layout_residual_cells: float = 4.0
    consistency_cells: float = 1.0
    keep_own_cells: float | None = KEEP_OWN_CELLS
    neighbour_sigma_sides: float | None = NEIGHBOUR_SIGMA_SIDES
    neighbour_degree: int = NEIGHBOUR_DEGREE
    visibility_threshold: float = 0.5
    image_batch_size: int = 4
    restrict_to_tables: bool = True
    vote_ids: bool = True
    vote_min: int = 2
    vote_min_partial: int = 4
    vote_tolerance: float = 0.3
    localizer_scale: float | None = None
    localizer_marker_px: float = 22.0
    grow_missing: bool = True
    grow_min_neighbours: int = 2
    grow_min_visible: float = 0.3
    smooth_crosspoints_px: float | None = SMOOTH_CROSSPOINTS_PX

    def __post_init__(self) -> None:
        problems = [problem] if (problem := crop_px_problem("smooth_crosspoints_px", self.smooth_crosspoints_px)) else []
        if not 1 <= self.grow_min_neighbours <= 8 or not 0 <= self.grow_min_visible <= 1:
            problems.append(f"grow_min_neighbours must be in 1..8 and grow_min_visible in [0, 1], got "
                            f"{self.grow_min_neighbours}, {self.grow_min_visible}")
        for name in ("presence_threshold", "visibility_threshold"):
            if not 0 < getattr(self, name) < 1:
                problems.append(f"{name} must be in (0, 1), got {getattr(self, name)}")
        for name in ("max_layout_residual_cells", "consistency_cells"):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)}")
        if problem := keep_own_problem(self.keep_own_cells):
            problems.append(problem)
        if problem := neighbour_fit_problem(self.neighbour_sigma_sides, self.neighbour_degree):
            problems.append(problem)
        if self.nms_radius_px is not None and not self.nms_radius_px > 0:
            problems.append(f"nms_radius_px must be > 0 or None, got {self.nms_radius_px}")
        if self.localizer_scale is not None and not 0 < self.localizer_scale <= 4:
            problems.append(f"localizer_scale must be in (0, 4] or None (chosen per image), got {self.localizer_scale}")
        if problem := marker_px_problem("localizer_marker_px", self.localizer_marker_px):
            problems.append(problem)
        if self.vote_min < 1 or self.vote_min_partial < 1 or not 0 < self.vote_tolerance < 0.5:
            problems.append(f"vote_min and vote_min_partial must be >= 1 and vote_tolerance in (0, 0.5), got "
                            f"{self.vote_min}, {self.vote_min_partial}, {self.vote_tolerance}")
        if self.image_batch_size < 1:
            problems.append(f"image_batch_size must be >= 1, got {self.image_batch_size}")
        if problems:
            raise ValueError("invalid DetectorConfig: " + "; ".join(problems))


# ---- geometric steps on plain arrays (called directly by the tests) ------------------------------

def check_images(images: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The images as a list of uint8 (H, W, 3) arrays; ValueError naming the first bad one."""
    if isinstance(images, np.ndarray):
        raise ValueError("Detector expects a list of (H, W, 3) uint8 images, got one array; wrap it in a list")
    out = []
    for i, image in enumerate(images):
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 1:
            raise ValueError(f"images[{i}]: expected uint8 RGB (H, W, 3), got {image.dtype} {image.shape}")
        out.append(image)
    return out


def pad_images(images: Sequence[np.ndarray], cell: int = CELL) -> np.ndarray:
    """Images (H_i, W_i, 3) uint8 -> one (B, H, W, 3) uint8 batch, zero-padded right and bottom to
    the largest height and width rounded up to a multiple of `cell` (pixel coordinates unchanged)."""
    height = -(-max(im.shape[0] for im in images) // cell) * cell
    width = -(-max(im.shape[1] for im in images) // cell) * cell
    batch = np.zeros((len(images), height, width, 3), dtype=np.uint8)
    for b, image in enumerate(images):
        batch[b, : image.shape[0], : image.shape[1]] = image
    return batch


def resize_for_localizer(image: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(the image resized by `scale` (area resampling when shrinking), (2,) the per-axis factor from
    its continuous pixels back to the image's: x_image = x_resized * factor)."""
    if scale == 1.0:
        return image, np.ones(2)
    height, width = image.shape[:2]
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    resized = cv2.resize(image, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    return resized, np.array([width / size[0], height / size[1]])


def unwarp_markers(images: Sequence[np.ndarray], image_index: np.ndarray, points_px: np.ndarray,
                   spec: PatternSpec, crop: CropSpec) -> np.ndarray:
    """Crops of markers from several images: image_index (N,) into `images`, points_px (N, 5, 2).
    Returns (N, S, S, 3) uint8, exactly `assets.pattern.unwarp` (as the training crops)."""
    out = np.zeros((len(image_index), crop.size_px, crop.size_px, 3), dtype=np.uint8)
    for i in np.unique(image_index):
        pick = np.flatnonzero(image_index == i)
        out[pick] = unwarp(images[i], spec, crop, np.asarray(points_px[pick], dtype=np.float64))
    return out


def usable_points(spec: PatternSpec, points_px: np.ndarray) -> np.ndarray:
    """(N,) bool: five points (N, 5, 2) that define a finite, invertible crop homography."""
    points_px = np.asarray(points_px, dtype=np.float64)
    ok = np.isfinite(points_px).all(axis=(1, 2))
    if ok.any():
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            h = crop_homography(spec, RECOGNIZER_CROP, points_px[ok])
            det = np.linalg.det(h)
        ok[ok] = np.isfinite(h).all(axis=(1, 2)) & np.isfinite(det) & (np.abs(det) > 1e-12)
    return ok


def _grown_markers(grown: tuple[np.ndarray, ...], support_dtype: np.dtype) -> tuple[np.ndarray, ...]:
    """`Detector.grow`'s (image_index, marker_id, points, confidence) as the detections' six arrays
    (image_index, marker_id, points, confidence, partial, id_support): partial, support -1."""
    count = len(grown[0])
    return (*grown, np.ones(count, bool), np.full(count, -1, support_dtype))


def _joined(first: tuple[np.ndarray, ...], second: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Two tuples of per-marker arrays, concatenated array by array."""
    return tuple(np.concatenate([a, b.astype(a.dtype, copy=False)]) for a, b in zip(first, second))


def fully_observed(spec: PatternSpec, points_px: np.ndarray, image_size: tuple[int, int],
                   max_residual_cells: float) -> np.ndarray:
    """(N,) bool: all five points are in the image (W, H) and consistent with a homography of the
    canonical layout (residual <= max_residual_cells, corners a convex, unmirrored quad)."""
    inside = inside_image(points_px, *image_size).all(axis=1)
    return inside & (layout_residual(spec, points_px) <= max_residual_cells) & is_convex_layout(points_px)


def vote_markers(layout: MarkerLayout, spec: PatternSpec, marker_id: np.ndarray, points_px: np.ndarray,
                 image_size: tuple[int, int], config: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """One image's markers (N,) with their five points (N, 5, 2) in an image of `image_size` (W, H):
    (IDs after the neighbours' votes, id_support (N,) int16), the fully observed markers voting
    (`networks.neighbours.vote_ids` with the config's vote settings)."""
    points_px = np.asarray(points_px, dtype=np.float64)
    full = fully_observed(spec, points_px, image_size, config.max_layout_residual_cells)
    ids, support = vote_ids(layout, spec, marker_id, points_px, full, config.vote_min, config.vote_min_partial,
                            config.vote_tolerance)
    return ids, support.astype(np.int16)


def _batches(count: int, size: int) -> Iterator[slice]:
    for start in range(0, count, size):
        yield slice(start, min(start + size, count))


#: the Detector's stages, in order (`DetectorResult.stage_seconds`)
STAGES = ("localize", "recognize", "vote", "complete", "crosspoints")


@dataclass(frozen=True)
class DetectorResult:
    """What one `Detector.detect` call found, per image of the call, and what it took.

    detections: one `Detections` per image.
    located: per image, the localizer's own output (`Detector.localize`): points_px (N, 5, 2)
      float32 and presence probability (N,) float32, before the partial markers' completion (what
      evaluation measures the cut test on).
    localizer_scales: per image, the scale the localizer saw it at (`DetectorConfig.localizer_scale`,
      or the one chosen for the image).
    stage_seconds: seconds spent in each of `STAGES` by the call, each stage ending with its results
      on the host.
    """

    detections: list[Detections]
    located: list[tuple[np.ndarray, np.ndarray]]
    localizer_scales: list[float]
    stage_seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))


# ---- the Detector -------------------------------------------------------------------------------

#: crops per recognizer/crosspoint forward pass by default: on a GPU one batch of 1,024 is 1.56x the
#: Detector's images/s of batches of 64 (an H200, ~170 markers an image: the networks are launch-bound
#: at 64); on the CPU larger batches gain nothing
GPU_CROP_BATCH, CPU_CROP_BATCH = 1024, 64


class Detector:
    """Marker Localizer + Marker Recognizer + Crosspoint Localizer, chained (module docstring).

    localizer, recognizer, crosspoints: the networks of `networks.models` (moved to `device`, put in
    eval mode).  spec: the pattern they were trained on; codebook (num_ids, n, n): its codebook
    (generated from `spec` when None).  tables: the garment's marker tables (one per panel) for
    partial markers and for restricting IDs to the garment; None to detect any ID.  batch_size: crops
    per forward pass (default `GPU_CROP_BATCH` on a GPU, `CPU_CROP_BATCH` on the CPU).
    """

    def __init__(self, localizer: nn.Module, recognizer: nn.Module, crosspoints: nn.Module, spec: PatternSpec,
                 device: str | torch.device = "cpu", batch_size: int | None = None,
                 tables: Sequence[MarkerTable] | None = None, config: DetectorConfig = DetectorConfig(),
                 codebook: np.ndarray | None = None) -> None:
        self.device = torch.device(device)
        if batch_size is None:
            batch_size = GPU_CROP_BATCH if self.device.type == "cuda" else CPU_CROP_BATCH
        if batch_size < 1:
            raise ValueError(f"Detector: batch_size must be >= 1, got {batch_size}")
        self.spec = spec
        self.config = config
        self.batch_size = batch_size
        self.codebook = generate_codebook(spec) if codebook is None else np.asarray(codebook)
        n = spec.modules_per_side
        if self.codebook.shape[1:] != (n, n):
            raise ValueError(f"Detector: codebook has shape {self.codebook.shape}, expected (num_ids, {n}, {n})")
        num_ids = getattr(recognizer, "num_ids", None)  # none for a module reader: it reads any ID
        if reads_modules(recognizer) and recognizer.modules_per_side != n:
            raise ValueError(f"Detector: the recognizer reads {recognizer.modules_per_side} x "
                             f"{recognizer.modules_per_side} code modules, the pattern has {n} x {n}")
        if num_ids is not None and num_ids > len(self.codebook):
            raise ValueError(f"Detector: the recognizer has {num_ids} IDs, the codebook only {len(self.codebook)}")
        k = getattr(crosspoints, "crosspoints_per_side", spec.crosspoints_per_side)
        if k != spec.crosspoints_per_side:
            raise ValueError(f"Detector: the crosspoint localizer has {k} crosspoints per side, the pattern "
                             f"{spec.crosspoints_per_side}")
        self.layout = None
        if tables:
            for t, table in enumerate(tables):
                if table.marker_ids.max() >= len(self.codebook) or not np.array_equal(
                        table.codes, self.codebook[table.marker_ids]):
                    raise ValueError(f"Detector: tables[{t}] (IDs {table.first_id}..{table.marker_ids.max()}) "
                                     "does not use this pattern's codebook")
                if num_ids is not None and table.marker_ids.max() >= num_ids:
                    raise ValueError(f"Detector: tables[{t}] uses IDs up to {table.marker_ids.max()}, the recognizer "
                                     f"knows {num_ids}; a module reader (the stored reader.pt, `python -m "
                                     "networks.weights fetch`) recognises any ID of the codebook")
            self.layout = MarkerLayout.from_tables(tables, len(self.codebook))
        #: a module reader's decoder: the garment's IDs with `restrict_to_tables`, else the whole codebook
        self.decoder = None
        if reads_modules(recognizer):
            candidates = np.flatnonzero(self.layout.table_of_id >= 0) \
                if self.layout is not None and config.restrict_to_tables else None
            self.decoder = CodeDecoder(self.codebook, candidates, self.device)
        # NHWC convolutions: faster on a GPU's tensor cores, and on the CPU too (10-21% less time per
        # network)
        self.localizer = localizer.to(self.device, memory_format=torch.channels_last).eval()
        self.recognizer = recognizer.to(self.device, memory_format=torch.channels_last).eval()
        self.crosspoints = crosspoints.to(self.device, memory_format=torch.channels_last).eval()
        self._references: dict[int, np.ndarray] = {}
        if self.layout is not None:  # the garment's IDs are all the crosspoint network will be shown
            self.references(np.flatnonzero(self.layout.table_of_id >= 0))

    @classmethod
    def from_checkpoints(cls, localizer_path: str | Path, recognizer_path: str | Path, crosspoints_path: str | Path,
                         device: str | torch.device | None = None, **kwargs: object) -> "Detector":
        """The Detector of three checkpoints (`networks.checkpoint`), which must share one pattern.

        device: None picks "cuda" when available, else "cpu".  kwargs go to `Detector` (batch_size,
        tables, config)."""
        if device is None:
            device = "cuda" if torch.cuda.is_available() else "cpu"
        recognizer, _, record = load_checkpoint(recognizer_path, expected_task="recognizer", device=device)
        spec = checkpoint_spec(record)
        models = {}
        for task, path in (("localizer", localizer_path), ("crosspoints", crosspoints_path)):
            models[task], _, record = load_checkpoint(path, expected_task=task, device=device)
            try:
                check_pattern(record, spec, source=str(path))
            except ValueError as exc:
                raise ValueError(f"the {task} checkpoint and the recognizer checkpoint {recognizer_path} do not "
                                 f"share one pattern: {exc}") from exc
        return cls(models["localizer"], recognizer, models["crosspoints"], spec, device=device, **kwargs)

    # ---- the stages -----------------------------------------------------------------------------
    def _to_device(self, images: np.ndarray) -> torch.Tensor:
        """uint8 (B, H, W, 3) numpy -> normalised float (B, 3, H, W) on the device."""
        return normalize(torch.from_numpy(np.ascontiguousarray(images)).to(self.device).permute(0, 3, 1, 2))

    def _crops(self, images: Sequence[np.ndarray], on_device: Sequence[torch.Tensor] | None, image_index: np.ndarray,
               points_px: np.ndarray, crop: CropSpec) -> torch.Tensor:
        """Normalised (N, 3, S, S) crops on the device: cut there from `on_device` (the images already on
        a GPU, `images_on_device`), else cut by OpenCV on the host and moved."""
        if on_device is not None:
            return normalize(unwarp_markers_on_device(on_device, image_index, points_px, self.spec, crop))
        return self._to_device(unwarp_markers(images, image_index, points_px, self.spec, crop))

    def localize(self, images: Sequence[np.ndarray], scales: Sequence[float] | None = None
                 ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[float]]:
        """Stage 1: (per image, (points_px (N, 5, 2) float32, presence probability (N,) float32) of the
        markers whose centre lies in the image; per image, the localizer scale it was seen at): at
        `scales` (one per image) when given, else at `config.localizer_scale`, else at a scale chosen
        per image (`DetectorConfig.localizer_scale`, `localize_auto`)."""
        if scales is None and self.config.localizer_scale is None:
            return self.localize_auto(images)
        if scales is None:
            scales = [self.config.localizer_scale] * len(images)
        if len(scales) != len(images):
            raise ValueError(f"localize: {len(scales)} scales for {len(images)} images")
        return self._localize(images, scales), [float(scale) for scale in scales]

    def localize_auto(self, images: Sequence[np.ndarray]) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[float]]:
        """`localize` at a scale chosen per image (`networks.localizer_scale.search_scales`)."""
        return search_scales(list(images), self._localize, self.config.localizer_marker_px)

    def _localize(self, images: Sequence[np.ndarray], scales: Sequence[float]) -> list[tuple[np.ndarray, np.ndarray]]:
        """`localize` with the localizer scale of each image given."""
        kwargs = {} if self.config.nms_radius_px is None else {"nms_radius_px": self.config.nms_radius_px}
        out = []
        with torch.inference_mode():
            for chunk in _batches(len(images), self.config.image_batch_size):
                resized = [resize_for_localizer(image, scale) for image, scale in zip(images[chunk], scales[chunk])]
                batch = self._to_device(pad_images([r for r, _ in resized]))
                decoded = decode_localizer(self.localizer(batch), threshold=self.config.presence_threshold,
                                           cell=CELL, **kwargs)
                for image, (_, factor), (points, score) in zip(images[chunk], resized, decoded):
                    points = (np.asarray(points, dtype=np.float64).reshape(-1, 5, 2) * factor).astype(np.float32)
                    score = np.asarray(score, dtype=np.float32).reshape(-1)
                    keep = inside_image(points[:, 0], image.shape[1], image.shape[0])
                    out.append((points[keep], score[keep]))
        return out

    def recognize(self, images: Sequence[np.ndarray], image_index: np.ndarray, points_px: np.ndarray,
                  marker_id: np.ndarray | None = None, on_device: Sequence[torch.Tensor] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Stage 2: (marker_id (N,) int64, softmax probability of that ID (N,) float32): the most
        probable ID, or the given `marker_id` (N,) with the probability the recognizer gives it (a
        module reader's: the decoded posterior among `self.decoder`'s candidates).  `on_device`: the
        images already on the GPU (`images_on_device`), where the crops are then cut."""
        ids = np.zeros(len(image_index), dtype=np.int64) if marker_id is None else np.asarray(marker_id, np.int64)
        probability = np.zeros(len(image_index), dtype=np.float32)
        allowed = None
        if self.layout is not None and self.config.restrict_to_tables:
            allowed = torch.as_tensor(self.layout.table_of_id >= 0, device=self.device)
        with torch.inference_mode():
            for part in _batches(len(image_index), self.batch_size):
                crops = self._crops(images, on_device, image_index[part], points_px[part],
                                    self.recognizer.crops.recognizer)
                output = self.recognizer(crops).float()
                if self.decoder is not None:
                    if marker_id is not None:
                        probability[part] = self.decoder.probability_of(output, ids[part]).cpu().numpy()
                    else:
                        reading = self.decoder.decode(output)
                        ids[part] = reading.marker_id.cpu().numpy()
                        probability[part] = reading.probability.cpu().numpy()
                    continue
                prob = torch.softmax(output, dim=1)
                if marker_id is not None:
                    given = torch.as_tensor(ids[part], device=self.device)
                    probability[part] = prob.gather(1, given[:, None])[:, 0].cpu().numpy()
                    continue
                if allowed is not None:
                    best, index = torch.where(allowed[: prob.shape[1]], prob, -1.0).max(dim=1)
                else:
                    best, index = prob.max(dim=1)
                ids[part] = index.cpu().numpy()
                probability[part] = best.cpu().numpy()
        return ids, probability

    def references(self, marker_id: np.ndarray) -> np.ndarray:
        """(N, S, S, 3) uint8 reference textures of the IDs in the crosspoint network's crop
        (its `crop`, the reference's S = 112), cached per ID."""
        marker_id = np.asarray(marker_id, dtype=np.int64)
        missing = np.array(sorted(set(marker_id.tolist()) - set(self._references)), dtype=np.int64)
        if len(missing):
            textures = reference_textures(self.spec, self.codebook[missing], self.crosspoints.crop)
            self._references.update(zip(missing.tolist(), textures))
        size = self.crosspoints.crop.size_px
        if len(marker_id) == 0:
            return np.zeros((0, size, size, 3), dtype=np.uint8)
        return np.stack([self._references[i] for i in marker_id.tolist()])

    def locate_crosspoints(self, images: Sequence[np.ndarray], image_index: np.ndarray, points_px: np.ndarray,
                           marker_id: np.ndarray, on_device: Sequence[torch.Tensor] | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
        """Stage 5: (crosspoints_px (N, K, K, 2) float32 image pixels, visible (N, K, K) bool);
        `on_device` as `recognize`'s."""
        k = self.spec.crosspoints_per_side
        xy = np.zeros((len(image_index), k, k, 2), dtype=np.float32)
        visible = np.zeros((len(image_index), k, k), dtype=bool)
        crop = self.crosspoints.crop
        with torch.inference_mode():
            for part in _batches(len(image_index), self.batch_size):
                references = self._to_device(self.references(marker_id[part]))
                crops = self._crops(images, on_device, image_index[part], points_px[part], crop)
                output = self.crosspoints(crops, references).float()
                if on_device is not None:  # the per-marker geometry where the output is, one copy back
                    shown = torch.sigmoid(output[:, 0]) > self.config.visibility_threshold
                    crop_xy = output[:, 1:].permute(0, 2, 3, 1)
                    if self.config.smooth_crosspoints_px is not None:
                        crop_xy = smooth_crosspoints_on_device(crop_xy, shown, self.config.smooth_crosspoints_px)
                    xy[part] = crop_to_image_on_device(self.spec, crop, points_px[part], crop_xy).cpu().numpy()
                    visible[part] = shown.cpu().numpy()
                    continue
                output = output.cpu().numpy()
                crop_xy = output[:, 1:].transpose(0, 2, 3, 1)
                with np.errstate(over="ignore"):
                    visible[part] = 1.0 / (1.0 + np.exp(-output[:, 0])) > self.config.visibility_threshold
                if self.config.smooth_crosspoints_px is not None:
                    crop_xy = smooth_crosspoints(crop_xy, visible[part], self.config.smooth_crosspoints_px)
                xy[part] = crop_to_image(self.spec, crop, points_px[part], crop_xy)
        for i in np.unique(image_index):
            pick = image_index == i
            height, width = images[i].shape[:2]
            visible[pick] &= inside_image(xy[pick], width, height)
        return xy, visible

    def vote(self, images: Sequence[np.ndarray], image_index: np.ndarray, points_px: np.ndarray,
             marker_id: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stage 3: (marker_id (N,) int64 corrected by the neighbours' votes, per image; id_support
        (N,) int16, the votes for that ID); unchanged IDs and support -1 without tables or with
        `config.vote_ids` off."""
        marker_id = np.asarray(marker_id, dtype=np.int64).copy()
        support = np.full(len(marker_id), -1, dtype=np.int16)
        if self.layout is None or not self.config.vote_ids:
            return marker_id, support
        for i in np.unique(image_index):
            pick = np.flatnonzero(image_index == i)
            size = (images[i].shape[1], images[i].shape[0])
            marker_id[pick], support[pick] = vote_markers(self.layout, self.spec, marker_id[pick], points_px[pick],
                                                          size, self.config)
        return marker_id, support

    def complete_partial(self, images: Sequence[np.ndarray], image_index: np.ndarray, points_px: np.ndarray,
                         marker_id: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stage 4: (points (N, 5, 2) float64, partial (N,) bool): cut markers' points estimated from
        their neighbours (unchanged without tables or without a detected full neighbour)."""
        points = np.asarray(points_px, dtype=np.float64).copy()
        partial = np.zeros(len(image_index), dtype=bool)
        if self.layout is None:
            return points, partial
        for i in np.unique(image_index):
            pick = np.flatnonzero(image_index == i)
            size = (images[i].shape[1], images[i].shape[0])
            full = fully_observed(self.spec, points[pick], size, self.config.max_layout_residual_cells)
            points[pick], partial[pick] = estimate_from_neighbours(
                self.layout, self.spec, marker_id[pick], points[pick], full, confidence[pick], size,
                self.config.consistency_cells, self.config.keep_own_cells, self.config.neighbour_sigma_sides,
                self.config.neighbour_degree)
        return points, partial

    def grow(self, images: Sequence[np.ndarray], image_index: np.ndarray, points_px: np.ndarray,
             marker_id: np.ndarray, confidence: np.ndarray, partial: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Stage 4b: the markers the localizer missed next to fully observed ones (`config.grow_missing`;
        `networks.neighbours.predict_missing`): (image_index (A,), marker_id (A,), points (A, 5, 2),
        confidence (A,)); none without tables."""
        found = [(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 5, 2)), np.zeros(0, np.float32))]
        if self.layout is None or not self.config.grow_missing:
            return found[0]
        for i in np.unique(image_index):
            pick = np.flatnonzero(image_index == i)
            size = (images[i].shape[1], images[i].shape[0])
            full = fully_observed(self.spec, points_px[pick], size, self.config.max_layout_residual_cells) & ~partial[pick]
            ids, points, conf = predict_missing(self.layout, marker_id[pick], points_px[pick], full, confidence[pick],
                                                size, self.config.grow_min_neighbours, self.config.neighbour_sigma_sides,
                                                self.config.neighbour_degree)
            found.append((np.full(len(ids), i, np.int64), ids, points, conf))
        return tuple(np.concatenate(arrays) for arrays in zip(*found))

    def __call__(self, images: Sequence[np.ndarray]) -> list[Detections]:
        """Detect the markers of every image: images uint8 (H, W, 3) -> one `Detections` per image."""
        return self.detect(images).detections

    def detect(self, images: Sequence[np.ndarray]) -> DetectorResult:
        """The `Detections` of every image, as `__call__`, with the localizer's own output and scale per
        image and the seconds of each stage (`DetectorResult`)."""
        images = check_images(images)
        if not images:
            return DetectorResult([], [], [])
        seconds = dict.fromkeys(STAGES, 0.0)
        clock = time.perf_counter()

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            seconds[stage] += now - clock
            clock = now

        located, scales = self.localize(images)
        # on a GPU the crops are cut there, from images moved once, and the crosspoints' smoothing and
        # mapping run there (`networks.device_geometry`); on the CPU OpenCV cuts the crops, 5-7x faster
        # than grid_sample there
        on_device = images_on_device(images, self.device) if self.device.type == "cuda" else None
        lap("localize")
        image_index = np.concatenate([np.full(len(s), i, dtype=np.int64) for i, (_, s) in enumerate(located)])
        points = np.concatenate([p for p, _ in located]).astype(np.float64)
        presence = np.concatenate([s for _, s in located])
        keep = usable_points(self.spec, points)
        image_index, points, presence = image_index[keep], points[keep], presence[keep]

        marker_id, probability = self.recognize(images, image_index, points, on_device=on_device)
        lap("recognize")
        voted, support = self.vote(images, image_index, points, marker_id)
        changed = voted != marker_id
        if changed.any():
            marker_id = voted
            probability[changed] = self.recognize(images, image_index[changed], points[changed], voted[changed],
                                                  on_device)[1]
        lap("vote")
        confidence = (presence * probability).astype(np.float32)
        points, partial = self.complete_partial(images, image_index, points, marker_id, confidence)
        detected = len(image_index)
        # the grown markers go through the crosspoint network with the detections, in one pass
        grown = self.grow(images, image_index, points, marker_id, confidence, partial)
        image_index, marker_id, points, confidence, partial, support = _joined(
            (image_index, marker_id, points, confidence, partial, support), _grown_markers(grown, support.dtype))
        lap("complete")
        crosspoints_px, visible = self.locate_crosspoints(images, image_index, points, marker_id, on_device)
        keep = np.ones(len(image_index), bool)
        keep[detected:] = visible[detected:].mean(axis=(1, 2)) >= self.config.grow_min_visible
        image_index, marker_id, points, confidence, partial, support, crosspoints_px, visible = (
            a[keep] for a in (image_index, marker_id, points, confidence, partial, support, crosspoints_px, visible))
        lap("crosspoints")

        result = []
        for i in range(len(images)):
            pick = image_index == i
            result.append(Detections(
                marker_id=marker_id[pick], confidence=confidence[pick], points_px=points[pick].astype(np.float32),
                crosspoints_px=crosspoints_px[pick], crosspoint_visible=visible[pick], partial=partial[pick],
                id_support=support[pick]))
        return DetectorResult(result, located, scales, seconds)
