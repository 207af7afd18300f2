"""Ground truth for one rendered image: where every marker's points are, and which ones are seen.

Two steps.  `MarkerSurface.build(template, level_mm)` (once per template and level) finds every
marker point on the garment mesh; `image_ground_truth(surface, positions, camera, depth)` (once per
image) projects them with the render's camera and decides visibility against the render's depth.
The result is an `assets.pattern.observation.ImageGroundTruth`, from which that module makes the
training targets of the three networks.

Conventions: metres; pixels are continuous image coordinates (x right, y down) with pixel centres at
integer + 0.5 (DESIGN.md); depth is the camera-frame z (distance along the view axis, as in Blender's
Z pass).  M markers (every marker of every panel, in panel order, then the panel's row-major marker
order), K = crosspoints_per_side (25), the five localization points in the order
`assets.pattern.LOCALIZATION_POINTS` (centre, TL, TR, BL, BR; each is also a crosspoint).

`MarkerSurface` arrays (sewn mesh of one template level, F faces, V sewn vertices):
  marker_id (M,) int32            garment-global marker ID
  panel     (M,) int16            panel index into template.pattern.panels
  xp_face   (M, K, K) int64       face (row of `sewn_faces` = row of the unsewn level's `faces`)
                                  holding crosspoint (row, col) of the marker, or -1 off the fabric
                                  (outside the panel's mesh: partial markers cut by the outline)
  xp_bary   (M, K, K, 3) float64  barycentric weights of the point in that face (0 off the fabric)
  loc_face  (M, 5), loc_bary (M, 5, 3)   the same for the five localization points
Faces are counter-clockwise seen from the outside, so ``(p1 - p0) x (p2 - p0)`` points out of the
garment, to the printed side.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import numpy as np

from assets.cameras import Camera
from assets.garments.template import Template
from assets.pattern.observation import ImageGroundTruth
from assets.pattern.spec import PatternSpec
from assets.pattern.table import MarkerTable, localization_rc

#: a point is inside a triangle when its smallest barycentric weight is at least -this
_INSIDE_TOLERANCE = 1e-9
#: points located per batch (bounds the memory of the candidate pairs)
_LOCATE_BATCH = 1 << 16


@dataclass(frozen=True, eq=False)
class MarkerSurface:
    """Where every marker's crosspoints lie on the sewn mesh of one template level (see module doc)."""

    spec: PatternSpec
    marker_id: np.ndarray
    panel: np.ndarray
    xp_face: np.ndarray
    xp_bary: np.ndarray
    sewn_faces: np.ndarray
    num_vertices: int

    @classmethod
    def build(cls, template: Template, level_mm: int, tables: Sequence[MarkerTable] | None = None) -> "MarkerSurface":
        """Locate every marker crosspoint of `template` in its level `level_mm` mesh.

        tables: the layout's marker tables (`template.layout.tables()`, made here if not given; pass
        them when already at hand, as making them generates the codebook)."""
        level = template.level(level_mm)
        if tables is None:
            tables = template.layout.tables()
        if len(tables) != len(template.layout.panels):
            raise ValueError(f"tables: {len(tables)} marker tables for {len(template.layout.panels)} panels")
        face_panel = level.panel[level.faces[:, 0]]
        faces, barys, ids, panels = [], [], [], []
        for p, table in enumerate(tables):
            mine = np.flatnonzero(face_panel == p)
            face, bary = locate_in_mesh(level.pattern_xy, level.faces[mine], table.crosspoint_xy)
            face = np.where(face >= 0, mine[np.maximum(face, 0)], -1)
            faces.append(face[table.crosspoint_index])
            barys.append(bary[table.crosspoint_index])
            ids.append(table.marker_ids)
            panels.append(np.full(table.num_markers, p, np.int16))
        return cls(
            spec=template.layout.spec,
            marker_id=np.concatenate(ids).astype(np.int32),
            panel=np.concatenate(panels),
            xp_face=np.concatenate(faces).astype(np.int64),
            xp_bary=np.concatenate(barys),
            sewn_faces=level.sewn_faces,
            num_vertices=level.num_sewn_vertices,
        )

    @property
    def num_markers(self) -> int:
        return len(self.marker_id)

    @cached_property
    def loc_face(self) -> np.ndarray:
        rc = localization_rc(self.spec)
        return self.xp_face[:, rc[:, 0], rc[:, 1]]

    @cached_property
    def loc_bary(self) -> np.ndarray:
        rc = localization_rc(self.spec)
        return self.xp_bary[:, rc[:, 0], rc[:, 1]]

    def points(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sewn-mesh vertices (V, 3) -> (localization points (M, 5, 3), crosspoints (M, K, K, 3)),
        NaN off the fabric."""
        positions = self._positions(positions)
        return _interpolate(positions, self.sewn_faces, self.loc_face, self.loc_bary), _interpolate(
            positions, self.sewn_faces, self.xp_face, self.xp_bary)

    def normals(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit outward face normals at the localization points (M, 5, 3) and crosspoints
        (M, K, K, 3), NaN off the fabric (and zero on degenerate faces)."""
        normal = _face_normals(self._positions(positions), self.sewn_faces)
        return _take(normal, self.loc_face), _take(normal, self.xp_face)

    def _positions(self, positions: np.ndarray) -> np.ndarray:
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != (self.num_vertices, 3):
            raise ValueError(f"positions must have shape ({self.num_vertices}, 3) (the sewn mesh of this level), "
                             f"got {positions.shape}")
        return positions


def image_ground_truth(
    surface: MarkerSurface,
    positions: np.ndarray,
    camera: Camera,
    depth: np.ndarray,
    depth_tolerance: float = 0.005,
) -> ImageGroundTruth:
    """Project and test every marker point of `surface` in one rendered image.

    positions (V, 3): the sewn-mesh vertices in world coordinates as rendered, metres.
    camera: the render's camera.  depth (H, W): the renderer's depth along the view axis, metres,
    inf (or huge) on the background.  depth_tolerance: metres a point may lie behind the rendered
    depth of its pixel and still be seen (absorbs the depth change across one pixel)."""
    depth = np.asarray(depth)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"depth has shape {depth.shape}, expected (H, W) = {(camera.height, camera.width)} "
                         f"of camera {camera.name!r}")
    if not depth_tolerance >= 0:
        raise ValueError(f"depth_tolerance must be >= 0, got {depth_tolerance}")
    positions = surface._positions(positions)
    face = surface.xp_face.reshape(-1)
    points = _interpolate(positions, surface.sewn_faces, face, surface.xp_bary.reshape(-1, 3))
    normals = _take(_face_normals(positions, surface.sewn_faces), face)
    pixels, z = camera.project(points)
    with np.errstate(invalid="ignore"):
        seen = (face >= 0) & (z > 0) & (np.einsum("nd,nd->n", normals, camera.center - points) > 0)
        seen &= (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < camera.height)
    candidates = np.flatnonzero(seen)
    cols = np.floor(pixels[candidates, 0]).astype(np.int64)
    rows = np.floor(pixels[candidates, 1]).astype(np.int64)
    with np.errstate(invalid="ignore"):
        seen[candidates] = z[candidates] <= depth[rows, cols].astype(np.float64) + depth_tolerance

    m, k = surface.xp_face.shape[:2]
    on = (face >= 0).reshape(m, k, k)
    visible = seen.reshape(m, k, k)
    crosspoints_px = pixels.reshape(m, k, k, 2).astype(np.float32)
    crosspoints_z = np.where(face >= 0, z, np.nan).reshape(m, k, k).astype(np.float32)
    rc = localization_rc(surface.spec)
    point_visible = visible[:, rc[:, 0], rc[:, 1]]
    full = (visible == on).all(axis=(1, 2)) & point_visible.all(axis=1)
    status = np.where(full, 2, np.where(visible.any(axis=(1, 2)), 1, 0)).astype(np.int8)
    return ImageGroundTruth(
        width=camera.width,
        height=camera.height,
        marker_id=surface.marker_id.astype(np.int32),
        points_px=crosspoints_px[:, rc[:, 0], rc[:, 1]],
        points_depth=crosspoints_z[:, rc[:, 0], rc[:, 1]],
        point_visible=point_visible,
        crosspoints_px=crosspoints_px,
        crosspoint_visible=visible,
        status=status,
    )


# ---- geometry helpers ----------------------------------------------------------------------------
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
        bary = _barycentric(tri[candidate], batch[point])
        score = bary.min(axis=1)
        inside = score >= -_INSIDE_TOLERANCE
        point, candidate, bary, score = point[inside], candidate[inside], bary[inside], score[inside]
        best = np.lexsort((-score, point))
        _, keep = np.unique(point[best], return_index=True)
        best = best[keep]
        face_out[start + point[best]] = candidate[best]
        bary_out[start + point[best]] = bary[best]
    return face_out, bary_out


def _barycentric(tri: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights (N, 3) of points (N, 2) in triangles (N, 3, 2)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    l1 = (v2[:, 0] * v1[:, 1] - v2[:, 1] * v1[:, 0]) / det
    l2 = (v0[:, 0] * v2[:, 1] - v0[:, 1] * v2[:, 0]) / det
    return np.stack([1 - l1 - l2, l1, l2], axis=1)


def _interpolate(positions: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Points (..., 3) at faces `face` (...) with weights `bary` (..., 3); NaN where face is -1."""
    corners = positions[faces[np.maximum(face, 0)]]  # (..., 3, 3)
    out = np.einsum("...kd,...k->...d", corners, bary)
    out[face < 0] = np.nan
    return out


def _face_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit outward normals (zero for degenerate faces)."""
    p0, p1, p2 = (positions[faces[:, i]] for i in range(3))
    normal = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    return np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)


def _take(per_face: np.ndarray, face: np.ndarray) -> np.ndarray:
    out = per_face[np.maximum(face, 0)]
    out[face < 0] = np.nan
    return out
