"""What an image shows of the pattern: every marker's points in pixels and which are seen, and the
training targets of the three networks made from them.

The plain-data contract between the factory (which computes it from a rendered mesh), the networks
(which learn from it and synthesize it) and reconstruction (which can take it in place of detections).
`localizer_targets` (Marker Localizer cells), `recognizer_crops` (Marker Recognizer) and
`crosspoint_crops` (Crosspoint Localizer) turn an image and its ground truth into training samples.

Pixels are continuous image coordinates (x right, y down) with pixel centres at integer + 0.5; depth is
the camera-frame z in metres.  M markers, K = crosspoints_per_side (25), the five localization points in
the order `assets.pattern.LOCALIZATION_POINTS` (centre, TL, TR, BL, BR; each is also a crosspoint).

`ImageGroundTruth` arrays (one image of W x H pixels, M markers):
  marker_id          (M,) int32
  points_px          (M, 5, 2) float32   projected localization points, even where hidden; NaN off
                                         the fabric (meaningless where points_depth <= 0)
  points_depth       (M, 5) float32      their camera-frame depth, metres; NaN off the fabric
  point_visible      (M, 5) bool
  crosspoints_px     (M, K, K, 2) float32   projected crosspoints, as points_px
  crosspoint_visible (M, K, K) bool
  status             (M,) int8           2 fully visible (every on-fabric crosspoint and all five
                                         localization points visible), 1 partly (some crosspoint
                                         visible), 0 hidden
A point is visible when it is on the fabric, in front of the camera, inside the image, front-facing
(its face's outward normal points towards the camera centre) and not occluded: its depth is at most
the rendered depth of the pixel containing it (floor of its continuous coordinates) plus a tolerance.
Saved files keep only markers with status > 0.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from assets.arrays import check_fields
from assets.fileio import load_npz, save_npz
from assets.geometry import apply_homography, fit_homography
from assets.pattern.crops import (
    CROSSPOINT_CROP,
    RECOGNIZER_CROP,
    CropSpec,
    crop_homography,
    crop_localization_px,
    unwarp,
)
from assets.pattern.spec import PatternSpec
from assets.pattern.table import grid_localization_rc

#: a marker gets a crosspoint crop only when the homography fitted to its five localization points
#: puts each of them within this many cells (a quarter of the 24 per marker edge) of its place in the
#: crop.  Fully visible markers of the rendered shirt (curved cloth) fit within 4.7 cells, 3.1 at the
#: 99th percentile, synthetic ones within 7.9 (6.8 at the 99.9th); partial markers folded over or seen
#: edge-on miss by tens to thousands of cells.
MAX_CROP_FIT_CELLS = 6.0
#: a marker's localization point off the fabric is completed (`completed_points`) from a homography
#: fitted to at least this many of its crosspoints on the fabric
MIN_COMPLETION_CROSSPOINTS = 16


@dataclass(frozen=True, eq=False)
class ImageGroundTruth:
    """Marker points, projections and visibility in one image (see the module docstring)."""

    width: int
    height: int
    marker_id: np.ndarray
    points_px: np.ndarray
    points_depth: np.ndarray
    point_visible: np.ndarray
    crosspoints_px: np.ndarray
    crosspoint_visible: np.ndarray
    status: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.marker_id)
        k = self.crosspoints_px.shape[1] if self.crosspoints_px.ndim == 4 else -1
        expected = {
            "marker_id": ((m,), np.int32),
            "points_px": ((m, 5, 2), np.float32),
            "points_depth": ((m, 5), np.float32),
            "point_visible": ((m, 5), np.bool_),
            "crosspoints_px": ((m, k, k, 2), np.float32),
            "crosspoint_visible": ((m, k, k), np.bool_),
            "status": ((m,), np.int8),
        }
        check_fields(self, expected, valid=k >= 1)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height}")

    @property
    def num_markers(self) -> int:
        return len(self.marker_id)

    def select(self, index: np.ndarray) -> "ImageGroundTruth":
        """The ground truth of the markers at `index` (integer indices or a boolean mask)."""
        arrays = {f.name: getattr(self, f.name)[index] for f in fields(self) if f.name not in ("width", "height")}
        return ImageGroundTruth(self.width, self.height, **arrays)

    def jittered(self, sigma_px: float, rng: np.random.Generator) -> "ImageGroundTruth":
        """A copy whose five localization points are moved by independent Gaussian noise of standard
        deviation `sigma_px` pixels, where a Marker Localizer's errors put them; crosspoints,
        visibility and status stay the truth.  Crops cut from the copy (`recognizer_crops`,
        `crosspoint_crops`) are the slightly misaligned crops the Detector cuts, and crosspoint
        targets follow the moved crop.  Points off the fabric are completed first
        (`completed_points`), so a cut marker's completed corner moves too.  sigma_px 0: self."""
        if not sigma_px >= 0:
            raise ValueError(f"jittered: sigma_px must be >= 0, got {sigma_px}")
        if sigma_px == 0:
            return self
        noise = rng.normal(0.0, sigma_px, self.points_px.shape).astype(np.float32)
        return replace(self, points_px=completed_points(self) + noise)

    def save(self, path: str | Path) -> None:
        """Write the markers with status > 0 and the image size to an npz, atomically."""
        kept = self.select(self.status > 0)
        arrays = {f.name: getattr(kept, f.name) for f in fields(kept) if f.name not in ("width", "height")}
        save_npz(path, {**arrays, "width": np.int64(self.width), "height": np.int64(self.height)})

    @classmethod
    def load(cls, path: str | Path) -> "ImageGroundTruth":
        names = tuple(f.name for f in fields(cls))
        data = load_npz(path, required=names)
        try:
            return cls(width=int(data.pop("width")), height=int(data.pop("height")), **{n: data[n] for n in names[2:]})
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: {exc}") from exc


def completed_points(gt: ImageGroundTruth) -> np.ndarray:
    """(M, 5, 2) float32: the five localization points, each point off the fabric (NaN in
    `points_px`: a partial marker cut by the garment's edge) put where the marker's plane extends it,
    by the least-squares homography from the marker's crosspoint grid to its projected crosspoints
    on the fabric (at least `MIN_COMPLETION_CROSSPOINTS`; with fewer, the point stays NaN).  Points
    on the fabric are kept.  What a localizer can predict for a cut marker's missing corner, and
    what the recognizer's crop of it is cut from (the fabric's edge and what lies beyond it)."""
    points = np.array(gt.points_px, dtype=np.float32)
    missing = np.flatnonzero(~np.isfinite(points).all(axis=(1, 2)))
    if len(missing) == 0:
        return points
    k = gt.crosspoints_px.shape[1]
    rows, cols = np.meshgrid(np.arange(k, dtype=np.float64), np.arange(k, dtype=np.float64), indexing="ij")
    grid = np.stack([cols, rows], axis=-1).reshape(-1, 2)
    five = grid_localization_rc(k - 1)[:, ::-1].astype(np.float64)  # (col, row) = grid (x, y)
    for m in missing:
        projected = gt.crosspoints_px[m].reshape(-1, 2).astype(np.float64)
        on = np.isfinite(projected).all(axis=1)
        if on.sum() < MIN_COMPLETION_CROSSPOINTS:
            continue
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            fitted = apply_homography(fit_homography(grid[on], projected[on]), five)
        gap = ~np.isfinite(points[m]).all(axis=1)
        points[m, gap] = fitted[gap]
    return points


def localizer_targets(gt: ImageGroundTruth, cell: int = 8) -> np.ndarray:
    """The marker localizer's dense target (H // cell, W // cell, 11) float32.

    Channel 0: 1 in the cell containing the centre of a present marker (status > 0, centre visible),
    else 0.  Channels 1-10: its centre, TL, TR, BL, BR as (x, y) pixels relative to the cell's
    top-left corner (the centre's offsets lie in [0, cell)); a point off the fabric (a partial
    marker's missing corner) where the marker's plane extends it (`completed_points`), NaN when its
    on-fabric part is too small to say; 0 in empty cells.  Where two centres share a cell, the marker
    nearer the camera wins."""
    present = (gt.status > 0) & gt.point_visible[:, 0]
    return marker_cells(gt.width, gt.height, completed_points(gt), present, gt.points_depth[:, 0], cell)


def marker_cells(width: int, height: int, points_px: np.ndarray, present: np.ndarray, depth: np.ndarray,
                 cell: int = 8) -> np.ndarray:
    """`localizer_targets` from arrays: markers' five points (M, 5, 2) in an image of width x height,
    which of them are present (M,) bool (each present centre must lie inside the image) and their
    centres' depths (M,) (the nearer of two markers in one cell wins)."""
    if height % cell or width % cell:
        raise ValueError(f"image size {width} x {height} is not a multiple of the cell size {cell}")
    rows, cols = height // cell, width // cell
    present = np.flatnonzero(present)
    centre = points_px[present, 0].astype(np.float64)
    cx = np.clip(np.floor(centre[:, 0] / cell).astype(np.int64), 0, cols - 1)  # float32 may round up to W
    cy = np.clip(np.floor(centre[:, 1] / cell).astype(np.int64), 0, rows - 1)
    key = cy * cols + cx
    order = np.lexsort((depth[present], key))
    _, first = np.unique(key[order], return_index=True)
    chosen = order[first]
    out = np.zeros((rows, cols, 11), dtype=np.float32)
    corner = np.stack([cx[chosen], cy[chosen]], axis=1) * cell
    out[cy[chosen], cx[chosen], 0] = 1.0
    out[cy[chosen], cx[chosen], 1:] = (points_px[present[chosen]] - corner[:, None, :]).reshape(-1, 10)
    return out


def recognizer_markers(gt: ImageGroundTruth, spec: PatternSpec, partial: bool = False,
                       completed: np.ndarray | None = None) -> np.ndarray:
    """(N,) int64 indices into `gt` of the markers that get a Marker Recognizer crop: those whose five
    localization points are visible (the reference's crops); partial: also partial markers whose
    centre is visible (the localizer finds those, so the Detector recognizes them) and whose crop is
    sane (`crosspoint_markers`: five `completed_points` in front of the camera, a point off the
    fabric completed from the marker's crosspoints, giving a homography that describes a marker), in
    index order.  Their crops are cut from `completed_points` (completed: those, when the caller has
    them)."""
    whole = gt.point_visible.all(axis=1)
    if not partial:
        return np.flatnonzero(whole)
    keep = whole.copy()
    sane = crosspoint_markers(gt, spec, completed=completed)[0]
    keep[sane[gt.point_visible[sane, 0]]] = True
    return np.flatnonzero(keep)


def recognizer_crops(image: np.ndarray, gt: ImageGroundTruth, spec: PatternSpec, partial: bool = False
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Marker recognizer samples: (crops (N, 96, 96, C) of the image's dtype, marker IDs (N,) int32)
    of the markers of `recognizer_markers` (every marker whose five localization points are visible;
    partial: partial markers with a visible centre too), unwarped by `RECOGNIZER_CROP`.

    spec: the garment's pattern spec (`surface.spec`; the panels' specs differ only in their tiling,
    which crops do not depend on)."""
    image = _image(image, gt)
    if not partial:
        pick = recognizer_markers(gt, spec)
        return _unwarp(image, spec, RECOGNIZER_CROP, gt.points_px[pick]), gt.marker_id[pick]
    completed = completed_points(gt)
    pick = recognizer_markers(gt, spec, partial, completed)
    return _unwarp(image, spec, RECOGNIZER_CROP, completed[pick]), gt.marker_id[pick]


def crosspoint_crops(
    image: np.ndarray, gt: ImageGroundTruth, spec: PatternSpec, crop: CropSpec = CROSSPOINT_CROP,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Crosspoint localizer samples for the markers of `crosspoint_markers`.

    Returns crops (N, S, S, C) of the image's dtype (`crop`: the reference's `CROSSPOINT_CROP`, S =
    112), marker IDs (N,) int32, xy (N, K, K, 2) float32 crosspoint
    positions in crop pixels (the crop's homography applied to the projected crosspoints; NaN off
    the fabric) and visible (N, K, K) bool: the crosspoint is visible in the image and its xy lies
    in the crop, [0, S] x [0, S] (a visible crosspoint of a curved marker can fall outside; the
    network cannot see it there)."""
    image = _image(image, gt)
    if gt.crosspoints_px.shape[1] != spec.crosspoints_per_side:
        raise ValueError(f"spec has {spec.crosspoints_per_side} crosspoints per side, the ground truth "
                         f"{gt.crosspoints_px.shape[1]}")
    completed = completed_points(gt)
    pick, homography = crosspoint_markers(gt, spec, completed=completed, crop=crop)
    crops = _unwarp(image, spec, crop, completed[pick])
    xy, inside = _crop_targets(crop, homography, gt.crosspoints_px[pick])
    return crops, gt.marker_id[pick], xy.astype(np.float32), gt.crosspoint_visible[pick] & inside


def crosspoint_centre_markers(gt: ImageGroundTruth, spec: PatternSpec, crop: CropSpec = CROSSPOINT_CROP
                              ) -> np.ndarray:
    """Indices into `gt` of the markers `crosspoint_crops` cuts (in its order) whose centre crosspoint
    is visible in their crop: the crops the Detector gets (the localizer finds those markers), found
    without cutting any, so a caller that keeps a few of them cuts only those
    (`crosspoint_crops(image, gt.select(...))` gives the same rows: every step is per marker)."""
    completed = completed_points(gt)
    pick, homography = crosspoint_markers(gt, spec, completed=completed, crop=crop)
    c = spec.crosspoints_per_side // 2
    _, inside = _crop_targets(crop, homography, gt.crosspoints_px[pick, c:c + 1, c:c + 1])
    return pick[gt.crosspoint_visible[pick, c, c] & inside[:, 0, 0]]


def _crop_targets(crop: CropSpec, homography: np.ndarray, projected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crosspoints (N, A, B, 2) image pixels in the crops of markers with crop homographies (N, 3, 3):
    (xy float64 crop pixels, NaN off the fabric; inside (N, A, B) bool, xy within [0, S] x [0, S])."""
    shape = projected.shape
    flat = projected.astype(np.float64).reshape(len(homography), int(np.prod(shape[1:-1])), 2)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        xy = apply_homography(homography, flat).reshape(shape)
        inside = ((xy >= 0) & (xy <= crop.size_px)).all(axis=-1)
    return xy, inside


def crosspoint_markers(gt: ImageGroundTruth, spec: PatternSpec, max_fit_cells: float = MAX_CROP_FIT_CELLS,
                       completed: np.ndarray | None = None, crop: CropSpec = CROSSPOINT_CROP
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The markers that get a crosspoint crop: (indices (N,) int64 into `gt`, their crop homographies
    (N, 3, 3) float64 image -> `crop` pixels, `crop_homography` of their five `completed_points`).

    A marker qualifies when its status is > 0, its five localization points are known (on the
    fabric, or off it and completed from its crosspoints: a marker cut by the garment's edge) and in
    front of the camera (the crop follows their projections even where they are occluded) and their
    homography is sane (`sane_crop_homography`): a partial marker folded over or seen edge-on gives
    a degenerate fit that maps its visible crosspoints anywhere, up to millions of pixels away.
    completed: `completed_points(gt)` when the caller has them (they are computed otherwise)."""
    completed = completed_points(gt) if completed is None else completed
    with np.errstate(invalid="ignore"):
        in_front = ((gt.points_depth > 0) | np.isnan(gt.points_depth)).all(axis=1)  # NaN: off the fabric
        usable = np.isfinite(completed).all(axis=(1, 2)) & in_front
    pick = np.flatnonzero((gt.status > 0) & usable)
    if len(pick) == 0:
        return pick, np.zeros((0, 3, 3))
    points = completed[pick].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        homography = crop_homography(spec, crop, points)
    sane = sane_crop_homography(spec, crop, points, homography, max_fit_cells)
    return pick[sane], homography[sane]


def sane_crop_homography(spec: PatternSpec, crop: CropSpec, points_px: np.ndarray, homography: np.ndarray,
                         max_fit_cells: float = MAX_CROP_FIT_CELLS) -> np.ndarray:
    """(N,) bool: crop homographies (N, 3, 3) image -> `crop` pixels, fitted to five points (N, 5, 2)
    image pixels, that describe a marker: its corners are a convex quad turning as printed
    (`is_convex_layout`: not folded over or mirrored), each of the five points maps within
    `max_fit_cells` cells of its canonical crop position, and the whole crop square shows a bounded
    part of the image (the homography's vanishing line misses it: no crop wrapped through infinity)."""
    points_px = np.asarray(points_px, dtype=np.float64)
    homography = np.asarray(homography, dtype=np.float64)
    size = crop.size_px
    square = np.array([[0.0, 0.0, 1.0], [size, 0.0, 1.0], [0.0, size, 1.0], [size, size, 1.0]])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        fit = np.linalg.norm(apply_homography(homography, points_px) - crop_localization_px(spec, crop), axis=-1)
        fitted = fit.max(axis=-1) <= max_fit_cells * crop.px_per_cell(spec)
        # the third row of the inverse up to scale (the adjugate's, so a singular fit is no error):
        # the image depth of the crop's corners, of one sign where the crop is bounded
        depth = square @ np.cross(homography[:, :, 0], homography[:, :, 1])[..., None]
        bounded = (depth > 0).all(axis=(1, 2)) | (depth < 0).all(axis=(1, 2))
    return is_convex_layout(points_px) & fitted & bounded


def is_convex_layout(points_px: np.ndarray) -> np.ndarray:
    """(N,) bool: the corners TL, TR, BR, BL of five points (N, 5, 2) form a strictly convex
    quadrilateral turning as the printed marker does (seen from the front; a mirrored or folded-over
    quad is False)."""
    points_px = np.asarray(points_px, dtype=np.float64)
    ring = points_px[:, [1, 2, 4, 3]]  # TL, TR, BR, BL
    edge = np.roll(ring, -1, axis=1) - ring
    following = np.roll(edge, -1, axis=1)
    cross = edge[..., 0] * following[..., 1] - edge[..., 1] * following[..., 0]
    with np.errstate(invalid="ignore"):
        return (cross > 0).all(axis=1)


def _image(image: np.ndarray, gt: ImageGroundTruth) -> np.ndarray:
    image = np.asarray(image)
    if image.shape[:2] != (gt.height, gt.width) or image.ndim not in (2, 3):
        raise ValueError(f"image has shape {image.shape}, expected ({gt.height}, {gt.width}[, C]) of the ground truth")
    return image


def _unwarp(image: np.ndarray, spec: PatternSpec, crop: CropSpec, points_px: np.ndarray) -> np.ndarray:
    if len(points_px) == 0:
        return np.zeros((0, crop.size_px, crop.size_px) + image.shape[2:], dtype=image.dtype)
    return unwarp(image, spec, crop, points_px.astype(np.float64))


def training_samples(image: np.ndarray, gt: ImageGroundTruth, spec: PatternSpec) -> dict[str, np.ndarray]:
    """All three networks' training arrays of one image (what a dataset's ``samples/<name>.npz`` holds):
    cells (H/8, W/8, 11) of `localizer_targets`; recognizer_crops, recognizer_ids of
    `recognizer_crops`; crosspoint_crops, crosspoint_ids, crosspoint_xy, crosspoint_visible of
    `crosspoint_crops`.  The same from a saved ground truth (markers with status > 0 only) as from
    the full one."""
    rec, rec_ids = recognizer_crops(image, gt, spec)
    xp, xp_ids, xp_xy, xp_vis = crosspoint_crops(image, gt, spec)
    return {"cells": localizer_targets(gt), "recognizer_crops": rec, "recognizer_ids": rec_ids,
            "crosspoint_crops": xp, "crosspoint_ids": xp_ids, "crosspoint_xy": xp_xy, "crosspoint_visible": xp_vis}
