"""The Detector's geometry on plain arrays (numpy only): crop <-> image maps, the smoothing of a marker's
crosspoints, layout consistency of five predicted points, masked and weighted homography fits, a
marker's pose from its own crosspoints and the localizer's scale.  What needs the garment's layout
(neighbours, ID votes, cut and missed markers placed by their neighbours) is `networks.neighbours`.

Frames: image pixels are continuous (x right, y down, pixel centres at integer + 0.5); crop pixels are
those of `assets.pattern.CropSpec` (the marker axis-aligned, TL corner top-left); the canonical layout
is a marker's own frame in cells (x = local column, y = local row, so TL = (0, 0), BR = (24, 24));
`pattern_xy` is metres on the flat fabric (x right, y up).  Five points are always in the order
centre, TL, TR, BL, BR (`assets.pattern.LOCALIZATION_POINTS`).
"""

from __future__ import annotations

import numpy as np

from assets.geometry import apply_homography, fit_homography, invert_3x3
from assets.pattern import CropSpec, PatternSpec, crop_homography, localization_rc


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
    to_image = invert_3x3(crop_homography(spec, crop, points_px))
    return apply_homography(to_image, crop_xy.reshape(n, -1, 2)).reshape(crop_xy.shape)


#: `smooth_crosspoints`: the polynomial's degree (3 measured best on exact synthesized and rendered crops:
#: 2 cannot follow the renders' folds, 4 and more follow the network's noise) and the fewest visible
#: crosspoints, per coefficient, that a marker's fit needs
SMOOTH_DEGREE, SMOOTH_POINTS_PER_TERM = 3, 3


def smooth_crosspoints(crop_xy: np.ndarray, visible: np.ndarray, tolerance_px: float, degree: int = SMOOTH_DEGREE
                       ) -> np.ndarray:
    """Each marker's visible crosspoints moved onto a smooth field fitted to them, where they lie near it.

    crop_xy (N, K, K, 2) crop pixels, visible (N, K, K) bool.  Per marker, a polynomial of `degree` in
    the grid position (row, column) is fitted by least squares to its visible crosspoints, once more
    without those further than `tolerance_px` from the first fit; a visible crosspoint within
    `tolerance_px` of the second fit takes its value, the others (a fold the polynomial cannot follow,
    a wrong prediction) keep their own.  Cloth is smooth across one marker, the network's errors are
    not: the fit averages them out.  A marker with fewer than `SMOOTH_POINTS_PER_TERM` visible
    crosspoints per coefficient is left as it is, as are hidden crosspoints.  Returns a new array."""
    crop_xy = np.asarray(crop_xy, dtype=np.float64)
    visible = np.asarray(visible, dtype=bool)
    if crop_xy.ndim != 4 or crop_xy.shape[1] != crop_xy.shape[2] or crop_xy.shape[-1] != 2 \
            or visible.shape != crop_xy.shape[:3]:
        raise ValueError(f"smooth_crosspoints: crop_xy must be (N, K, K, 2) and visible (N, K, K), got "
                         f"{crop_xy.shape} and {visible.shape}")
    if not tolerance_px > 0 or degree < 1:
        raise ValueError(f"smooth_crosspoints: tolerance_px must be > 0 and degree >= 1, got {tolerance_px}, {degree}")
    n, k = crop_xy.shape[:2]
    grid = np.linspace(-1.0, 1.0, k)
    row, col = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    terms = np.stack([col ** i * row ** j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=1)  # (P, T)
    points = np.where(visible[..., None], crop_xy, 0.0).reshape(n, k * k, 2)
    seen = visible.reshape(n, k * k)
    needed = SMOOTH_POINTS_PER_TERM * terms.shape[1]
    enough = seen.sum(axis=1) >= needed

    def fit(w: np.ndarray) -> np.ndarray:  # (N, P) bool weights -> (N, P, 2) fitted field
        # matrix products, not a three-operand einsum (which numpy loops over without BLAS: 1 ms a marker)
        weighted = np.swapaxes(w[:, :, None] * terms, 1, 2)  # (N, T, P)
        normal = weighted @ terms
        normal += np.eye(terms.shape[1]) * 1e-9 * np.trace(normal, axis1=1, axis2=2)[:, None, None].clip(min=1.0)
        coef = np.linalg.solve(normal, weighted @ points)
        return terms @ coef

    out = crop_xy.reshape(n, k * k, 2).copy()
    if not enough.any():
        return out.reshape(crop_xy.shape)
    near = (np.linalg.norm(points - fit(seen), axis=-1) <= tolerance_px) & seen
    # refit without the far ones, where enough are near (else on all the visible ones again)
    fitted = fit(np.where((near.sum(axis=1) >= needed)[:, None], near, seen))
    move = (np.linalg.norm(points - fitted, axis=-1) <= tolerance_px) & seen & enough[:, None]
    out[move] = fitted[move]
    return out.reshape(crop_xy.shape)


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
    return fit_homography_weighted(src, dst, np.asarray(mask, dtype=bool).astype(np.float64))


def fit_homography_weighted(src: np.ndarray, dst: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Weighted least-squares homographies ``dst ~ H src`` (normalised DLT, each point's two rows
    scaled by its weight).

    src, dst (N, P, 2); weight (N, P) >= 0, points of weight 0 take no part (and may be NaN).  Returns
    (N, 3, 3) float64 with H[2, 2] = 1, all NaN where fewer than 4 points have a weight above 0.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    weight = np.asarray(weight, dtype=np.float64)
    if src.ndim != 3 or src.shape != dst.shape or src.shape[-1] != 2 or weight.shape != src.shape[:2]:
        raise ValueError(f"fit_homography_weighted: expected src, dst (N, P, 2) and weight (N, P), "
                         f"got {src.shape}, {dst.shape}, {weight.shape}")
    if (weight < 0).any() or not np.isfinite(weight).all():
        raise ValueError("fit_homography_weighted: weights must be finite and >= 0")
    used = weight > 0
    count = weight.sum(axis=1)
    ts, s = _masked_normalise(np.where(used[..., None], src, 0.0), weight, count)
    td, d = _masked_normalise(np.where(used[..., None], dst, 0.0), weight, count)
    x, y, u, v = s[..., 0], s[..., 1], d[..., 0], d[..., 1]
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([-x, -y, -one, zero, zero, zero, u * x, u * y, u], axis=-1) * weight[..., None]
    rows_v = np.stack([zero, zero, zero, -x, -y, -one, v * x, v * y, v], axis=-1) * weight[..., None]
    a = np.concatenate([rows_u, rows_v], axis=1)  # (N, 2P, 9); rows of weight 0 are zero
    hn = np.linalg.svd(a)[2][:, -1].reshape(-1, 3, 3)
    h = invert_3x3(td) @ hn @ ts
    with np.errstate(invalid="ignore", divide="ignore"):
        h = h / h[:, 2:3, 2:3]
    h[used.sum(axis=1) < 4] = np.nan
    return h


def _masked_normalise(points: np.ndarray, weight: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Similarity (N, 3, 3) moving the weighted centroid to 0 and weighted mean distance to sqrt(2), and
    the points mapped by it (points of weight 0 become 0 after weighting by the caller); count (N,) is
    the sum of the weights."""
    total = np.where(count > 0, count, 1.0)
    centre = (points * weight[..., None]).sum(axis=1) / total[:, None]
    spread = (np.linalg.norm(points - centre[:, None], axis=2) * weight).sum(axis=1) / total
    scale = np.sqrt(2.0) / np.maximum(spread, 1e-12)
    t = np.zeros((len(points), 3, 3))
    t[:, 0, 0] = t[:, 1, 1] = scale
    t[:, :2, 2] = -scale[:, None] * centre
    t[:, 2, 2] = 1.0
    return t, (points - centre[:, None]) * scale[:, None, None]


#: `auto_localizer_scale` measures the markers' size when there are at least this many
AUTO_MIN_MARKERS = 8


def marker_side_px(points_px: np.ndarray) -> np.ndarray:
    """(N,) the side of each marker of points_px (N, 5, 2) (centre, TL, TR, BL, BR): the square root
    of the area of its corner quadrilateral, in the points' pixels."""
    corners = np.asarray(points_px, np.float64)[:, [1, 2, 4, 3]]  # TL, TR, BR, BL: around the marker
    x, y = corners[..., 0], corners[..., 1]
    area = 0.5 * np.abs((x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1))
    return np.sqrt(area)


def auto_localizer_scale(points_px: np.ndarray, first_scale: float, marker_px: float,
                         min_markers: int = AUTO_MIN_MARKERS) -> float:
    """The localizer scale that makes the median side of the markers `points_px` (N, 5, 2), found at
    `first_scale` and given in full-resolution pixels, `marker_px` pixels: at most 1 (an enlarged
    image adds no detail and costs the square) and at least 1/16; `first_scale` when fewer than
    `min_markers` markers were found (too few to measure)."""
    if len(points_px) < min_markers:
        return first_scale
    return float(np.clip(marker_px / np.median(marker_side_px(points_px)), 1 / 16, 1.0))
