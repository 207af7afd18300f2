"""Closed polylines: where one crosses or touches itself (sewing-pattern panels, printed panel outlines)."""

from __future__ import annotations

import numpy as np

#: points closer than this fraction of the polyline's size to a segment's line are on it
ON_LINE = 1e-9
#: candidate segment pairs tested at once: memory stays bounded for outlines of any length
_PAIRS_PER_BLOCK = 1 << 22


def first_crossing(points: np.ndarray) -> tuple[int, int] | None:
    """First pair (i, j), i < j, of non-adjacent segments of the closed polyline (P, 2) that cross or
    touch, or None; segment i runs points[i] -> points[i + 1].  A point within `ON_LINE` of the
    polyline's size from a segment's line counts as on it: the orientation of exactly collinear samples
    (two pieces of one straight edge) is float rounding, about 1e-17 m to either side of the line, and
    no evidence of a crossing."""
    n = len(points)
    a, b = points, np.roll(points, -1, axis=0)
    tolerance = ON_LINE * float(np.ptp(points, axis=0).max())
    # only segments whose bounding boxes overlap can meet: a few per segment instead of all n^2 pairs
    low, high = np.minimum(a, b) - tolerance, np.maximum(a, b) + tolerance
    (low_x, low_y), (high_x, high_y) = low.T, high.T

    def side_and_on(k: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Side of segment k's line each point p is on (-1, 0 on the line, 1), and whether p is on the
        segment itself; k (m,), p (m, 2)."""
        direction, offset = b[k] - a[k], p - a[k]
        length = np.linalg.norm(direction, axis=1)
        distance = (direction[:, 0] * offset[:, 1] - direction[:, 1] * offset[:, 0]) / length
        along = np.einsum("md,md->m", direction, offset) / length
        side = np.where(np.abs(distance) <= tolerance, 0.0, np.sign(distance))
        return side, (side == 0) & (along >= -tolerance) & (along <= length + tolerance)

    block = max(1, _PAIRS_PER_BLOCK // max(n, 1))
    for start in range(0, n, block):  # blocks of rows of the n x n pair matrix, in row-major order
        rows = slice(start, start + block)
        overlap = ((low_x[rows, None] <= high_x) & (low_x <= high_x[rows, None])
                   & (low_y[rows, None] <= high_y) & (low_y <= high_y[rows, None]))
        i, j = np.nonzero(overlap)
        i += start
        keep = (j >= i + 2) & ~((i == 0) & (j == n - 1))  # neither adjacent segments nor the segment itself
        i, j = i[keep], j[keep]
        (side_ja, on_ja), (side_jb, on_jb) = side_and_on(i, a[j]), side_and_on(i, b[j])
        (side_ia, on_ia), (side_ib, on_ib) = side_and_on(j, a[i]), side_and_on(j, b[i])
        hit = ((side_ja * side_jb < 0) & (side_ia * side_ib < 0)) | on_ja | on_jb | on_ia | on_ib
        first = np.flatnonzero(hit)
        if len(first):
            return int(i[first[0]]), int(j[first[0]])
    return None
