"""From captured crosspoints to anchored vertices: which vertices of a template level are captured in a
frame, and where their anchor springs pull them.

Captured crosspoints (`CapturedPoints`, keyed by (panel, crosspoint index)) are located once per level
in its sewing pattern (face + barycentric weights of the level's mesh, like
`assets.garments.markers.MarkerSurface`, for every crosspoint on the fabric).

A vertex is **captured** when captured crosspoints surround it closely in the sewing pattern: within
the radius r = radius_factor * max(level spacing, 2 crosspoint pitches) of the vertex (in its panel),
every one of `sectors` equal angular sectors that holds crosspoints of the fabric holds a captured one,
and at least `coverage` of all the fabric's crosspoints in that disc are captured.  A seam vertex must
be captured on every panel it joins.  So an isolated point (a wrong ID that survived triangulation)
anchors nothing, and a vertex at the edge of what the cameras saw is anchored only when its target is
interpolated, not extrapolated.

Its **anchor target** comes from one sparse least-squares fit per frame and level over the vertices of
the faces that hold captured points: each captured point p (confidence c_p, world position y_p, face
f_p, weights b_p) asks sum_k b_pk x_{f_p,k} = y_p with weight c_p, and a small Laplacian term keeps the
uniform-Laplacian coordinates of the fitted vertices those of a reference shape (the frame's starting
shape), weight `regularizer` per crosspoint the vertex's pattern area holds (at least 1):

    min_x  sum_p c_p |B_p x - y_p|^2 + sum_v a_v |(L (x - x_ref))_v|^2.

Positions: world metres on the level's sewn mesh (V sewn vertices); pattern coordinates metres.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from assets.garments.template import Template
from assets.geometry import locate_in_mesh

_PANEL_OFFSET = 1.0e3  # m between panels in the joint neighbour search (panel frames overlap)
_CENTRE = 1e-7  # m: a crosspoint this close to a vertex is that vertex
_FIT_TOLERANCE = 1e-10  # relative residual of the anchor fit's conjugate gradients
_FIT_ITERATIONS = 5000

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Anchors:
    """One frame's anchoring on one level (V sewn vertices).

    captured (V,) bool         vertices with an anchor spring
    targets (V, 3) float64     anchor targets, world metres (NaN where not captured)
    points int                 captured crosspoints on this level's fabric
    fit_rms float              RMS distance (m) of the captured points from the fitted surface
    """

    captured: np.ndarray
    targets: np.ndarray
    points: int
    fit_rms: float


class LevelAnchoring:
    """Captured crosspoints -> captured vertices and anchor targets on one template level (module doc)."""

    def __init__(self, template: Template, level_mm: int, radius_factor: float = 1.0, coverage: float = 0.5,
                 sectors: int = 4, regularizer: float = 1e-2):
        if not (radius_factor > 0 and 0 < coverage <= 1 and sectors >= 1 and regularizer >= 0):
            raise ValueError(f"anchoring: expected radius_factor > 0, coverage in (0, 1], sectors >= 1, "
                             f"regularizer >= 0, got {radius_factor}, {coverage}, {sectors}, {regularizer}")
        self.level_mm = int(level_mm)
        self.coverage, self.sectors = float(coverage), int(sectors)
        level = template.level(level_mm)
        layout = template.layout
        self.sewn_faces = level.sewn_faces.astype(np.int64)
        self.sewn_index = level.sewn_index
        self.num_vertices = level.num_sewn_vertices
        faces = level.faces.astype(np.int64)
        face_panel = level.panel[faces[:, 0]]

        # every crosspoint of the fabric, located in this level's pattern mesh
        self.first_crosspoint = np.array([sheet.first_crosspoint for sheet in layout.panels], dtype=np.int64)
        self.panel_crosspoints = np.array([sheet.spec.num_crosspoints for sheet in layout.panels], dtype=np.int64)
        self.lookup = np.full(int((self.first_crosspoint + self.panel_crosspoints).max(initial=0)), -1, np.int64)
        face, bary, xy, panel, flat = [], [], [], [], []
        for p, sheet in enumerate(layout.panels):
            rows, cols = sheet.spec.grid_shape
            grid_row, grid_col = np.divmod(np.arange(rows * cols), cols)
            points = sheet.spec.uv_to_xy(np.stack([grid_col, grid_row], axis=1))
            mine = np.flatnonzero(face_panel == p)
            where, weights = locate_in_mesh(level.pattern_xy, faces[mine], points)
            on = np.flatnonzero(where >= 0)
            face.append(mine[where[on]])
            bary.append(weights[on])
            xy.append(points[on])
            panel.append(np.full(len(on), p, np.int64))
            flat.append(sheet.first_crosspoint + on)
        self.face, self.bary = np.concatenate(face), np.concatenate(bary)
        crosspoint_xy, crosspoint_panel = np.concatenate(xy), np.concatenate(panel)
        self.lookup[np.concatenate(flat)] = np.arange(len(self.face))

        # crosspoints near each unsewn vertex, by angular sector
        pitch = layout.spec.pitch
        self.radius = radius_factor * max(level.spacing_mm * 1e-3, 2.0 * pitch)
        vertex_xy = level.pattern_xy + (level.panel[:, None] * _PANEL_OFFSET) * np.array([[1.0, 0.0]])
        point_xy = crosspoint_xy + (crosspoint_panel[:, None] * _PANEL_OFFSET) * np.array([[1.0, 0.0]])
        near = cKDTree(vertex_xy).sparse_distance_matrix(cKDTree(point_xy), self.radius, output_type="ndarray")
        vertex, point = near["i"].astype(np.int64), near["j"].astype(np.int64)
        offset = point_xy[point] - vertex_xy[vertex]
        centre = near["v"] < _CENTRE
        self.centre = np.full(level.num_vertices, -1, np.int64)
        self.centre[vertex[centre]] = point[centre]
        angle = np.arctan2(offset[~centre, 1], offset[~centre, 0])
        sector = np.minimum(((angle + np.pi) / (2 * np.pi) * sectors).astype(np.int64), sectors - 1)
        self.pair_cell = vertex[~centre] * sectors + sector  # (unsewn vertex, sector) of each pair
        self.pair_point = point[~centre]
        self.fabric = np.bincount(self.pair_cell, minlength=level.num_vertices * sectors).reshape(-1, sectors)

        # uniform Laplacian of the sewn mesh and the regulariser weights
        edges = np.concatenate([self.sewn_faces[:, [0, 1]], self.sewn_faces[:, [1, 2]], self.sewn_faces[:, [2, 0]]])
        n = self.num_vertices
        adjacency = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
        adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64)
        degree = np.asarray(adjacency.sum(axis=1)).ravel()
        self.laplacian = (sp.identity(n, format="csr") - sp.diags(1.0 / np.maximum(degree, 1)) @ adjacency).tocsr()
        corners = level.pattern_xy[faces]
        area = 0.5 * np.abs(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
        vertex_area = np.bincount(self.sewn_faces.ravel(), np.repeat(area / 3.0, 3), minlength=n)
        self.regularizer = regularizer * np.maximum(vertex_area / pitch**2, 1.0)

    def rows(self, key: np.ndarray) -> np.ndarray:
        """Crosspoint keys (P, 2) (panel, index in the panel's MarkerTable) -> rows (P,) of this level's
        fabric crosspoints, -1 for a crosspoint off this level's fabric."""
        key = np.asarray(key, dtype=np.int64).reshape(-1, 2)
        panel, index = key[:, 0], key[:, 1]
        bad = (panel < 0) | (panel >= len(self.first_crosspoint))
        bad |= (index < 0) | (index >= self.panel_crosspoints[np.clip(panel, 0, len(self.first_crosspoint) - 1)])
        if bad.any():
            raise ValueError(f"CapturedPoints.key: {int(bad.sum())} keys are not (panel, crosspoint index) of this "
                             f"garment's layout, e.g. {key[np.argmax(bad)].tolist()}")
        return self.lookup[self.first_crosspoint[panel] + index]

    def captured_vertices(self, key: np.ndarray) -> np.ndarray:
        """(V,) bool: the sewn vertices that captured crosspoints `key` (P, 2) surround (module doc)."""
        rows = self.rows(key)
        seen = np.zeros(len(self.face) + 1, dtype=bool)  # the last slot stands for "no crosspoint"
        seen[rows[rows >= 0]] = True
        captured = np.bincount(self.pair_cell, seen[self.pair_point], minlength=self.fabric.size)
        captured = captured.reshape(self.fabric.shape)
        fabric = self.fabric
        # a crosspoint at the vertex itself counts towards the coverage, in no sector
        total = fabric.sum(axis=1) + (self.centre >= 0)
        unsewn = ((fabric == 0) | (captured >= 1)).all(axis=1) & (total > 0)
        unsewn &= captured.sum(axis=1) + seen[self.centre] >= self.coverage * total
        return np.bincount(self.sewn_index, ~unsewn, minlength=self.num_vertices) == 0

    def anchors(self, key: np.ndarray, xyz: np.ndarray, confidence: np.ndarray, reference: np.ndarray) -> Anchors:
        """Captured vertices and their targets from captured points (key (P, 2), xyz (P, 3) world
        metres, confidence (P,) in [0, 1]); reference (V, 3) is the shape whose Laplacian coordinates
        regularise the fit (the frame's starting shape)."""
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != (self.num_vertices, 3):
            raise ValueError(f"reference: expected ({self.num_vertices}, 3) (the sewn {self.level_mm} mm level), "
                             f"got {reference.shape}")
        rows = self.rows(key)
        on = rows >= 0
        rows, xyz, weight = rows[on], np.asarray(xyz, np.float64)[on], np.asarray(confidence, np.float64)[on]
        captured = self.captured_vertices(np.asarray(key)[on])
        targets = np.full((self.num_vertices, 3), np.nan)
        if len(rows) == 0:
            return Anchors(captured, targets, 0, 0.0)
        corners = self.sewn_faces[self.face[rows]]  # (P, 3)
        unknown = np.unique(np.concatenate([corners.ravel(), np.flatnonzero(captured)]))
        column = np.full(self.num_vertices, -1, np.int64)
        column[unknown] = np.arange(len(unknown))
        sqrt_w = np.sqrt(weight)
        data = sp.csr_matrix(((self.bary[rows] * sqrt_w[:, None]).ravel(),
                              (np.repeat(np.arange(len(rows)), 3), column[corners].ravel())),
                             shape=(len(rows), len(unknown)))
        laplacian = self.laplacian[unknown][:, unknown]
        smooth = sp.diags(self.regularizer[unknown]) @ laplacian
        normal = (data.T @ data + laplacian.T @ smooth).tocsr()
        normal = normal + sp.identity(len(unknown), format="csr") * (1e-9 * float(normal.diagonal().mean()))
        residual = (xyz - interpolate_rows(reference, corners, self.bary[rows])) * sqrt_w[:, None]
        rhs = np.asarray(data.T @ residual)
        # conjugate gradients on the displacement from the reference (Jacobi-preconditioned): the data
        # term dominates, so it converges in tens of iterations where a factorisation of the 2 mm
        # level's system takes half a minute
        jacobi = sp.diags(1.0 / normal.diagonal())
        step = np.zeros_like(rhs)
        for axis in range(3):
            step[:, axis], info = spla.cg(normal, rhs[:, axis], M=jacobi, rtol=_FIT_TOLERANCE, maxiter=_FIT_ITERATIONS)
            if info:
                log.warning("anchor fit (%d mm): conjugate gradients stopped after %d iterations short of "
                            "tolerance %.0e", self.level_mm, info, _FIT_TOLERANCE)
        fitted = reference[unknown] + step
        targets[captured] = fitted[column[captured]]
        fit = np.einsum("pkd,pk->pd", fitted[column[corners]], self.bary[rows])
        rms = float(np.sqrt(np.mean(np.sum((fit - xyz) ** 2, axis=1))))
        return Anchors(captured, targets, int(len(rows)), rms)

    def points_on(self, positions: np.ndarray, key: np.ndarray) -> np.ndarray:
        """Crosspoints `key` (P, 2) on a shape (V, 3) of this level: (P, 3), NaN off this level's fabric."""
        rows = self.rows(key)
        out = interpolate_rows(np.asarray(positions, np.float64), self.sewn_faces[self.face[np.maximum(rows, 0)]],
                               self.bary[np.maximum(rows, 0)])
        out[rows < 0] = np.nan
        return out


def interpolate_rows(positions: np.ndarray, corners: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Points (P, 3) = sum_k bary[:, k] * positions[corners[:, k]]."""
    return np.einsum("pkd,pk->pd", positions[corners], bary)


def rigid_fit(source: np.ndarray, target: np.ndarray, weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (3, 3) and translation t (3,) minimising sum_i w_i |R source_i + t - target_i|^2
    (Kabsch), for point sets (N, 3), N >= 3 not collinear."""
    source, target = np.asarray(source, np.float64), np.asarray(target, np.float64)
    weight = np.ones(len(source)) if weight is None else np.asarray(weight, np.float64)
    if len(source) < 3 or weight.sum() <= 0:
        raise ValueError(f"rigid_fit: needs at least 3 weighted points, got {len(source)}")
    w = weight / weight.sum()
    source_mean, target_mean = w @ source, w @ target
    covariance = (target - target_mean).T @ ((source - source_mean) * w[:, None])
    u, _, vt = np.linalg.svd(covariance)
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ flip @ vt
    return rotation, target_mean - rotation @ source_mean
