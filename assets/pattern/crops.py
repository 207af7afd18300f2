"""Marker crops: the one mapping between a marker's crosspoints and the pixels of its unwarped crop.

A crop (`CropSpec`) is a square image of `size_px` pixels showing one marker axis-aligned in its own
frame (TL corner top-left) with `margin_cells` cells of surroundings on every side, so at
``s = size_px / (cells_per_side + 2 margin)`` pixels per cell, crosspoint (row r, col c) of the marker
sits at continuous crop coordinates (pixel centres at +0.5, DESIGN.md)::

    x = (c + margin) * s,    y = (r + margin) * s

The reference's crops: the Marker Recognizer sees 96 x 96 (`RECOGNIZER_CROP`: margin 0, 4 px per cell,
corners on the crop's outer edge) and the Crosspoint Localizer 112 x 112 (`CROSSPOINT_CROP`: margin 2
cells, 4 px per cell, crosspoints at 8, 12, ..., 104).

`crop_homography` (image -> crop, fitted by least squares to the five localization points) is the one
function that makes training crops from ground truth, unwarps detections at inference, and renders the
reference textures' frame, so all three agree by construction.

`bent_crop_map` (crop -> image) is the option that follows curved cloth (`unwarp(..., bend=True)`; a
network trained on it says so in its config, `networks.config.TrainConfig.recognizer_bend`): the
homography through the four corners plus a displacement that puts the centre on its own point and
vanishes at the corners (the mean of a paraboloid and of one parabola per marker axis, `bent_crop_map`).
Five points do not fit a homography on curved cloth, and the least-squares one misplaces the
crosspoints: on the 10,195 fully visible markers of 120 renders their median distance from where the
map puts the crop's canonical grid is 0.36 cells with the homography, 0.14 with the bend (the tenth of
markers furthest off a homography: 1.22 against 0.45 cells; `benchmarks/crop_bend.py`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from assets.geometry import apply_homography, fit_homography
from assets.pattern.raster import cell_weights, composite, line_coverage
from assets.pattern.spec import PatternSpec
from assets.pattern.table import localization_rc


@dataclass(frozen=True)
class CropSpec:
    """A square marker crop: `size_px` pixels, `margin_cells` cells around the marker."""

    size_px: int
    margin_cells: float

    def __post_init__(self) -> None:
        if self.size_px < 8 or self.margin_cells < 0:
            raise ValueError(f"invalid CropSpec: size_px={self.size_px} (>= 8), margin_cells={self.margin_cells} (>= 0)")

    def px_per_cell(self, spec: PatternSpec) -> float:
        return self.size_px / (spec.cells_per_side + 2 * self.margin_cells)


RECOGNIZER_CROP = CropSpec(size_px=96, margin_cells=0)
CROSSPOINT_CROP = CropSpec(size_px=112, margin_cells=2)


def crop_crosspoints_px(spec: PatternSpec, crop: CropSpec) -> np.ndarray:
    """(K, K, 2) continuous crop coordinates (x, y) of every marker crosspoint (row, col)."""
    s = crop.px_per_cell(spec)
    k = np.arange(spec.crosspoints_per_side, dtype=np.float64)
    x = (k[None, :] + crop.margin_cells) * s
    y = (k[:, None] + crop.margin_cells) * s
    return np.stack(np.broadcast_arrays(x, y), axis=-1)


def crop_localization_px(spec: PatternSpec, crop: CropSpec) -> np.ndarray:
    """(5, 2) crop coordinates of centre, TL, TR, BL, BR."""
    rc = localization_rc(spec)
    return crop_crosspoints_px(spec, crop)[rc[:, 0], rc[:, 1]]


def crop_homography(spec: PatternSpec, crop: CropSpec, localization_px: np.ndarray) -> np.ndarray:
    """Homographies image -> crop from a marker's five localization points in an image.

    localization_px: (5, 2) or (N, 5, 2) continuous image coordinates of centre, TL, TR, BL, BR.
    Returns (3, 3) or (N, 3, 3), mapping continuous image coordinates to continuous crop coordinates.
    """
    points = np.asarray(localization_px, dtype=np.float64)
    if points.shape[-2:] != (5, 2):
        raise ValueError(f"localization points must have shape (5, 2) or (N, 5, 2), got {points.shape}")
    return fit_homography(points, crop_localization_px(spec, crop))


def bent_crop_map(spec: PatternSpec, crop: CropSpec, localization_px: np.ndarray,
                  crop_xy: np.ndarray | None = None) -> np.ndarray:
    """Crop -> image coordinates of markers on curved cloth (module docstring): the homography through
    the four corners plus a displacement that is the centre's offset d from that homography at the
    centre and vanishes at the corners.  With x, y from -1 to 1 across the marker (corner to corner
    through the centre), the displacement is the mean of the paraboloid ``(1 - (x^2 + y^2) / 2) d``
    (a dome) and of ``(1 - x^2) a e_x + (1 - y^2) b e_y``, where d = a e_x + b e_y on the marker's
    image axes e_x, e_y (a cylinder along each axis).  All five points map exactly.

    localization_px: (5, 2) or (N, 5, 2) continuous image coordinates of centre, TL, TR, BL, BR;
    crop_xy: (..., 2) continuous crop coordinates (default: every crop pixel's centre, (S, S, 2)).
    Returns (N, ..., 2) (or (..., 2) for one marker) continuous image coordinates."""
    points, single = _five_points(localization_px)
    if crop_xy is None:
        shape, (homogeneous, weights) = (crop.size_px, crop.size_px, 2), _pixel_bend_basis(spec, crop)
    else:
        shape, (homogeneous, weights) = np.shape(crop_xy), _bend_basis(spec, crop, crop_xy)
    corners, fields = _bend_parts(spec, crop, points)
    mapped = homogeneous @ np.swapaxes(corners, -1, -2)  # (N, P, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        mapped = mapped[..., :2] / mapped[..., 2:]
    out = (mapped + weights @ fields).reshape(len(points), *shape)
    return out[0] if single else out


def _five_points(localization_px: np.ndarray) -> tuple[np.ndarray, bool]:
    """(N, 5, 2) float64 localization points, and whether one marker's (5, 2) were given."""
    points = np.asarray(localization_px, dtype=np.float64)
    single = points.ndim == 2
    points = points[None] if single else points
    if points.shape[-2:] != (5, 2):
        raise ValueError(f"localization points must have shape (5, 2) or (N, 5, 2), got {points.shape}")
    return points, single


def _marker_points(points: np.ndarray, single: bool, xy: np.ndarray, frame: str) -> tuple[np.ndarray, tuple]:
    """Each marker's own points (..., 2) of one marker (`single`) or (N, ..., 2) for the N markers of
    `points` (N, 5, 2), as (N, P, 2) float64 and the shape (with N) to give results back in; `frame`
    ("crop", "image") names them in the error."""
    values = np.asarray(xy, dtype=np.float64)
    values = values[None] if single else values
    if values.shape[0] != len(points) or values.shape[-1] != 2:
        raise ValueError(f"{frame} points must have shape (N, ..., 2) for N = {len(points)} markers, got "
                         f"{np.shape(xy)}")
    return values.reshape(len(points), -1, 2), values.shape


def _bend_parts(spec: PatternSpec, crop: CropSpec, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`bent_crop_map`'s per-marker parts for points (N, 5, 2): the corners' homographies (N, 3, 3)
    crop -> image, and the fields (N, 3, 2) the weights of `_bend_basis` multiply: half the centre's
    offset d (the dome), half a e_x and half b e_y (the cylinders; d = a e_x + b e_y)."""
    canonical = crop_localization_px(spec, crop)
    n = len(points)
    corners = fit_homography(np.broadcast_to(canonical[1:], (n, 4, 2)), points[:, 1:])  # (N, 3, 3) crop -> image
    offset = points[:, 0] - apply_homography(corners, np.broadcast_to(canonical[:1], (n, 1, 2)))[:, 0]  # (N, 2)
    _, tl, tr, bl, br = (points[:, k] for k in range(5))
    e_x, e_y = (tr - tl + br - bl) / 2, (bl - tl + br - tr) / 2  # (N, 2): the marker's image axes
    det = e_x[:, 0] * e_y[:, 1] - e_x[:, 1] * e_y[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):  # offset = a e_x + b e_y (Cramer)
        a = (offset[:, 0] * e_y[:, 1] - offset[:, 1] * e_y[:, 0]) / det
        b = (e_x[:, 0] * offset[:, 1] - e_x[:, 1] * offset[:, 0]) / det
    a, b = (np.where(np.isfinite(v), v, 0.0)[:, None] for v in (a, b))  # a degenerate quad: the dome alone
    return corners, 0.5 * np.stack([offset, a * e_x, b * e_y], axis=1)


def _bend_basis(spec: PatternSpec, crop: CropSpec, crop_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`bent_crop_map`'s fixed parts at crop points (..., 2): their homogeneous coordinates (P, 3) and
    the weights (P, 3) of the dome ``1 - (x^2 + y^2) / 2`` and the cylinders ``1 - x^2``, ``1 - y^2``."""
    canonical = crop_localization_px(spec, crop)
    flat = np.asarray(crop_xy, dtype=np.float64).reshape(-1, 2)
    weights = _bend_weights((flat - canonical[0]) / (canonical[4] - canonical[0]))
    return np.concatenate([flat, np.ones((len(flat), 1))], axis=1), weights


def _bend_weights(xy: np.ndarray) -> np.ndarray:
    """(..., 3): at marker coordinates xy (..., 2) (centre 0, corners +-1), the weights of the dome
    ``1 - (x^2 + y^2) / 2`` and of the cylinders ``1 - x^2``, ``1 - y^2``."""
    return np.stack([1.0 - 0.5 * (xy ** 2).sum(axis=-1), 1.0 - xy[..., 0] ** 2, 1.0 - xy[..., 1] ** 2], axis=-1)


@functools.lru_cache(maxsize=8)
def _pixel_bend_basis(spec: PatternSpec, crop: CropSpec) -> tuple[np.ndarray, np.ndarray]:
    """`_bend_basis` at every crop pixel's centre, kept: the map is cut for every training crop."""
    centres = np.arange(crop.size_px, dtype=np.float64) + 0.5
    basis = _bend_basis(spec, crop, np.stack(np.meshgrid(centres, centres), axis=-1))
    for array in basis:
        array.flags.writeable = False
    return basis


def unwarp(image: np.ndarray, spec: PatternSpec, crop: CropSpec, localization_px: np.ndarray,
           bend: bool = False) -> np.ndarray:
    """Cut the crops of N markers out of one image.

    image (H, W) or (H, W, C); localization_px (N, 5, 2) or (5, 2) continuous image coordinates.
    bend: through `bent_crop_map` (curved cloth) instead of `crop_homography`.
    Returns (N, S, S[, C]) (or (S, S[, C])) with the image's dtype, bilinear, zero outside the image.
    """
    points = np.asarray(localization_px, dtype=np.float64)
    single = points.ndim == 2
    size = (crop.size_px, crop.size_px)
    if bend:
        maps = (bent_crop_map(spec, crop, points[None] if single else points) - 0.5).astype(np.float32)
        crops = np.stack([cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
                          for m in maps])
        return crops[0] if single else crops
    homographies = crop_homography(spec, crop, points[None] if single else points)
    # OpenCV puts pixel centres at integers; ours are at +0.5: conjugate by a half-pixel shift.
    to_cv = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]])
    from_cv = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    crops = np.stack(
        [cv2.warpPerspective(image, to_cv @ h @ from_cv, size, flags=cv2.INTER_LINEAR) for h in homographies]
    )
    return crops[0] if single else crops


def reference_textures(spec: PatternSpec, codes: np.ndarray, crop: CropSpec) -> np.ndarray:
    """The canonical crops of markers with module grids `codes` (N, n, n): (N, S, S, 3) uint8.

    Exactly what `unwarp` yields for a flat, fronto-parallel marker, rendered with the same box
    filter as the printable pattern.  The margin shows the grid lines, which continue on the fabric,
    over background: the neighbours' codes are not part of a marker's identity.
    """
    codes = np.asarray(codes)
    n = spec.cells_per_side
    k = spec.cells_per_module
    cells = np.repeat(np.repeat(codes, k, axis=-2), k, axis=-1).astype(np.float32)  # (N, n, n)
    s = crop.px_per_cell(spec)
    edges = np.arange(crop.size_px + 1) / s - crop.margin_cells
    weights = cell_weights(edges, 0, n).toarray()  # (S, n)
    fill = weights @ cells @ weights.T
    lo, hi = int(np.floor(edges[0])), int(np.ceil(edges[-1]))
    lines_1d = line_coverage(spec, edges, lo, hi)
    lines = lines_1d[:, None] + lines_1d[None, :] - lines_1d[:, None] * lines_1d[None, :]
    return composite(spec, fill, np.broadcast_to(lines, fill.shape))
