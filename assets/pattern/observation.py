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

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from assets.arrays import check_fields
from assets.fileio import load_npz, save_npz
from assets.geometry import apply_homography
from assets.pattern.crops import CROSSPOINT_CROP, RECOGNIZER_CROP, CropSpec, crop_homography, unwarp
from assets.pattern.spec import PatternSpec


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


def localizer_targets(gt: ImageGroundTruth, cell: int = 8) -> np.ndarray:
    """The marker localizer's dense target (H // cell, W // cell, 11) float32.

    Channel 0: 1 in the cell containing the centre of a present marker (status > 0, centre visible),
    else 0.  Channels 1-10: its centre, TL, TR, BL, BR as (x, y) pixels relative to the cell's
    top-left corner (the centre's offsets lie in [0, cell)); NaN for a point off the fabric (a
    partial marker's missing corner); 0 in empty cells.  Where two centres share a cell, the marker
    nearer the camera wins."""
    if gt.height % cell or gt.width % cell:
        raise ValueError(f"image size {gt.width} x {gt.height} is not a multiple of the cell size {cell}")
    rows, cols = gt.height // cell, gt.width // cell
    present = np.flatnonzero((gt.status > 0) & gt.point_visible[:, 0])
    centre = gt.points_px[present, 0].astype(np.float64)
    cx = np.clip(np.floor(centre[:, 0] / cell).astype(np.int64), 0, cols - 1)  # float32 may round up to W
    cy = np.clip(np.floor(centre[:, 1] / cell).astype(np.int64), 0, rows - 1)
    key = cy * cols + cx
    order = np.lexsort((gt.points_depth[present, 0], key))
    _, first = np.unique(key[order], return_index=True)
    chosen = order[first]
    out = np.zeros((rows, cols, 11), dtype=np.float32)
    corner = np.stack([cx[chosen], cy[chosen]], axis=1) * cell
    out[cy[chosen], cx[chosen], 0] = 1.0
    out[cy[chosen], cx[chosen], 1:] = (gt.points_px[present[chosen]] - corner[:, None, :]).reshape(-1, 10)
    return out


def recognizer_crops(image: np.ndarray, gt: ImageGroundTruth, spec: PatternSpec) -> tuple[np.ndarray, np.ndarray]:
    """Marker recognizer samples: (crops (N, 96, 96, C) of the image's dtype, marker IDs (N,) int32)
    for every marker whose five localization points are visible, unwarped by `RECOGNIZER_CROP`.

    spec: the garment's pattern spec (`surface.spec`; the panels' specs differ only in their tiling,
    which crops do not depend on)."""
    image = _image(image, gt)
    pick = np.flatnonzero(gt.point_visible.all(axis=1))
    return _unwarp(image, spec, RECOGNIZER_CROP, gt.points_px[pick]), gt.marker_id[pick]


def crosspoint_crops(
    image: np.ndarray, gt: ImageGroundTruth, spec: PatternSpec
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Crosspoint localizer samples for every marker with status > 0 whose five localization points
    are on the fabric and in front of the camera (the crop follows their projections even where
    they are occluded).

    Returns crops (N, 112, 112, C) of the image's dtype (`CROSSPOINT_CROP`), marker IDs (N,) int32,
    xy (N, K, K, 2) float32 crosspoint positions in crop pixels (the crop's homography applied to
    the projected crosspoints; NaN off the fabric) and visible (N, K, K) bool."""
    image = _image(image, gt)
    if gt.crosspoints_px.shape[1] != spec.crosspoints_per_side:
        raise ValueError(f"spec has {spec.crosspoints_per_side} crosspoints per side, the ground truth "
                         f"{gt.crosspoints_px.shape[1]}")
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(gt.points_px).all(axis=(1, 2)) & (gt.points_depth > 0).all(axis=1)
    pick = np.flatnonzero((gt.status > 0) & usable)
    crops = _unwarp(image, spec, CROSSPOINT_CROP, gt.points_px[pick])
    k = spec.crosspoints_per_side
    if len(pick):
        homography = crop_homography(spec, CROSSPOINT_CROP, gt.points_px[pick].astype(np.float64))
        xy = apply_homography(homography, gt.crosspoints_px[pick].reshape(len(pick), -1, 2)).reshape(-1, k, k, 2)
    else:
        xy = np.zeros((0, k, k, 2))
    return crops, gt.marker_id[pick], xy.astype(np.float32), gt.crosspoint_visible[pick]


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
