"""Rendering the two-level pattern to images, exactly and at any scale.

Every feature of the pattern is an axis-aligned rectangle in grid coordinates (u = column, v = row,
in pitches; see `spec`): code-coloured cells, and thin lines through every crosspoint row and column
(thicker on marker borders).  So each pixel's colour is computed exactly as the area average over the
pixel (a box filter), separably: a sparse matrix of 1D overlaps per axis gives the code-colour
fraction ``f = Wv @ cells @ Wu.T`` and the line coverages ``lu``, ``lv``; horizontal and vertical
lines together cover ``L = lu + lv - lu lv`` of the pixel.  The colour is then
``(1 - L) * lerp(background, code, f) + L * line``.  This is exact at 300 DPI for printing and at a
few pixels per cell for reference textures and previews, costs O(pixels), and runs in row strips so
that memory stays bounded for a 1.5 m fabric at 300 DPI (17,700 px square).

Image convention: pixel (row r, col c) covers [c, c + 1] x [r, r + 1] in continuous image
coordinates, so its centre is at (c + 0.5, r + 0.5) (DESIGN.md); row 0 is the top of the fabric.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import scipy.sparse as sp
from PIL import Image

from assets.fileio import atomic_path
from assets.polylines import first_crossing
from assets.pattern.spec import PatternSpec
from assets.pattern.table import MarkerTable

_METRES_PER_INCH = 0.0254
#: the largest image a CLI renders unless told otherwise (`--max-pixels`): the default 32 x 32 marker
#: fabric is 18,142 px square (329 Mpx) at 300 DPI and 1.32 Gpx at a fine print's 600 DPI, a garment
#: sheet at 300 DPI under 300 Mpx; an image costs 3 bytes a pixel, about twice over while it is written
MAX_PIXELS = 1_500_000_000
_STRIP_ROWS = 256
_SUBPIXEL_BITS = 8  # OpenCV polygon coordinates are fixed point with this many fractional bits


def box_weights(edges: np.ndarray, seg_lo: np.ndarray, seg_hi: np.ndarray) -> sp.csr_matrix:
    """Fraction of each pixel interval covered by each segment.

    edges (P+1,) increasing pixel edges; seg_lo, seg_hi (S,) sorted, disjoint segments, all in the
    same 1D unit.  Returns (P, S) CSR float32 with entry (p, s) = |[e_p, e_p+1] & [lo_s, hi_s]| /
    (e_p+1 - e_p).
    """
    lo, hi = edges[:-1], edges[1:]
    first = np.searchsorted(seg_hi, lo, side="right")
    count = np.maximum(np.searchsorted(seg_lo, hi, side="left") - first, 0)
    rows = np.repeat(np.arange(len(lo)), count)
    offsets = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    cols = np.repeat(first, count) + offsets
    overlap = np.minimum(hi[rows], seg_hi[cols]) - np.maximum(lo[rows], seg_lo[cols])
    weights = (overlap / (hi - lo)[rows]).astype(np.float32)
    return sp.csr_matrix((weights, (rows, cols)), shape=(len(lo), len(seg_lo)))


def line_coverage(spec: PatternSpec, edges: np.ndarray, first: int, last: int) -> np.ndarray:
    """(P,) fraction of each pixel covered by grid lines at integer positions first..last."""
    index = np.arange(first, last + 1)
    width = np.where(index % spec.cells_per_side == 0, spec.border_line_width_mm, spec.line_width_mm)
    half = width / spec.pitch_mm / 2
    weights = box_weights(edges, index - half, index + half)
    return np.asarray(weights.sum(axis=1), dtype=np.float32).ravel()


def cell_weights(edges: np.ndarray, first: int, count: int) -> sp.csr_matrix:
    """(P, count) overlap of pixels with cells [first + k, first + k + 1]."""
    lo = np.arange(first, first + count, dtype=np.float64)
    return box_weights(edges, lo, lo + 1)


def composite(spec: PatternSpec, fill: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Code fraction `fill` and line coverage `lines` (same shape (...)) -> sRGB (..., 3) uint8.

    The colour is bg + fill (code - bg), then lines of the line colour over it; expanded, an affine
    map of (fill, lines, fill * lines), done in one `cv2.transform` pass, in float32 when both inputs
    are float32 (as the colour arithmetic has always been for them), else in float64."""
    dtype = np.result_type(np.asarray(fill).dtype, np.asarray(lines).dtype, np.float32)
    fill = np.asarray(fill, dtype=dtype)
    lines = np.broadcast_to(np.asarray(lines, dtype=dtype), fill.shape)
    if fill.size == 0:
        return np.zeros(fill.shape + (3,), dtype=np.uint8)
    bg = np.asarray(spec.background_rgb, dtype=dtype)
    code = np.asarray(spec.code_rgb, dtype=dtype)
    line = np.asarray(spec.line_rgb, dtype=dtype)
    affine = np.concatenate([np.stack([code - bg, line - bg, bg - code], axis=1), (bg + 0.5)[:, None]], axis=1)
    flat = (-1, fill.shape[-1]) if fill.ndim > 1 else (1, -1)
    f, l = fill.reshape(flat), np.ascontiguousarray(lines).reshape(flat)
    rgb = cv2.transform(cv2.merge([f, l, f * l]), affine)
    np.clip(rgb, 0, 255, out=rgb)
    return rgb.astype(np.uint8).reshape(fill.shape + (3,))


def fabric_cells(table: MarkerTable) -> np.ndarray:
    """(24 R, 24 C) uint8: 1 where a cell of the whole fabric is code-coloured."""
    spec = table.spec
    k = spec.cells_per_module
    cells = np.repeat(np.repeat(table.codes, k, axis=1), k, axis=2)  # (M, 24, 24)
    n = spec.cells_per_side
    return cells.reshape(spec.rows, spec.cols, n, n).transpose(0, 2, 1, 3).reshape(spec.rows * n, -1)


def render_grid_view(
    table: MarkerTable,
    u_edges: np.ndarray,
    v_edges: np.ndarray,
    polygons_px: Sequence[np.ndarray] = (),
    outline_px: int = 0,
    progress: bool = False,
) -> np.ndarray:
    """Render the fabric over an axis-aligned pixel grid.

    u_edges (W+1,), v_edges (H+1,): pixel edges in grid units (increasing).  If `polygons_px`
    ((K, 2) arrays in continuous image coordinates) are given, only their inside is printed and their
    outlines are drawn `outline_px` wide in the line colour (a cut line).  Returns (H, W, 3) uint8.
    """
    spec = table.spec
    cells = fabric_cells(table).astype(np.float32)
    grid_rows, grid_cols = spec.grid_shape
    wu = cell_weights(u_edges, 0, cells.shape[1])
    wv = cell_weights(v_edges, 0, cells.shape[0])
    lu = line_coverage(spec, u_edges, 0, grid_cols - 1)
    lv = line_coverage(spec, v_edges, 0, grid_rows - 1)
    height, width = len(v_edges) - 1, len(u_edges) - 1
    image = np.empty((height, width, 3), dtype=np.uint8)
    scale = 1 << _SUBPIXEL_BITS
    polys = [np.round((np.asarray(p, np.float64) - 0.5) * scale).astype(np.int32) for p in polygons_px]
    background = np.asarray(spec.background_rgb, dtype=np.uint8)
    starts = range(0, height, _STRIP_ROWS)
    from tqdm import tqdm  # here, not at import: Blender's own Python may lack it
    for r0 in tqdm(starts, desc="render", unit="strip", disable=not progress):
        r1 = min(r0 + _STRIP_ROWS, height)
        fill = np.asarray(wu @ np.asarray(wv[r0:r1] @ cells).T).T
        lines = lv[r0:r1, None] + lu[None, :] - lv[r0:r1, None] * lu[None, :]
        strip = composite(spec, fill, lines)
        if polys:
            shifted = [p - np.array([0, r0 * scale], np.int32) for p in polys]
            mask = np.zeros((r1 - r0, width), dtype=np.uint8)
            cv2.fillPoly(mask, shifted, 255, cv2.LINE_AA, _SUBPIXEL_BITS)
            alpha = mask[..., None].astype(np.float32) / 255.0
            strip = (background + alpha * (strip.astype(np.float32) - background) + 0.5).astype(np.uint8)
            if outline_px > 0:
                colour = tuple(int(c) for c in spec.line_rgb)
                cv2.polylines(strip, shifted, True, colour, outline_px, cv2.LINE_AA, _SUBPIXEL_BITS)
        image[r0:r1] = strip
    return image


def pixels_per_metre(dpi: float) -> float:
    return dpi / _METRES_PER_INCH


def region_shape(bounds_xy: tuple[float, float, float, float], dpi: float) -> tuple[int, int]:
    """(H, W) pixels of a region at `dpi`; the image extends to whole pixels right and down."""
    xmin, ymin, xmax, ymax = bounds_xy
    ppm = pixels_per_metre(dpi)
    return math.ceil((ymax - ymin) * ppm - 1e-6), math.ceil((xmax - xmin) * ppm - 1e-6)


def xy_to_pixel(xy: np.ndarray, bounds_xy: tuple[float, float, float, float], dpi: float) -> np.ndarray:
    """pattern_xy (..., 2) metres -> continuous image coordinates (..., 2) (x right, y down; pixel
    centres at +0.5) in an image of `bounds_xy` rendered at `dpi`."""
    xy = np.asarray(xy, dtype=np.float64)
    ppm = pixels_per_metre(dpi)
    return np.stack([(xy[..., 0] - bounds_xy[0]) * ppm, (bounds_xy[3] - xy[..., 1]) * ppm], axis=-1)


def render_region(
    table: MarkerTable,
    bounds_xy: tuple[float, float, float, float] | None = None,
    dpi: float = 300.0,
    polygons_xy: Sequence[np.ndarray] = (),
    outline_mm: float = 0.5,
    progress: bool = False,
) -> np.ndarray:
    """The fabric at exact physical scale: one pixel is 1/dpi inch.

    bounds_xy: (xmin, ymin, xmax, ymax) in pattern_xy metres, default the whole marker grid; pixel
    (0, 0) starts at (xmin, ymax).  polygons_xy: optional panel outlines ((K, 2) metres) that limit
    the print to their inside, with an `outline_mm` cut line.  Returns (H, W, 3) uint8.
    """
    spec = table.spec
    if bounds_xy is None:
        bounds_xy = spec.fabric_bounds
    if not (bounds_xy[2] > bounds_xy[0] and bounds_xy[3] > bounds_xy[1]):
        raise ValueError(f"empty region {bounds_xy}: need xmin < xmax and ymin < ymax")
    if not dpi > 0:
        raise ValueError(f"dpi must be > 0, got {dpi}")
    height, width = region_shape(bounds_xy, dpi)
    step = 1.0 / pixels_per_metre(dpi)
    x_edges = bounds_xy[0] + np.arange(width + 1) * step
    y_edges = bounds_xy[3] - np.arange(height + 1) * step
    u_edges = spec.xy_to_uv(np.stack([x_edges, np.full_like(x_edges, bounds_xy[3])], axis=1))[:, 0]
    v_edges = spec.xy_to_uv(np.stack([np.full_like(y_edges, bounds_xy[0]), y_edges], axis=1))[:, 1]
    polygons_px = [xy_to_pixel(p, bounds_xy, dpi) for p in validate_polygons(spec, polygons_xy)]
    outline_px = max(1, round(outline_mm * 1e-3 * pixels_per_metre(dpi))) if polygons_px else 0
    return render_grid_view(table, u_edges, v_edges, polygons_px, outline_px, progress)


def validate_polygons(spec: PatternSpec, polygons_xy: Sequence[np.ndarray], source: str = "polygons") -> list[np.ndarray]:
    """Check panel outlines: each (K >= 3, 2) finite metres inside the fabric, not crossing itself;
    return float64 copies."""
    xmin, ymin, xmax, ymax = spec.fabric_bounds
    out = []
    for i, polygon in enumerate(polygons_xy):
        p = np.asarray(polygon, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3 or not np.isfinite(p).all():
            raise ValueError(f"{source}[{i}]: expected a list of at least 3 finite [x, y] points")
        tol = 1e-9
        if p[:, 0].min() < xmin - tol or p[:, 0].max() > xmax + tol or p[:, 1].min() < ymin - tol or p[:, 1].max() > ymax + tol:
            raise ValueError(
                f"{source}[{i}]: extends outside the fabric's marker grid "
                f"[{xmin:.4f}, {xmax:.4f}] x [{ymin:.4f}, {ymax:.4f}] m; enlarge rows/cols or move origin_xy"
            )
        crossing = first_crossing(p)
        if crossing is not None:
            raise ValueError(f"{source}[{i}]: the outline crosses or touches itself (segments from points "
                             f"{crossing[0]} and {crossing[1]}); a panel is one simple polygon")
        out.append(p)
    return out


def panel_bounds(polygons_xy: Sequence[np.ndarray], margin_m: float) -> tuple[float, float, float, float]:
    """Bounding box of all polygons, grown by `margin_m`."""
    points = np.concatenate([np.asarray(p, np.float64) for p in polygons_xy])
    lo, hi = points.min(axis=0) - margin_m, points.max(axis=0) + margin_m
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def write_png(path: str | Path, image: np.ndarray, dpi: float, compress_level: int = 6) -> None:
    """Write an (H, W, 3) uint8 image as PNG with its DPI in the pHYs chunk, atomically."""
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", dpi=(dpi, dpi), compress_level=compress_level)
