"""Planar projective geometry on plain arrays: homography fitting and application, batched."""

from __future__ import annotations

import numpy as np


def apply_homography(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (..., P, 2) by homographies (..., 3, 3) (broadcast over leading axes)."""
    points = np.asarray(points, dtype=np.float64)
    ones = np.ones(points.shape[:-1] + (1,))
    mapped = np.concatenate([points, ones], axis=-1) @ np.swapaxes(np.asarray(h, np.float64), -1, -2)
    return mapped[..., :2] / mapped[..., 2:3]


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
    s = apply_homography(ts[:, None], src[:, :, None])[:, :, 0]
    d = apply_homography(td[:, None], dst[:, :, None])[:, :, 0]
    x, y = s[..., 0], s[..., 1]
    u, v = d[..., 0], d[..., 1]
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([-x, -y, -one, zero, zero, zero, u * x, u * y, u], axis=-1)
    rows_v = np.stack([zero, zero, zero, -x, -y, -one, v * x, v * y, v], axis=-1)
    a = np.concatenate([rows_u, rows_v], axis=1)  # (N, 2P, 9)
    hn = np.linalg.svd(a)[2][:, -1].reshape(-1, 3, 3)
    h = np.linalg.inv(td) @ hn @ ts
    h /= h[:, 2:3, 2:3]
    return h[0] if single else h
