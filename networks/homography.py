"""The Detector's geometry on plain arrays (numpy only): crop <-> image maps, layout consistency of
five predicted points, and the homography of a cut marker estimated from its neighbours.

Frames: image pixels are continuous (x right, y down, pixel centres at integer + 0.5); crop pixels are
those of `assets.pattern.CropSpec` (the marker axis-aligned, TL corner top-left); the canonical layout
is a marker's own frame in cells (x = local column, y = local row, so TL = (0, 0), BR = (24, 24));
`pattern_xy` is metres on the flat fabric (x right, y up).  Five points are always in the order
centre, TL, TR, BL, BR (`assets.pattern.LOCALIZATION_POINTS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from assets.geometry import apply_homography, fit_homography
from assets.pattern import CropSpec, MarkerTable, PatternSpec, crop_homography, localization_rc

#: neighbour offsets (d_row, d_col) on the marker grid: the 8 markers sharing an edge or a corner
_NEIGHBOUR_OFFSETS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


def crop_to_image(spec: PatternSpec, crop: CropSpec, points_px: np.ndarray, crop_xy: np.ndarray) -> np.ndarray:
    """Map crop pixels back to image pixels through the inverse of each marker's crop homography.

    points_px (N, 5, 2) image pixels (the points the crops were unwarped with); crop_xy (N, ..., 2)
    crop pixels of `crop`.  Returns (N, ..., 2) float64 image pixels.
    """
    points_px = np.asarray(points_px, dtype=np.float64)
    crop_xy = np.asarray(crop_xy, dtype=np.float64)
    if points_px.ndim != 3 or crop_xy.shape[:1] != points_px.shape[:1] or crop_xy.shape[-1] != 2:
        raise ValueError(f"crop_to_image: points_px must be (N, 5, 2) and crop_xy (N, ..., 2), "
                         f"got {points_px.shape} and {crop_xy.shape}")
    n = len(points_px)
    if n == 0:
        return np.zeros(crop_xy.shape)
    to_image = np.linalg.inv(crop_homography(spec, crop, points_px))
    return apply_homography(to_image, crop_xy.reshape(n, -1, 2)).reshape(crop_xy.shape)


def canonical_layout(spec: PatternSpec) -> np.ndarray:
    """(5, 2) float64: the five localization points in the marker's own frame, in cells (x=col, y=row)."""
    return localization_rc(spec)[:, ::-1].astype(np.float64)


def layout_residual(spec: PatternSpec, points_px: np.ndarray) -> np.ndarray:
    """How far five points are from a homography of the canonical layout: (N,) float64 in cells.

    The four corners fix a homography image -> marker frame; the residual is the distance, in cells of
    the marker (24 per side), between the predicted centre mapped by it and the canonical centre.
    One corner off by d cells gives a residual of about d / 3.  Scale-free, so one threshold fits near
    and far markers; +inf where a point is not finite or the corners are degenerate.
    """
    points_px = np.asarray(points_px, dtype=np.float64)
    out = np.full(len(points_px), np.inf)
    finite = np.isfinite(points_px).all(axis=(1, 2))
    if finite.any():
        layout = canonical_layout(spec)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            h = fit_homography(points_px[finite, 1:], layout[1:])
            error = np.linalg.norm(apply_homography(h, points_px[finite, :1]) - layout[:1], axis=-1)[:, 0]
        out[finite] = np.where(np.isfinite(error), error, np.inf)
    return out


def inside_image(points_px: np.ndarray, width: int, height: int) -> np.ndarray:
    """(...,) bool: points (..., 2) lie in the image [0, width] x [0, height] (False for NaN)."""
    points_px = np.asarray(points_px, dtype=np.float64)
    x, y = points_px[..., 0], points_px[..., 1]
    with np.errstate(invalid="ignore"):
        return (x >= 0) & (x <= width) & (y >= 0) & (y <= height)


def fit_homography_masked(src: np.ndarray, dst: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Least-squares homographies ``dst ~ H src`` over the masked points only (normalised DLT).

    src, dst (N, P, 2); mask (N, P) bool.  Points outside the mask may be NaN.  Returns (N, 3, 3)
    float64 with H[2, 2] = 1, all NaN where fewer than 4 points are masked in.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if src.ndim != 3 or src.shape != dst.shape or src.shape[-1] != 2 or mask.shape != src.shape[:2]:
        raise ValueError(f"fit_homography_masked: expected src, dst (N, P, 2) and mask (N, P), "
                         f"got {src.shape}, {dst.shape}, {mask.shape}")
    weight = mask.astype(np.float64)
    count = weight.sum(axis=1)
    ts, s = _masked_normalise(np.where(mask[..., None], src, 0.0), weight, count)
    td, d = _masked_normalise(np.where(mask[..., None], dst, 0.0), weight, count)
    x, y, u, v = s[..., 0], s[..., 1], d[..., 0], d[..., 1]
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([-x, -y, -one, zero, zero, zero, u * x, u * y, u], axis=-1) * weight[..., None]
    rows_v = np.stack([zero, zero, zero, -x, -y, -one, v * x, v * y, v], axis=-1) * weight[..., None]
    a = np.concatenate([rows_u, rows_v], axis=1)  # (N, 2P, 9); masked-out rows are zero
    hn = np.linalg.svd(a)[2][:, -1].reshape(-1, 3, 3)
    h = np.linalg.inv(td) @ hn @ ts
    with np.errstate(invalid="ignore", divide="ignore"):
        h = h / h[:, 2:3, 2:3]
    h[count < 4] = np.nan
    return h


def _masked_normalise(points: np.ndarray, weight: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Similarity (N, 3, 3) moving the masked centroid to 0 and mean distance to sqrt(2), and the
    points mapped by it (masked-out points become 0 after weighting by the caller)."""
    total = np.maximum(count, 1.0)
    centre = (points * weight[..., None]).sum(axis=1) / total[:, None]
    spread = (np.linalg.norm(points - centre[:, None], axis=2) * weight).sum(axis=1) / total
    scale = np.sqrt(2.0) / np.maximum(spread, 1e-12)
    t = np.zeros((len(points), 3, 3))
    t[:, 0, 0] = t[:, 1, 1] = scale
    t[:, :2, 2] = -scale[:, None] * centre
    t[:, 2, 2] = 1.0
    return t, (points - centre[:, None]) * scale[:, None, None]


@dataclass(frozen=True, eq=False)
class MarkerLayout:
    """Where every marker ID of a garment sits on its panel: the marker tables indexed by ID.

      table_of_id     (num_ids,) int64        panel (table) index of each ID, -1 if not on the garment
      rc_of_id        (num_ids, 2) int64      (row, col) on that panel's marker grid
      localization_xy (num_ids, 5, 2) float64 the five localization points in the panel's pattern_xy
                                              (metres), NaN for IDs not on the garment
      table_shape     (T, 2) int64            each table's marker grid (rows, cols)
      table_first_id  (T,) int64
    """

    table_of_id: np.ndarray
    rc_of_id: np.ndarray
    localization_xy: np.ndarray
    table_shape: np.ndarray
    table_first_id: np.ndarray

    @classmethod
    def from_tables(cls, tables: Sequence[MarkerTable], num_ids: int) -> "MarkerLayout":
        """The layout of a garment's `tables` (one per panel, disjoint IDs below `num_ids`)."""
        table_of_id = np.full(num_ids, -1, dtype=np.int64)
        rc_of_id = np.full((num_ids, 2), -1, dtype=np.int64)
        localization_xy = np.full((num_ids, 5, 2), np.nan)
        for t, table in enumerate(tables):
            ids = table.marker_ids.astype(np.int64)
            if ids.max() >= num_ids:
                raise ValueError(f"tables[{t}]: marker IDs {ids.min()}..{ids.max()} exceed the "
                                 f"pattern's {num_ids} IDs")
            clash = table_of_id[ids] >= 0
            if clash.any():
                raise ValueError(f"tables[{t}]: marker ID {ids[clash][0]} is also in "
                                 f"tables[{table_of_id[ids[clash][0]]}]; IDs must be unique on a garment")
            table_of_id[ids] = t
            rc_of_id[ids] = table.marker_rc
            localization_xy[ids] = table.localization_xy
        shape = np.array([(t.spec.rows, t.spec.cols) for t in tables], dtype=np.int64).reshape(-1, 2)
        first = np.array([t.first_id for t in tables], dtype=np.int64)
        return cls(table_of_id, rc_of_id, localization_xy, shape, first)

    @property
    def num_ids(self) -> int:
        return len(self.table_of_id)

    def contains(self, marker_id: np.ndarray) -> np.ndarray:
        """(N,) bool: the IDs are on the garment."""
        marker_id = np.asarray(marker_id, dtype=np.int64)
        inside = (marker_id >= 0) & (marker_id < self.num_ids)
        return inside & (self.table_of_id[np.where(inside, marker_id, 0)] >= 0)

    def neighbours(self, marker_id: np.ndarray) -> np.ndarray:
        """(N, 8) int64: IDs of the markers sharing an edge or a corner on the same panel, -1 where
        there is none (grid border, or an ID not on the garment)."""
        marker_id = np.asarray(marker_id, dtype=np.int64)
        known = self.contains(marker_id)
        safe = np.where(known, marker_id, 0)
        table = np.where(known, self.table_of_id[safe], 0)
        rc = self.rc_of_id[safe][:, None, :] + _NEIGHBOUR_OFFSETS[None]  # (N, 8, 2)
        rows, cols = self.table_shape[table, 0][:, None], self.table_shape[table, 1][:, None]
        valid = known[:, None] & (rc >= 0).all(axis=-1) & (rc[..., 0] < rows) & (rc[..., 1] < cols)
        ids = self.table_first_id[table][:, None] + rc[..., 0] * cols + rc[..., 1]
        return np.where(valid, ids, -1)


def estimate_from_neighbours(
    layout: MarkerLayout,
    spec: PatternSpec,
    marker_id: np.ndarray,
    points_px: np.ndarray,
    full: np.ndarray,
    confidence: np.ndarray,
    image_size: tuple[int, int],
    consistency_cells: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Five points of the cut markers of one image, predicted from their fully visible neighbours.

    marker_id (N,), points_px (N, 5, 2) image pixels, full (N,) bool (the marker's own five points are
    trusted), confidence (N,) (picks one detection when an ID was found twice), image_size (W, H).
    For every marker that is not `full` but on the garment, a pattern_xy -> image homography is fitted
    to the localization points of its detected full neighbours on the same panel, then refitted with
    those of its own points that lie in the image within `consistency_cells` cells of the first
    prediction; its five points are that homography applied to its localization_xy.

    Returns (points (N, 5, 2) float64: estimated where `estimated`, else the input; estimated (N,) bool).
    """
    marker_id = np.asarray(marker_id, dtype=np.int64)
    points_px = np.asarray(points_px, dtype=np.float64)
    full = np.asarray(full, dtype=bool)
    out = points_px.copy()
    estimated = np.zeros(len(marker_id), dtype=bool)
    known = layout.contains(marker_id)
    targets = np.flatnonzero(~full & known)
    sources = np.flatnonzero(full & known)
    if len(targets) == 0 or len(sources) == 0:
        return out, estimated
    # the most confident full detection of every ID
    ranked = sources[np.argsort(-np.asarray(confidence)[sources], kind="stable")]
    unique_ids, first = np.unique(marker_id[ranked], return_index=True)
    detection_of_id = np.full(layout.num_ids, -1, dtype=np.int64)
    detection_of_id[unique_ids] = ranked[first]

    neighbour = layout.neighbours(marker_id[targets])  # (T, 8)
    detection = np.where(neighbour >= 0, detection_of_id[np.maximum(neighbour, 0)], -1)
    found = detection >= 0
    t = len(targets)
    src = np.concatenate([layout.localization_xy[np.maximum(neighbour, 0)].reshape(t, 40, 2),
                          layout.localization_xy[marker_id[targets]]], axis=1)  # (T, 45, 2)
    dst = np.concatenate([points_px[np.maximum(detection, 0)].reshape(t, 40, 2), points_px[targets]], axis=1)
    mask = np.concatenate([np.repeat(found, 5, axis=1), np.zeros((t, 5), dtype=bool)], axis=1)

    first_fit = fit_homography_masked(src, dst, mask)
    own_xy = layout.localization_xy[marker_id[targets]]
    predicted = apply_homography(first_fit, own_xy)  # (T, 5, 2)
    side_px = np.linalg.norm(np.diff(predicted[:, [1, 2, 4, 3, 1]], axis=1), axis=-1).mean(axis=1)
    tolerance = consistency_cells * side_px / spec.cells_per_side
    with np.errstate(invalid="ignore"):
        consistent = (np.linalg.norm(points_px[targets] - predicted, axis=-1) <= tolerance[:, None]) & inside_image(
            points_px[targets], *image_size)
    mask[:, 40:] = consistent
    predicted = apply_homography(fit_homography_masked(src, dst, mask), own_xy)
    ok = found.any(axis=1) & np.isfinite(predicted).all(axis=(1, 2))
    out[targets[ok]] = predicted[ok]
    estimated[targets[ok]] = True
    return out, estimated
