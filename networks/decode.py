"""Marker Localizer inference (cells -> markers in image pixels) and its border-duplicated targets.

The localizer predicts, for every 8 x 8 cell, whether a marker centre lies in it and the marker's five
localization points relative to the cell's top-left corner.  A centre within about a pixel of a cell
border is ambiguous: noise, blur or a sub-pixel shift moves it to the neighbouring cell.  The
reference handles this by "duplication of predictions within 1 pixel of a cell border to the
neighbouring cell with adjusted offsets", which we implement in two halves:

* training (`duplicate_border_targets`): a marker whose centre lies within `margin_px` of a cell
  border is also written into the neighbouring cell(s) across that border (the diagonal one too at
  a corner), with its ten offsets shifted by one cell so they still point at the same image pixels.
  The network thus learns to fire in both cells, and neither cell is taught "no marker" for it.
* inference (`decode_localizer`): every cell whose presence probability exceeds the threshold
  yields a marker at absolute pixels (cell corner + offsets); a marker seen from two cells appears
  twice at nearly the same centre, and non-maximum suppression by centre distance (`nms`) keeps the
  more confident one.

So a marker near a border is found whichever side its centre falls on, and reported once.
Pixel coordinates are continuous (x right, y down, pixel centres at integer + 0.5); cell (row i,
col j) covers x in [j * cell, (j + 1) * cell) and y in [i * cell, (i + 1) * cell).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

from networks.models import CELL, NUM_POINTS

#: Default NMS radius in pixels: below the distance between two markers' centres (one marker
#: apart: 11-23 px in the 512 px renders, p5-p95) and above the spread of a duplicated marker's two
#: predictions of the same centre.  Larger radii (6-10 px, or 0.4-0.6 of the predicted marker's size)
#: traded recall for precision at the same F1 on a trained localizer.
NMS_RADIUS_PX = 4.0

_CHANNELS = 1 + 2 * NUM_POINTS


def decode_localizer(output: torch.Tensor, threshold: float = 0.5, cell: int = CELL,
                     nms_radius_px: float = NMS_RADIUS_PX) -> list[tuple[np.ndarray, np.ndarray]]:
    """Markers from a `MarkerLocalizer` output.

    output: (B, 11, h, w) raw output (presence logit, ten offsets in pixels from the cell corner).
    Returns one (points_px float32 (N, 5, 2), score float32 (N,)) per image: absolute image pixels of
    centre, TL, TR, BL, BR and the presence probability, sorted by decreasing score, after
    thresholding sigmoid(presence) > `threshold` and `nms` with `nms_radius_px`.
    """
    if output.ndim != 4 or output.shape[1] != _CHANNELS:
        raise ValueError(f"decode_localizer: expected a (B, {_CHANNELS}, h, w) localizer output, "
                         f"got {tuple(output.shape)}")
    with torch.no_grad():
        cells = output.detach().permute(0, 2, 3, 1).float()
        probability = torch.sigmoid(cells[..., 0])
        image, row, col = torch.nonzero(probability > threshold, as_tuple=True)  # image-major order
        corner = torch.stack([col, row], dim=-1).to(cells.dtype) * cell
        points = cells[image, row, col, 1:].reshape(-1, NUM_POINTS, 2) + corner[:, None, :]
        score = probability[image, row, col]
    points, score, image = points.cpu().numpy(), score.cpu().numpy(), image.cpu().numpy()
    bounds = np.concatenate([[0], np.cumsum(np.bincount(image, minlength=output.shape[0]))])
    result = []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        keep = nms(points[start:stop], score[start:stop], nms_radius_px)
        result.append((points[start:stop][keep].astype(np.float32), score[start:stop][keep].astype(np.float32)))
    return result


def nms(points_px: np.ndarray, score: np.ndarray, radius_px: float) -> np.ndarray:
    """Greedy non-maximum suppression by centre distance.

    points_px: (N, 5, 2) (only the centre, [:, 0], is used); score: (N,).  A marker is dropped when a
    kept marker of higher score (ties: lower index) has its centre within `radius_px` (inclusive).
    Returns the kept indices (int64), by decreasing score.

    Vectorised: the greedy result is the unique fixed point of "kept = not suppressed by a kept
    better neighbour" over the pairs within the radius (a k-d tree finds them); iterating that map
    from "all kept" settles it after (longest chain of better neighbours + 1) passes.
    """
    points = np.asarray(points_px, dtype=np.float64)
    score = np.asarray(score, dtype=np.float64)
    if points.ndim != 3 or points.shape[1:] != (NUM_POINTS, 2) or score.shape != points.shape[:1]:
        raise ValueError(f"nms: expected points (N, {NUM_POINTS}, 2) and score (N,), got {points.shape} and {score.shape}")
    if not np.isfinite(points[:, 0]).all():
        raise ValueError("nms: marker centres must be finite")
    n = len(score)
    order = np.argsort(-score, kind="stable")
    if n < 2:
        return order.astype(np.int64)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    pairs = cKDTree(points[:, 0]).query_pairs(radius_px, output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    better = np.where(rank[a] < rank[b], a, b)
    worse = a + b - better
    keep = np.ones(n, dtype=bool)
    while True:
        suppressed = np.zeros(n, dtype=bool)
        suppressed[worse[keep[better]]] = True
        if np.array_equal(~suppressed, keep):
            return order[keep[order]].astype(np.int64)
        keep = ~suppressed


def duplicate_border_targets(cells: np.ndarray | torch.Tensor, margin_px: float = 1.0, cell: int = CELL
                             ) -> np.ndarray | torch.Tensor:
    """Localizer targets with every marker near a cell border also written to the neighbouring cell(s).

    cells: (h, w, 11) or (B, h, w, 11) float targets (`assets.pattern.observation.localizer_targets`:
    presence, then (x, y) of centre, TL, TR, BL, BR relative to the cell corner, NaN off the fabric),
    numpy or torch.  A marker whose centre is within `margin_px` of its cell's left / right / top /
    bottom border (x <= margin, x >= cell - margin, likewise y) is copied to the neighbour across that
    border, and to the diagonal neighbour when it is near two borders; the copy's offsets are shifted
    by -/+ `cell` so they address the same pixels (NaN stays NaN).  A copy never replaces a cell that
    holds its own marker, nor leaves the grid; where copies compete for one cell, the one whose
    centre is nearest to that cell wins (ties: the first in row-major order).
    Returns a new array of the same shape and type (float32).
    """
    if torch.is_tensor(cells):
        result = duplicate_border_targets(cells.detach().cpu().numpy(), margin_px, cell)
        return torch.from_numpy(result).to(cells.device)
    source = np.asarray(cells, dtype=np.float32)
    if source.ndim not in (3, 4) or source.shape[-1] != _CHANNELS:
        raise ValueError(f"duplicate_border_targets: expected cells (h, w, {_CHANNELS}) or (B, h, w, {_CHANNELS}), "
                         f"got {source.shape}")
    if not 0 <= margin_px < cell / 2:
        raise ValueError(f"duplicate_border_targets: margin_px must be in [0, {cell / 2}), got {margin_px}")
    h, w = source.shape[-3:-1]
    src = source.reshape(-1, h, w, _CHANNELS)
    out = src.copy()
    image, row, col = np.nonzero(src[..., 0] > 0.5)
    centre = src[image, row, col, 1:3]
    with np.errstate(invalid="ignore"):
        step = np.where(centre <= margin_px, -1, np.where(centre >= cell - margin_px, 1, 0))  # (M, 2) x, y
    # candidate moves: across the x border, across the y border, diagonally
    move = np.concatenate([step * [1, 0], step * [0, 1], step])
    wanted = np.concatenate([step[:, 0] != 0, step[:, 1] != 0, (step != 0).all(axis=1)])
    which = np.tile(np.arange(len(image)), 3)
    move, which = move[wanted], which[wanted]
    b, i, j = image[which], row[which] + move[:, 1], col[which] + move[:, 0]
    inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
    move, which, b, i, j = move[inside], which[inside], b[inside], i[inside], j[inside]
    free = src[b, i, j, 0] <= 0.5
    move, which, b, i, j = move[free], which[free], b[free], i[free], j[free]
    shifted = centre[which] - move * cell  # centre relative to the target cell
    distance = np.hypot(*np.maximum(np.maximum(-shifted, shifted - cell), 0).T)
    key = (b * h + i) * w + j
    chosen = np.lexsort((which, distance, key))
    _, first = np.unique(key[chosen], return_index=True)
    chosen = chosen[first]
    b, i, j, which, move = b[chosen], i[chosen], j[chosen], which[chosen], move[chosen]
    out[b, i, j, 0] = 1.0
    offset = np.tile(move * cell, NUM_POINTS).astype(np.float32)  # (n, 10) x, y per point
    out[b, i, j, 1:] = src[image[which], row[which], col[which], 1:] - offset
    return out.reshape(source.shape)
