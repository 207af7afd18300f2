"""Dynamic rest shape: per frame, the rest shape the post-processing's membrane and bending pull towards.

Stencils: a triangle (3 vertices) carries a 2 x 2 rest matrix, a hinge (the 4 vertices of two
triangles sharing an edge) a rest dihedral angle and a rest edge length.  As in the reference:

1. observed: where every vertex of a stencil is captured in the current frame, its rest value is
   measured on the captured (anchor target) positions;
2. elsewhere the value measured on the previous frame's solved shape (the frame the propagation comes
   from), or the template's own rest shape (flat sewing pattern, flat hinges) where there is none or
   where that triangle is crushed;
3. a bidirectional smoothing pass replaces every stencil that is not observed by the mean of the
   values measured on the previous and next frames' solved shapes.

Conventions (Newton's, so the arrays go straight into `model.tri_poses`, `tri_areas`,
`edge_rest_angle`, `edge_rest_length`):
  triangle (F, 3) vertex indices; its rest matrix D (2, 2) holds the rest edges x1 - x0 and x2 - x0
    as columns in the triangle's own frame (x along x1 - x0): D = [[|e1|, e2.u], [0, |e2 - (e2.u) u|]]
    (upper triangular, positive diagonal, so values from different frames can be averaged).  Newton's
    deformation gradient is [x1 - x0, x2 - x0] @ D^-1 and its rest area det(D) / 2.
  hinge (E, 4) vertex indices (o0, o1, v0, v1): opposite vertices of the two triangles, then the edge;
    o1 = -1 on a boundary edge (no bending there).  The dihedral angle is
    atan2((n1 x n2) . e, n1 . n2) with n1 = (v0 - o0) x (v1 - o0), n2 = (v1 - o1) x (v0 - o1),
    e = (v1 - v0) / |v1 - v0|: 0 when flat.
Units: metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a triangle counts as crushed (its measured value unusable) below this fraction of its template area
MIN_AREA_FRACTION = 1e-2


@dataclass(frozen=True, eq=False)
class RestShape:
    """Rest values of every stencil of one mesh (F triangles, E hinges; see the module docstring).

    triangle (F, 2, 2) float64 rest edge matrices D, metres
    hinge_angle (E,) float64 rest dihedral angles, radians
    hinge_length (E,) float64 rest edge lengths, metres
    """

    triangle: np.ndarray
    hinge_angle: np.ndarray
    hinge_length: np.ndarray

    def __post_init__(self) -> None:
        f, e = len(self.triangle), len(self.hinge_angle)
        for name, shape in (("triangle", (f, 2, 2)), ("hinge_angle", (e,)), ("hinge_length", (e,))):
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"RestShape.{name}: expected shape {shape}, got {np.shape(getattr(self, name))}")

    @property
    def areas(self) -> np.ndarray:
        """(F,) rest areas, m^2."""
        return 0.5 * (self.triangle[:, 0, 0] * self.triangle[:, 1, 1] - self.triangle[:, 0, 1] * self.triangle[:, 1, 0])

    @property
    def poses(self) -> np.ndarray:
        """(F, 2, 2) inverse rest matrices D^-1 (Newton's `tri_poses`)."""
        return np.linalg.inv(self.triangle)

    def where(self, triangle: np.ndarray, hinge: np.ndarray, other: "RestShape") -> "RestShape":
        """This shape's values where the masks (F,) / (E,) are true, `other`'s elsewhere."""
        return RestShape(
            triangle=np.where(triangle[:, None, None], self.triangle, other.triangle),
            hinge_angle=np.where(hinge, self.hinge_angle, other.hinge_angle),
            hinge_length=np.where(hinge, self.hinge_length, other.hinge_length),
        )


def triangle_rest(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Rest matrices D (F, 2, 2) of the triangles `faces` (F, 3) at `positions` (V, 3) or flat (V, 2)."""
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape[1] == 2:
        positions = np.concatenate([positions, np.zeros((len(positions), 1))], axis=1)
    corners = positions[np.asarray(faces)]
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    length = np.linalg.norm(e1, axis=1)
    u = e1 / np.maximum(length, 1e-300)[:, None]
    along = np.einsum("fd,fd->f", e2, u)
    height = np.linalg.norm(e2 - along[:, None] * u, axis=1)
    out = np.zeros((len(corners), 2, 2))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 1] = length, along, height
    return out


def hinge_angles(positions: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Dihedral angles (E,) radians of `hinges` (E, 4) at `positions` (V, 3); 0 on boundary edges."""
    positions = np.asarray(positions, dtype=np.float64)
    hinges = np.asarray(hinges, dtype=np.int64)
    x0, x1, x2, x3 = (positions[np.maximum(hinges[:, k], 0)] for k in range(4))
    n1 = np.cross(x2 - x0, x3 - x0)
    n2 = np.cross(x3 - x1, x2 - x1)
    e = x3 - x2
    n1 /= np.maximum(np.linalg.norm(n1, axis=1), 1e-300)[:, None]
    n2 /= np.maximum(np.linalg.norm(n2, axis=1), 1e-300)[:, None]
    e /= np.maximum(np.linalg.norm(e, axis=1), 1e-300)[:, None]
    angle = np.arctan2(np.einsum("ed,ed->e", np.cross(n1, n2), e), np.einsum("ed,ed->e", n1, n2))
    return np.where((hinges[:, :2] >= 0).all(axis=1), angle, 0.0)


def hinge_lengths(positions: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Lengths (E,) of the hinge edges v0 - v1."""
    positions = np.asarray(positions, dtype=np.float64)
    return np.linalg.norm(positions[hinges[:, 3]] - positions[hinges[:, 2]], axis=1)


def measure(positions: np.ndarray, faces: np.ndarray, hinges: np.ndarray) -> RestShape:
    """The rest values a mesh at `positions` (V, 3) would have if that shape were its rest."""
    return RestShape(triangle_rest(positions, faces), hinge_angles(positions, hinges),
                     hinge_lengths(positions, hinges))


def pattern_rest(pattern_xy: np.ndarray, unsewn_faces: np.ndarray, sewn_faces: np.ndarray,
                 hinges: np.ndarray) -> RestShape:
    """The template's own rest shape: triangles from the flat sewing pattern, flat hinges, and each
    hinge edge's length the mean of its pattern lengths (the two sides of a seam may differ).

    pattern_xy (Vu, 2) and unsewn_faces (F, 3) are the level's unsewn mesh; sewn_faces (F, 3) the same
    faces on the sewn vertices that `hinges` (E, 4) index."""
    triangle = triangle_rest(pattern_xy, unsewn_faces)
    corners = np.asarray(pattern_xy, dtype=np.float64)[np.asarray(unsewn_faces)]
    side = np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2)  # (F, 3): edge k from corner k to k + 1
    start, end = np.asarray(sewn_faces, np.int64), np.asarray(sewn_faces, np.int64)[:, [1, 2, 0]]
    keys, inverse = np.unique(_edge_keys(start.ravel(), end.ravel()), return_inverse=True)
    mean_length = np.bincount(inverse, side.ravel(), len(keys)) / np.bincount(inverse, minlength=len(keys))
    slot = np.searchsorted(keys, _edge_keys(hinges[:, 2].astype(np.int64), hinges[:, 3].astype(np.int64)))
    if not np.array_equal(keys[np.minimum(slot, len(keys) - 1)],
                          _edge_keys(hinges[:, 2].astype(np.int64), hinges[:, 3].astype(np.int64))):
        raise ValueError("hinges: every hinge edge (v0, v1) must be an edge of sewn_faces")
    return RestShape(triangle, np.zeros(len(hinges)), mean_length[slot])


def stencils_captured(captured: np.ndarray, faces: np.ndarray, hinges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which stencils have every vertex captured: captured (V,) bool -> triangles (F,), hinges (E,)
    (a boundary hinge never: it has no bending)."""
    captured = np.asarray(captured, dtype=bool)
    triangle = captured[np.asarray(faces)].all(axis=1)
    hinges = np.asarray(hinges, dtype=np.int64)
    hinge = (hinges >= 0).all(axis=1) & captured[np.maximum(hinges, 0)].all(axis=1)
    return triangle, hinge


def usable(shape: RestShape, template: RestShape) -> tuple[np.ndarray, np.ndarray]:
    """Stencils whose measured values can serve as rest: triangles (F,) of at least MIN_AREA_FRACTION
    of their template area, hinges (E,) whose edge is not collapsed (same fraction of its length)."""
    triangle = shape.areas > MIN_AREA_FRACTION * template.areas
    hinge = shape.hinge_length > MIN_AREA_FRACTION * template.hinge_length
    return triangle, hinge


def dynamic_rest(observed: RestShape, observed_triangle: np.ndarray, observed_hinge: np.ndarray,
                 previous: RestShape | None, template: RestShape) -> RestShape:
    """Rules 1 and 2 of the module docstring.

    observed: values measured on the captured positions (meaningful where the masks are true);
    observed_triangle (F,), observed_hinge (E,): stencils with every vertex captured;
    previous: values measured on the previous frame's solved shape, or None (the first frame);
    template: the template's rest shape (`pattern_rest`)."""
    fallback = template
    if previous is not None:
        fallback = previous.where(*usable(previous, template), template)
    ok_triangle, ok_hinge = usable(observed, template)
    return observed.where(observed_triangle & ok_triangle, observed_hinge & ok_hinge, fallback)


def smoothed_rest(observed: RestShape, observed_triangle: np.ndarray, observed_hinge: np.ndarray,
                  before: RestShape | None, after: RestShape | None, template: RestShape) -> RestShape:
    """Rule 3: observed stencils keep their observed value; the others take the mean of the values
    measured on the previous (`before`) and next (`after`) frames' solved shapes (the one there is
    at either end of the sequence; angles averaged on the circle)."""
    sides = [shape.where(*usable(shape, template), template) for shape in (before, after) if shape is not None]
    if not sides:
        raise ValueError("smoothed_rest: needs the previous or the next frame's shape (got neither)")
    mean = RestShape(
        triangle=np.mean([s.triangle for s in sides], axis=0),
        hinge_angle=np.arctan2(np.mean([np.sin(s.hinge_angle) for s in sides], axis=0),
                               np.mean([np.cos(s.hinge_angle) for s in sides], axis=0)),
        hinge_length=np.mean([s.hinge_length for s in sides], axis=0),
    )
    ok_triangle, ok_hinge = usable(observed, template)
    return observed.where(observed_triangle & ok_triangle, observed_hinge & ok_hinge, mean)


def _edge_keys(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Undirected edge keys (N,) int64 of vertex pairs."""
    low, high = np.minimum(a, b), np.maximum(a, b)
    return low * (1 << 31) + high
