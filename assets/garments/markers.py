"""Where every marker's crosspoints lie on a garment mesh: `MarkerSurface`.

`MarkerSurface.build(template, level_mm)` locates every crosspoint of every marker of the garment's
layout in the flat (pattern_xy) mesh of one template level, once; `points(positions)` then gives
them on any posed copy of that mesh.  The factory projects them to make ground truth; reconstruction
maps a detected (marker ID, row, col) to the mesh through it.

M markers (every marker of every panel, in panel order, then the panel's row-major marker order),
K = crosspoints_per_side (25), the five localization points in the order
`assets.pattern.LOCALIZATION_POINTS`.

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

from assets.garments.template import Template
from assets.geometry import locate_in_mesh
from assets.pattern.spec import PatternSpec
from assets.pattern.table import MarkerTable, localization_rc


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
        positions = self.checked_positions(positions)
        return interpolate(positions, self.sewn_faces, self.loc_face, self.loc_bary), interpolate(
            positions, self.sewn_faces, self.xp_face, self.xp_bary)

    def normals(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit outward face normals at the localization points (M, 5, 3) and crosspoints
        (M, K, K, 3), NaN off the fabric (and zero on degenerate faces)."""
        normal = face_normals(self.checked_positions(positions), self.sewn_faces)
        return take(normal, self.loc_face), take(normal, self.xp_face)

    def checked_positions(self, positions: np.ndarray) -> np.ndarray:
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != (self.num_vertices, 3):
            raise ValueError(f"positions must have shape ({self.num_vertices}, 3) (the sewn mesh of this level), "
                             f"got {positions.shape}")
        return positions


def interpolate(positions: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Points (..., 3) at faces `face` (...) with weights `bary` (..., 3); NaN where face is -1."""
    corners = positions[faces[np.maximum(face, 0)]]  # (..., 3, 3)
    out = np.einsum("...kd,...k->...d", corners, bary)
    out[face < 0] = np.nan
    return out


def face_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit outward normals (zero for degenerate faces)."""
    p0, p1, p2 = (positions[faces[:, i]] for i in range(3))
    normal = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    return np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)


def take(per_face: np.ndarray, face: np.ndarray) -> np.ndarray:
    out = per_face[np.maximum(face, 0)]
    out[face < 0] = np.nan
    return out
