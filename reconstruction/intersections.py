"""Intersecting triangle pairs of a triangle mesh: how the post-processing measures self-intersection,
and `untangle`, which refills the regions around them.

Two triangles intersect when an edge of one pierces the interior of the other (in general position
every intersection of two non-coplanar triangles has such an edge).  Pairs that share a vertex (the
mesh's own neighbours) are never counted, and coplanar overlaps are not detected (they have measure
zero for captured or simulated cloth).

Broad phase: bounding spheres about centroids; a triangle more than twice the median size is cut into
similar pieces no larger than that, so one k-d tree query at twice the largest piece radius finds
every candidate however uneven the mesh (long slivers make many pieces: the placement-hint pose of a
garment, with its seams stretched across the body, is slow to test); then the axis-aligned boxes
must overlap.  Narrow phase: six exact segment-triangle tests per candidate pair (signed volumes),
vectorised in batches.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

_BATCH = 1 << 19  # candidate pairs per narrow-phase batch (memory, not speed)
_REGULAR_FACTOR = 2.0  # triangles larger than this many median radii are cut into pieces


def intersecting_pairs(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Pairs of faces that intersect and share no vertex.

    positions: (V, 3) float, vertex positions (any unit; metres here).
    faces: (F, 3) int, triangles (rows of positions).
    Returns (K, 2) int64 face index pairs, i < j in each row, rows sorted.
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions: expected (V, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces: expected (F, 3), got {faces.shape}")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(positions)):
        raise ValueError(f"faces: indices must lie in [0, {len(positions)}), got [{faces.min()}, {faces.max()}]")
    if not np.isfinite(positions).all():
        raise ValueError("positions: expected finite values")
    if len(faces) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    corners = positions[faces]  # (F, 3, 3)
    candidates = _candidate_pairs(corners)
    shared = (faces[candidates[:, 0], :, None] == faces[candidates[:, 1], None, :]).any(axis=(1, 2))
    candidates = candidates[~shared]
    hits = np.zeros(len(candidates), dtype=bool)
    for start in range(0, len(candidates), _BATCH):
        pair = candidates[start : start + _BATCH]
        hits[start : start + _BATCH] = triangles_intersect(corners[pair[:, 0]], corners[pair[:, 1]])
    return candidates[hits]


def count_intersections(positions: np.ndarray, faces: np.ndarray) -> int:
    """Number of intersecting face pairs that share no vertex (see `intersecting_pairs`)."""
    return len(intersecting_pairs(positions, faces))


def untangle(positions: np.ndarray, faces: np.ndarray, frozen: np.ndarray, rings: int = 2,
             rounds: int = 4) -> tuple[np.ndarray, int]:
    """Remove intersections from a shape by refilling the regions around them.

    Each round finds the intersecting pairs; the vertices of their faces, grown by `rings` rings per
    round so far, are refilled by harmonic interpolation (uniform Laplacian, the rest of the mesh held
    fixed): a patch pushed through another layer is pulled back onto the surface around it.  Vertices
    in `frozen` (V,) bool (captured ones) are held in the first round and freed after it.

    positions (V, 3), faces (F, 3).  Returns the shape (V, 3) and the number of intersecting pairs
    left after the last round (0 when it succeeded)."""
    x = np.asarray(positions, dtype=np.float64).copy()
    faces = np.asarray(faces, dtype=np.int64)
    frozen = np.asarray(frozen, dtype=bool)
    n = len(x)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adjacency = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64).tocsr()
    laplacian = (sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
    pairs = intersecting_pairs(x, faces)
    for round_index in range(rounds):
        if len(pairs) == 0:
            break
        region = np.zeros(n, dtype=bool)
        region[faces[pairs].ravel()] = True
        for _ in range(rings * (round_index + 1)):
            region |= (adjacency @ region.astype(np.float64)) > 0
        free = np.flatnonzero(region & ~frozen if round_index == 0 else region)
        fixed = np.setdiff1d(np.arange(n), free)
        # a free component without fixed neighbours keeps its mean (the small identity term)
        system = laplacian[free][:, free] + sp.identity(len(free)) * 1e-6
        rhs = -(laplacian[free][:, fixed] @ x[fixed]) + 1e-6 * x[free]
        x[free] = spla.splu(system.tocsc()).solve(np.asarray(rhs))
        pairs = intersecting_pairs(x, faces)
    return x, len(pairs)


def triangles_intersect(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Whether triangle pairs intersect: first, second (N, 3, 3) corners -> (N,) bool.

    True when an edge of either triangle crosses the other's plane strictly between its endpoints
    and passes strictly inside the other triangle."""
    hit = np.zeros(len(first), dtype=bool)
    for a, b in ((first, second), (second, first)):
        for k in range(3):
            hit |= _segment_crosses_triangle(a[:, k], a[:, (k + 1) % 3], b)
    return hit


def _segment_crosses_triangle(p: np.ndarray, q: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Segments p -> q (N, 3) against triangles (N, 3, 3): (N,) bool, strict crossing of the interior."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    normal = np.cross(b - a, c - a)
    side_p = np.einsum("nd,nd->n", normal, p - a)
    side_q = np.einsum("nd,nd->n", normal, q - a)
    crosses_plane = side_p * side_q < 0.0
    direction = q - p
    # signed volumes of (p, q, edge): the line p-q passes inside when all three share a sign
    s_ab = np.einsum("nd,nd->n", np.cross(a - p, b - p), direction)
    s_bc = np.einsum("nd,nd->n", np.cross(b - p, c - p), direction)
    s_ca = np.einsum("nd,nd->n", np.cross(c - p, a - p), direction)
    inside = ((s_ab > 0) & (s_bc > 0) & (s_ca > 0)) | ((s_ab < 0) & (s_bc < 0) & (s_ca < 0))
    return crosses_plane & inside


def _candidate_pairs(corners: np.ndarray) -> np.ndarray:
    """Face pairs (K, 2) int64, i < j, whose bounding spheres (or those of their pieces) and boxes
    overlap; corners (F, 3, 3).

    A triangle larger than the regular radius (twice the median) is cut into n x n similar pieces,
    each of radius at most the regular one, so one k-d tree query with a fixed radius finds every
    pair however uneven the mesh is."""
    centre = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1)
    regular_radius = max(_REGULAR_FACTOR * float(np.median(radius)), 1e-12)
    pieces = np.maximum(np.ceil(radius / regular_radius), 1).astype(np.int64)
    owner, piece_centre = [np.arange(len(corners))[pieces == 1]], [centre[pieces == 1]]
    for n in np.unique(pieces[pieces > 1]):  # a few distinct sizes
        which = np.flatnonzero(pieces == n)
        uv = _piece_centres(int(n))  # (n^2, 2)
        tri = corners[which]
        points = tri[:, None, 0] + uv[None, :, :1] * (tri[:, None, 1] - tri[:, None, 0]) \
            + uv[None, :, 1:] * (tri[:, None, 2] - tri[:, None, 0])
        owner.append(np.repeat(which, len(uv)))
        piece_centre.append(points.reshape(-1, 3))
    owner, piece_centre = np.concatenate(owner), np.concatenate(piece_centre)
    piece_radius = float((radius / pieces).max())
    near = cKDTree(piece_centre).query_pairs(2.0 * piece_radius, output_type="ndarray")
    pairs = np.sort(owner[near], axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    if (pieces > 1).any():
        pairs = np.unique(pairs, axis=0)  # pieces of one triangle find the same neighbour
    i, j = pairs[:, 0], pairs[:, 1]
    low, high = corners.min(axis=1), corners.max(axis=1)
    boxes = ((low[i] <= high[j]) & (low[j] <= high[i])).all(axis=1)
    return pairs[boxes]


def _piece_centres(n: int) -> np.ndarray:
    """Centroids (n^2, 2) of the n x n similar pieces of a triangle, as weights of corners 1 and 2."""
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b = a.ravel().astype(np.float64), b.ravel().astype(np.float64)
    upright = a + b <= n - 1
    flipped = a + b <= n - 2
    centres = np.concatenate([np.stack([a[upright] + 1 / 3, b[upright] + 1 / 3], 1),
                              np.stack([a[flipped] + 2 / 3, b[flipped] + 2 / 3], 1)])
    return centres / n
