"""Correspondence: a detected (marker ID, crosspoint row, col) -> crosspoint key -> template point.

Every marker of a garment's layout has a unique ID (`assets.garments.layout`); its crosspoint at
local (row, col) is global crosspoint ``crosspoint_index[marker, row, col]`` of its panel's
`MarkerTable`, so the **key** of a crosspoint is (panel index, that global index): neighbouring
markers share their border crosspoints and give them the same key.  Keys are also numbered
garment-wide (`flat`: ``layout.panels[panel].first_crosspoint + index``, the numbering of
`Level.crosspoint`), which sorts and groups them as one integer.

Each key sits at a point of the sewing pattern, located once per template level on the level's sewn
mesh (`assets.garments.markers.MarkerSurface`): a face (row of `Level.sewn_faces`) and barycentric
weights, -1 where the crosspoint is off the fabric (a partial marker cut by the panel's outline).
Where a crosspoint coincides with a mesh vertex (a weight of 1 within 1e-9; every crosspoint of a
level whose grid is the crosspoint grid, and every 6th of the 12 mm level), `vertex_of` gives it.

K = crosspoints per side (25).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from assets.garments.markers import MarkerSurface, interpolate
from assets.garments.template import Template
from assets.pattern.table import MarkerTable
from networks.detections import Detections

log = logging.getLogger(__name__)

#: a barycentric weight within this of 1 makes a crosspoint a mesh vertex (`vertex_of`)
VERTEX_TOLERANCE = 1e-9


@dataclass(frozen=True, eq=False)
class Observations:
    """The crosspoints one view saw, n of them (one row per detected marker crosspoint).

      key (n, 2) int64          (panel, global crosspoint index in the panel's MarkerTable)
      pixels (n, 2) float64     continuous image pixels as detected (distorted camera)
      confidence (n,) float64   the detecting marker's confidence, in [0, 1]
      marker_id (n,) int64      the detecting marker (a border crosspoint appears once per marker)
    """

    key: np.ndarray
    pixels: np.ndarray
    confidence: np.ndarray
    marker_id: np.ndarray

    def __len__(self) -> int:
        return len(self.key)


@dataclass(frozen=True, eq=False)
class CrosspointMap:
    """The garment's markers and where their crosspoints lie on one template level (module doc).

      level_mm int
      marker_id (M,) int64 sorted          every marker of the layout
      panel (M,) int64                     its panel
      crosspoint_index (M, K, K) int64     global crosspoint of local (row, col) in the panel's table
      first_crosspoint (Pn,) int64         per panel, the garment-wide number of its crosspoint 0
      face (G,) int64, bary (G, 3) float64 per garment-wide crosspoint: face of the level's sewn
                                           mesh and barycentric weights, -1 / 0 off the fabric
      sewn_faces (F, 3) int32              the level's sewn faces
      pattern_xy (G, 2) float64            per garment-wide crosspoint, its place on its panel's flat
                                           fabric (`MarkerTable.crosspoint_xy`), metres
      grid_shape (Pn, 2) int64             per panel, its crosspoint grid (rows, cols): panel crosspoint
                                           (gr, gc) has index gr * cols + gc
    """

    level_mm: int
    marker_id: np.ndarray
    panel: np.ndarray
    crosspoint_index: np.ndarray
    first_crosspoint: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    sewn_faces: np.ndarray
    pattern_xy: np.ndarray
    grid_shape: np.ndarray

    @classmethod
    def build(cls, template: Template, level_mm: int, tables: Sequence[MarkerTable] | None = None) -> "CrosspointMap":
        """Locate every crosspoint of `template`'s markers on its `level_mm` sewn mesh.

        tables: `template.layout.tables()` when already at hand (making them generates the codebook)."""
        if tables is None:
            tables = template.layout.tables()
        surface = MarkerSurface.build(template, level_mm, tables)
        first = np.array([p.first_crosspoint for p in template.layout.panels], dtype=np.int64)
        index = np.concatenate([t.crosspoint_index for t in tables])
        panel = surface.panel.astype(np.int64)
        flat = first[panel][:, None, None] + index
        total = int(template.layout.num_crosspoints)
        face = np.full(total, -1, dtype=np.int64)
        bary = np.zeros((total, 3))
        # border crosspoints are written once per marker holding them, with identical values
        face[flat] = surface.xp_face
        bary[flat] = surface.xp_bary
        pattern_xy = np.zeros((total, 2))
        for start, table in zip(first, tables):
            pattern_xy[start:start + table.spec.num_crosspoints] = table.crosspoint_xy
        order = np.argsort(surface.marker_id, kind="stable")
        return cls(level_mm=int(level_mm), marker_id=surface.marker_id[order].astype(np.int64), panel=panel[order],
                   crosspoint_index=index[order], first_crosspoint=first, face=face, bary=bary,
                   sewn_faces=surface.sewn_faces, pattern_xy=pattern_xy,
                   grid_shape=np.array([t.spec.grid_shape for t in tables], dtype=np.int64).reshape(-1, 2))

    @property
    def crosspoints_per_side(self) -> int:
        return self.crosspoint_index.shape[1]

    @property
    def num_crosspoints(self) -> int:
        """G: crosspoints of the whole garment (every panel's table)."""
        return len(self.face)

    @property
    def marker_flat(self) -> np.ndarray:
        """(M, K, K) int64: the garment-wide crosspoint number of each marker's local (row, col)."""
        return self.first_crosspoint[self.panel][:, None, None] + self.crosspoint_index

    def grid_pairs(self, stride: int) -> np.ndarray:
        """(E, 2) int64 garment-wide numbers of the crosspoint pairs `stride` grid steps apart along a
        row or a column of a panel's grid, both on the fabric (across marker borders too)."""
        if stride < 1:
            raise ValueError(f"grid_pairs: stride must be >= 1, got {stride}")
        pairs = []
        for start, (rows, cols) in zip(self.first_crosspoint, self.grid_shape):
            grid = start + np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
            pairs += [np.stack([grid[:, :-stride].ravel(), grid[:, stride:].ravel()], axis=1),
                      np.stack([grid[:-stride].ravel(), grid[stride:].ravel()], axis=1)]
        pairs = np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)
        return pairs[(self.face[pairs] >= 0).all(axis=1)]

    # ---- lookups (vectorised) ------------------------------------------------------------------
    def marker_rows(self, marker_id: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Marker IDs (N,) -> (row of this map's marker arrays (N,) int64, known (N,) bool)."""
        marker_id = np.asarray(marker_id, dtype=np.int64)
        row = np.clip(np.searchsorted(self.marker_id, marker_id), 0, len(self.marker_id) - 1)
        return row, self.marker_id[row] == marker_id

    def lookup(self, marker_id: np.ndarray, row: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(marker ID, local row, local col) arrays (N,) -> (key (N, 2) int64, known (N,) bool).

        known is False for an ID not in this garment's layout or a row / col outside [0, K); their
        keys are (-1, -1)."""
        marker_id, row, col = np.broadcast_arrays(*(np.asarray(a, dtype=np.int64) for a in (marker_id, row, col)))
        marker, known = self.marker_rows(marker_id)
        k = self.crosspoints_per_side
        known &= (row >= 0) & (row < k) & (col >= 0) & (col < k)
        index = self.crosspoint_index[marker, np.clip(row, 0, k - 1), np.clip(col, 0, k - 1)]
        key = np.stack([self.panel[marker], index], axis=-1)
        key[~known] = -1
        return key, known

    def flat(self, key: np.ndarray) -> np.ndarray:
        """Keys (N, 2) -> garment-wide crosspoint numbers (N,) int64 (`Level.crosspoint`'s numbering)."""
        key = self._checked_keys(key)
        return self.first_crosspoint[key[:, 0]] + key[:, 1]

    def unflat(self, flat: np.ndarray) -> np.ndarray:
        """Garment-wide crosspoint numbers (N,) -> keys (N, 2) int64."""
        flat = np.asarray(flat, dtype=np.int64)
        if flat.size and (flat.min() < 0 or flat.max() >= self.num_crosspoints):
            raise ValueError(f"crosspoint numbers must lie in [0, {self.num_crosspoints}), got "
                             f"[{flat.min()}, {flat.max()}]")
        panel = np.searchsorted(self.first_crosspoint, flat, side="right") - 1
        return np.stack([panel, flat - self.first_crosspoint[panel]], axis=-1)

    def locate(self, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keys (N, 2) -> (face (N,) int64 of the level's sewn mesh or -1 off the fabric,
        barycentric weights (N, 3) float64)."""
        g = self.flat(key)
        return self.face[g], self.bary[g]

    def vertex_of(self, key: np.ndarray) -> np.ndarray:
        """Keys (N, 2) -> the sewn vertex (N,) int64 each crosspoint coincides with (a barycentric
        weight of 1 within `VERTEX_TOLERANCE`), or -1 where it lies inside a face or off the fabric."""
        face, bary = self.locate(key)
        corner = bary.argmax(axis=1)
        vertex = self.sewn_faces[np.maximum(face, 0), corner].astype(np.int64)
        on_vertex = (face >= 0) & (np.abs(bary[np.arange(len(bary)), corner] - 1.0) <= VERTEX_TOLERANCE)
        return np.where(on_vertex, vertex, -1)

    def points(self, positions: np.ndarray, key: np.ndarray) -> np.ndarray:
        """The crosspoints `key` (N, 2) on a posed copy of the level's sewn mesh `positions` (V, 3):
        (N, 3), NaN off the fabric."""
        face, bary = self.locate(key)
        return interpolate(np.asarray(positions, dtype=np.float64), self.sewn_faces, face, bary)

    def observations(self, detections: Detections, where: str = "detections") -> tuple[Observations, np.ndarray]:
        """One view's detections -> (its visible crosspoints on the fabric as `Observations`, the
        sorted unknown marker IDs (not in this garment's layout), which are dropped and logged).

        Crosspoints whose pixels are not finite, or that lie off the fabric of this garment, are
        dropped too.  `where` names the view in the log."""
        k = self.crosspoints_per_side
        if len(detections) and detections.crosspoints_px.shape[1] != k:
            raise ValueError(f"{where}: detections have {detections.crosspoints_px.shape[1]} crosspoints per side, "
                             f"the garment's markers {k}")
        _, known_marker = self.marker_rows(detections.marker_id)
        unknown = np.unique(detections.marker_id[~known_marker])
        if len(unknown):
            log.warning("%s: %d marker ID(s) not in this garment's layout dropped: %s", where, len(unknown),
                        unknown[:20].tolist())
        m, row, col = np.nonzero(detections.crosspoint_visible & known_marker[:, None, None])
        pixels = detections.crosspoints_px[m, row, col].astype(np.float64)
        key, _ = self.lookup(detections.marker_id[m], row, col)
        keep = np.isfinite(pixels).all(axis=1) & (self.face[self.flat(key)] >= 0)
        confidence = np.clip(detections.confidence[m].astype(np.float64), 0.0, 1.0)
        return Observations(key=key[keep], pixels=pixels[keep], confidence=confidence[keep],
                            marker_id=detections.marker_id[m][keep]), unknown

    def _checked_keys(self, key: np.ndarray) -> np.ndarray:
        key = np.asarray(key, dtype=np.int64)
        if key.ndim != 2 or key.shape[1] != 2:
            raise ValueError(f"keys must have shape (N, 2) (panel, crosspoint index), got {key.shape}")
        if len(key):
            panels = len(self.first_crosspoint)
            sizes = np.diff(np.append(self.first_crosspoint, self.num_crosspoints))
            bad = (key[:, 0] < 0) | (key[:, 0] >= panels)
            bad |= (key[:, 1] < 0) | (key[:, 1] >= sizes[np.clip(key[:, 0], 0, panels - 1)])
            if bad.any():
                raise ValueError(f"keys: {int(bad.sum())} of {len(key)} are not crosspoints of this garment, e.g. "
                                 f"{key[bad][0].tolist()} ({panels} panels)")
        return key
