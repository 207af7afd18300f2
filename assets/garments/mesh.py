"""Hybrid panel meshes: a regular grid aligned to the printed pattern, joined to the outline by a
conforming constrained-Delaunay band.

For one panel at grid spacing h (12, 4, 2 or 1 mm):

1. The outline is sampled edge by edge with a prescribed number of equal arc-length segments per
   edge; both edges of a seam get the same count (`seam_segment_counts`), so their vertices pair up.
   An edge shorter than `COLLAPSE_FRACTION` h (GarmentCode writes edges under a millimetre) gets no
   segment: it collapses to its end point, because Triangle may not split outline segments and
   cannot refine away the thin triangles that a side much shorter than its neighbours leaves.
2. Grid nodes sit at ``grid_origin + h * (i, j)``: with the panel's marker tiling anchored at the same
   origin, every node at h = 2 mm is a crosspoint (every other node at 1 mm, every 2nd/6th crosspoint
   at 4/12 mm).  A grid cell is kept when its four corners are inside the outline and at least
   `band` h away from it; each kept cell is two right triangles, diagonals alternating so the grid
   has no preferred shear direction.
3. The band between the outline and the kept cells is triangulated with Triangle (constrained
   Delaunay with quality refinement, minimum angle 20 degrees by default), with Steiner points
   allowed inside the band but on no segment (`YY`), so neither the seam vertices nor the grid's
   border change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi
import triangle
from scipy.spatial import cKDTree

from assets.garments.sewing import Panel, SewingPattern

# vertex flags
GRID = np.uint8(1)  #: a node of the regular grid
BOUNDARY = np.uint8(2)  #: on the panel outline
SEAM = np.uint8(4)  #: on an edge that is sewn
STEINER = np.uint8(8)  #: added inside the band by the quality triangulation

#: keep grid cells whose corners are at least this many spacings inside the outline
BAND = 0.6
MIN_ANGLE_DEG = 20.0
#: an edge shorter than this many grid spacings collapses to a point (with its seam partner when that
#: is as short).  Edges longer than h get segments of at least h / 2; on GarmentCode's jumpsuit at
#: 12 mm, sides of 0.9 to 5.4 mm among them left triangles of 4.3 degrees, 20.7 at 0.3, 24.9 at 0.5
COLLAPSE_FRACTION = 0.5


@dataclass(frozen=True)
class PanelMesh:
    """One panel's triangle mesh in its own frame.

    vertices (V, 2) float64 metres; faces (F, 3) int32, counter-clockwise; flags (V,) uint8 bit set;
    edge_vertices: per panel edge, the (n_k + 1,) vertex indices from its start to its end.
    """

    vertices: np.ndarray
    faces: np.ndarray
    flags: np.ndarray
    edge_vertices: tuple[np.ndarray, ...]


def seam_segment_counts(pattern: SewingPattern, spacing: float) -> list[list[int]]:
    """Segments per edge, counts[panel][edge]: about length / spacing, equal on both sides of a seam;
    0 (the edge collapses to its end point) for an edge shorter than `COLLAPSE_FRACTION` * spacing
    whose seam partner, if any, is as short."""
    counts = [
        [_segments(panel.edge_length(k), spacing) for k in range(len(panel.edges))] for panel in pattern.panels
    ]
    for seam in pattern.seams:
        pa, pb = pattern.panel_index(seam.a.panel), pattern.panel_index(seam.b.panel)
        ka = pattern.panels[pa].edge_index(seam.a.edge)
        kb = pattern.panels[pb].edge_index(seam.b.edge)
        counts[pa][ka] = counts[pb][kb] = max(counts[pa][ka], counts[pb][kb])
    return counts


def _segments(length: float, spacing: float) -> int:
    """Segments for an edge of `length` metres alone at grid `spacing`: 0 when it collapses."""
    if length < COLLAPSE_FRACTION * spacing:
        return 0
    return max(1, math.ceil(length / spacing - 1e-9))


def inside_polygon_grid(polygon: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(len(ys), len(xs)) bool: lattice points (xs[i], ys[j]) strictly inside the closed polygon (P, 2).

    Scanline even-odd rule: one vectorised crossing computation per row of the lattice.
    """
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    y0, y1 = a[:, 1], b[:, 1]
    inside = np.zeros((len(ys), len(xs)), dtype=bool)
    for j, y in enumerate(ys):  # rows of the lattice, not points
        crosses = (y0 <= y) != (y1 <= y)
        t = (y - y0[crosses]) / (y1[crosses] - y0[crosses])
        xc = np.sort(a[crosses, 0] + t * (b[crosses, 0] - a[crosses, 0]))
        inside[j] = np.searchsorted(xc, xs, side="right") % 2 == 1
    return inside


def mesh_panel(
    panel: Panel,
    spacing: float,
    segments_per_edge: list[int],
    grid_origin: np.ndarray,
    sewn_edges: set[int] = frozenset(),
    min_angle_deg: float = MIN_ANGLE_DEG,
) -> PanelMesh:
    """Mesh one panel (see the module docstring).  `segments_per_edge[k]` 0 collapses edge k to its
    end point: its `edge_vertices` entry is that one vertex.  Raises ValueError naming the panel on
    failure."""
    h = spacing
    # 1. outline
    pieces, edge_ranges, start = [], [], 0
    for k, n in enumerate(segments_per_edge):
        if n > 0:
            pieces.append(panel.edge_points(k, n)[:-1])
        edge_ranges.append(start + np.arange(n + 1))
        start += n
    if start < 3:
        raise ValueError(f"panel '{panel.name}': its outline has {start} segments at a {h * 1e3:g} mm grid "
                         f"(edges shorter than {COLLAPSE_FRACTION * h * 1e3:g} mm collapse); at least 3 needed")
    outline = np.concatenate(pieces)
    n_out = len(outline)
    edge_vertices = tuple(r % n_out for r in edge_ranges)

    # 2. grid nodes and kept cells
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    i0 = math.floor((lo[0] - grid_origin[0]) / h)
    j0 = math.floor((lo[1] - grid_origin[1]) / h)
    i1 = math.ceil((hi[0] - grid_origin[0]) / h)
    j1 = math.ceil((hi[1] - grid_origin[1]) / h)
    xs = grid_origin[0] + h * np.arange(i0, i1 + 1)
    ys = grid_origin[1] + h * np.arange(j0, j1 + 1)
    good = inside_polygon_grid(outline, xs, ys)
    dense = _densify(outline, h / 8)
    jj, ii = np.nonzero(good)
    dist, _ = cKDTree(dense).query(np.stack([xs[ii], ys[jj]], axis=1), distance_upper_bound=BAND * h)
    good[jj[np.isfinite(dist)], ii[np.isfinite(dist)]] = False
    cells = good[:-1, :-1] & good[:-1, 1:] & good[1:, :-1] & good[1:, 1:]  # (rows-1, cols-1)
    if not cells.any():
        raise ValueError(f"panel '{panel.name}': too small for a {h * 1e3:g} mm grid")

    used = np.zeros_like(good)
    used[:-1, :-1] |= cells
    used[:-1, 1:] |= cells
    used[1:, :-1] |= cells
    used[1:, 1:] |= cells
    node_id = np.full(good.shape, -1, dtype=np.int64)
    nj, ni = np.nonzero(used)
    node_id[nj, ni] = n_out + np.arange(len(nj))
    grid_xy = np.stack([xs[ni], ys[nj]], axis=1)

    # grid triangles, diagonals alternating with the parity of the global cell index
    cj, ci = np.nonzero(cells)
    n00, n01 = node_id[cj, ci], node_id[cj, ci + 1]
    n10, n11 = node_id[cj + 1, ci], node_id[cj + 1, ci + 1]
    odd = ((ci + i0 + cj + j0) % 2).astype(bool)
    tri_a = np.where(odd[:, None], np.stack([n00, n01, n10], 1), np.stack([n00, n01, n11], 1))
    tri_b = np.where(odd[:, None], np.stack([n01, n11, n10], 1), np.stack([n00, n11, n10], 1))
    grid_faces = np.concatenate([tri_a, tri_b])

    # border of the kept region: cell sides with a kept cell on exactly one side
    padded = np.pad(cells, 1)
    horiz = padded[:-1, 1:-1] != padded[1:, 1:-1]  # (rows, cols-1): side between nodes (j,i)-(j,i+1)
    vert = padded[1:-1, :-1] != padded[1:-1, 1:]  # (rows-1, cols): side between nodes (j,i)-(j+1,i)
    hj, hi_ = np.nonzero(horiz)
    vj, vi = np.nonzero(vert)
    border = np.concatenate(
        [np.stack([node_id[hj, hi_], node_id[hj, hi_ + 1]], 1), np.stack([node_id[vj, vi], node_id[vj + 1, vi]], 1)]
    )

    # 3. the band
    border_nodes = np.unique(border)  # sorted panel indices of the grid's border nodes
    band_vertices = np.concatenate([outline, grid_xy[border_nodes - n_out]])
    outline_segments = np.stack([np.arange(n_out), (np.arange(n_out) + 1) % n_out], 1)
    segments = np.concatenate([outline_segments, n_out + np.searchsorted(border_nodes, border)])
    labels, _ = ndi.label(cells)
    ids, first = np.unique(labels.ravel(), return_index=True)
    sj, si = np.unravel_index(first[ids > 0], labels.shape)  # one kept cell per component
    holes = np.stack([xs[si] + h / 2, ys[sj] + h / 2], axis=1)
    # the area bound in fixed point: Triangle's option parser cannot read "1e-05"
    band = triangle.triangulate(
        {"vertices": band_vertices, "segments": segments, "holes": holes},
        f"pq{min_angle_deg:g}YYa{h * h:.15f}Q",
    )
    band_faces = band["triangles"].astype(np.int64)
    n_band_in = len(band_vertices)
    steiner = band["vertices"][n_band_in:]
    # band vertex index -> panel vertex index
    to_panel = np.concatenate(
        [np.arange(n_out), border_nodes, n_out + len(grid_xy) + np.arange(len(steiner))]
    )
    faces = np.concatenate([grid_faces, to_panel[band_faces]]).astype(np.int32)
    vertices = np.concatenate([outline, grid_xy, steiner])

    flags = np.zeros(len(vertices), dtype=np.uint8)
    flags[:n_out] |= BOUNDARY
    flags[n_out : n_out + len(grid_xy)] |= GRID
    flags[n_out + len(grid_xy) :] |= STEINER
    for k in sewn_edges:
        flags[edge_vertices[k]] |= SEAM
    return PanelMesh(vertices, faces, flags, edge_vertices)


def _densify(polygon: np.ndarray, step: float) -> np.ndarray:
    """Points along the closed polygon's sides no farther apart than `step`."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step)).astype(int)
    side = np.repeat(np.arange(len(a)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    return a[side] + t[:, None] * (b - a)[side]


def triangle_quality(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed areas (F,) (positive = counter-clockwise) and minimum angles (F,) in degrees."""
    p = vertices[faces]
    e0, e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]
    area = 0.5 * (e0[:, 0] * (-e2[:, 1]) - e0[:, 1] * (-e2[:, 0]))

    def angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        cos = (u * v).sum(axis=1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300)
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    angles = np.stack([angle(e0, -e2), angle(e1, -e0), angle(e2, -e1)], axis=1)
    return area, angles.min(axis=1)
