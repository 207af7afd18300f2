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

    # candidate pairs by a sweep along x: with the segments sorted by their low x, segment r's x range
    # overlaps exactly those after it whose low x is at most its high x (no n x n matrix: the outlines
    # of a pattern's panels have thousands of points, and drafting validates every panel)
    order = np.argsort(low_x, kind="stable")
    end = np.searchsorted(low_x[order], high_x[order], side="right")
    count = np.maximum(end - np.arange(n) - 1, 0)
    first_pair = np.cumsum(count) - count  # of each r, in the flat list of all candidate pairs
    best = None
    r0 = 0
    while r0 < n:  # blocks of consecutive r with about _PAIRS_PER_BLOCK candidate pairs
        r1 = max(r0 + 1, int(np.searchsorted(first_pair, first_pair[r0] + _PAIRS_PER_BLOCK)))
        counts = count[r0:r1]
        r = np.repeat(np.arange(r0, r1), counts)
        s = r + 1 + np.arange(len(r)) - np.repeat(first_pair[r0:r1] - first_pair[r0], counts)
        i, j = np.minimum(order[r], order[s]), np.maximum(order[r], order[s])
        keep = ((low_y[i] <= high_y[j]) & (low_y[j] <= high_y[i])
                & (j >= i + 2) & ~((i == 0) & (j == n - 1)))  # neither adjacent segments nor the segment itself
        i, j = i[keep], j[keep]
        (side_ja, on_ja), (side_jb, on_jb) = side_and_on(i, a[j]), side_and_on(i, b[j])
        (side_ia, on_ia), (side_ib, on_ib) = side_and_on(j, a[i]), side_and_on(j, b[i])
        hit = ((side_ja * side_jb < 0) & (side_ia * side_ib < 0)) | on_ja | on_jb | on_ia | on_ib
        if hit.any():
            k = np.flatnonzero(hit)[np.argmin(i[hit].astype(np.int64) * n + j[hit])]  # the first in (i, j) order
            if best is None or (i[k], j[k]) < best:
                best = (int(i[k]), int(j[k]))
        r0 = r1
    return best
