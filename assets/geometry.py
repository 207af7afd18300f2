"""Planar geometry on plain arrays: homography fitting and application (batched), and exact point
location in a planar triangle mesh."""

from __future__ import annotations

import numpy as np


def apply_homography(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (..., P, 2) by homographies (..., 3, 3) (broadcast over leading axes)."""
    points = np.asarray(points, dtype=np.float64)
    ones = np.ones(points.shape[:-1] + (1,))
    mapped = np.concatenate([points, ones], axis=-1) @ np.swapaxes(np.asarray(h, np.float64), -1, -2)
    return mapped[..., :2] / mapped[..., 2:3]


def invert_3x3(m: np.ndarray) -> np.ndarray:
    """Inverses of (..., 3, 3) matrices in closed form (adjugate / determinant): NaN where singular.

    For the many small homographies of one batch this is faster than `np.linalg.inv`, and it calls
    no LAPACK, whose OpenBLAS threads stall for milliseconds after PyTorch's CPU threads have run."""
    m = np.asarray(m, dtype=np.float64)
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    adjugate = np.stack([
        np.stack([e * i - f * h, c * h - b * i, b * f - c * e], axis=-1),
        np.stack([f * g - d * i, a * i - c * g, c * d - a * f], axis=-1),
        np.stack([d * h - e * g, b * g - a * h, a * e - b * d], axis=-1)], axis=-2)
    det = a * adjugate[..., 0, 0] + b * adjugate[..., 1, 0] + c * adjugate[..., 2, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return adjugate / np.where(det == 0, np.nan, det)[..., None, None]


def _normaliser(points: np.ndarray) -> np.ndarray:
    """(N, P, 2) -> (N, 3, 3) similarity moving the centroid to 0 and the mean distance to sqrt(2)."""
    centre = points.mean(axis=1)
    spread = np.linalg.norm(points - centre[:, None], axis=2).mean(axis=1)
    scale = np.sqrt(2.0) / np.maximum(spread, 1e-12)
    t = np.zeros((len(points), 3, 3))
    t[:, 0, 0] = t[:, 1, 1] = scale
    t[:, :2, 2] = -scale[:, None] * centre
    t[:, 2, 2] = 1.0
    return t


def fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares homographies with ``dst ~ H src`` (normalised DLT).

    src (N, P, 2) or (P, 2), dst the same or (P, 2) shared by all N; P >= 4 points in general
    position.  Returns (N, 3, 3) (or (3, 3) for unbatched input) with H[2, 2] = 1.
    """
    src = np.asarray(src, dtype=np.float64)
    single = src.ndim == 2
    src = np.atleast_3d(src) if not single else src[None]
    dst = np.broadcast_to(np.asarray(dst, dtype=np.float64), src.shape)
    if src.shape[1] < 4:
        raise ValueError(f"fit_homography needs at least 4 point pairs, got {src.shape[1]}")
    ts, td = _normaliser(src), _normaliser(dst)
    s = src * ts[:, None, 0, :1] + ts[:, None, :2, 2]  # the normalisers are similarities: no division
    d = dst * td[:, None, 0, :1] + td[:, None, :2, 2]
    x, y = s[..., 0], s[..., 1]
    u, v = d[..., 0], d[..., 1]
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([-x, -y, -one, zero, zero, zero, u * x, u * y, u], axis=-1)
    rows_v = np.stack([zero, zero, zero, -x, -y, -one, v * x, v * y, v], axis=-1)
    a = np.concatenate([rows_u, rows_v], axis=1)  # (N, 2P, 9)
    # the least-squares null vector: the eigenvector of A^T A with the smallest eigenvalue (the last
    # right-singular vector of A).  A 9 x 9 eigenproblem per homography instead of the SVD of a 2P x 9
    # matrix: 10-40x faster for a batch (80 ms -> 2-5 ms for 1,350 markers), and with the points
    # normalised above A is well conditioned, so squaring its condition costs no accuracy that matters
    # (float64: about 1e-10 relative)
    normal = np.swapaxes(a, 1, 2) @ a
    hn = np.linalg.eigh(normal)[1][:, :, 0].reshape(-1, 3, 3)
    h = invert_3x3(td) @ hn @ ts
    h /= h[:, 2:3, 2:3]
    return h[0] if single else h


#: a point is inside a triangle when its smallest barycentric weight is at least -this
_INSIDE_TOLERANCE = 1e-9
#: points located per batch (bounds the memory of the candidate pairs)
_LOCATE_BATCH = 1 << 16


def locate_in_mesh(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact point location in a planar triangle mesh.

    vertices (V, 2), faces (F, 3) (one panel: faces must not overlap), points (N, 2).  Returns the
    face (N,) int64 containing each point (the one it is deepest inside where it lies on shared
    edges) or -1 when no face contains it, and barycentric weights (N, 3) (0 where -1).  Faces are
    bucketed in a uniform grid of about one face size, so every face containing a point is tested."""
    points = np.asarray(points, dtype=np.float64)
    tri = vertices[faces]  # (F, 3, 2)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    size = float(np.median((hi - lo).max(axis=1))) if len(faces) else 1.0
    pad = 1e-6 * size  # so a point on a face's edge, up to rounding, is in a cell of that face
    lo, hi = lo - pad, hi + pad
    origin = lo.min(axis=0) if len(faces) else np.zeros(2)
    first = np.floor((lo - origin) / size).astype(np.int64)
    last = np.floor((hi - origin) / size).astype(np.int64)
    grid_cols = int(last[:, 0].max()) + 1 if len(faces) else 1
    # (face, cell) pairs for every cell each face's bounding box touches, sorted by cell
    span = last - first + 1
    count = span[:, 0] * span[:, 1]
    owner = np.repeat(np.arange(len(faces)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    cell_x = first[owner, 0] + local % span[owner, 0]
    cell_y = first[owner, 1] + local // span[owner, 0]
    cell_key = cell_y * grid_cols + cell_x
    order = np.argsort(cell_key, kind="stable")
    cell_key, owner = cell_key[order], owner[order]

    face_out = np.full(len(points), -1, dtype=np.int64)
    bary_out = np.zeros((len(points), 3))
    for start in range(0, len(points), _LOCATE_BATCH):
        batch = points[start : start + _LOCATE_BATCH]
        cell = np.floor((batch - origin) / size).astype(np.int64)
        inside_grid = (cell >= 0).all(axis=1) & (cell[:, 0] < grid_cols)
        key = np.where(inside_grid, cell[:, 1] * grid_cols + cell[:, 0], -1)
        begin = np.searchsorted(cell_key, key, side="left")
        n = np.searchsorted(cell_key, key, side="right") - begin
        point = np.repeat(np.arange(len(batch)), n)
        candidate = owner[np.repeat(begin, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)]
        bary = barycentric(tri[candidate], batch[point])
        score = bary.min(axis=1)
        inside = score >= -_INSIDE_TOLERANCE
        point, candidate, bary, score = point[inside], candidate[inside], bary[inside], score[inside]
        best = np.lexsort((-score, point))
        _, keep = np.unique(point[best], return_index=True)
        best = best[keep]
        face_out[start + point[best]] = candidate[best]
        bary_out[start + point[best]] = bary[best]
    return face_out, bary_out




def barycentric(tri: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights (N, 3) of points (N, 2) in triangles (N, 3, 2)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    l1 = (v2[:, 0] * v1[:, 1] - v2[:, 1] * v1[:, 0]) / det
    l2 = (v0[:, 0] * v2[:, 1] - v0[:, 1] * v2[:, 0]) / det
    return np.stack([1 - l1 - l2, l1, l2], axis=1)


