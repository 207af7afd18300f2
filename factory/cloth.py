"""Cloth dynamics by projective dynamics (Bouaziz et al. 2014), with the reference's energies.

Model (`ClothModel`, static) and state (`ClothState`: positions, velocities) are separate; a step is
`ProjectiveDynamics.step(state, collider, pin_targets) -> ClothState`.  Implicit Euler: each step
minimises over the new positions x

    E(x) = 1/(2 h^2) (x - y)^T M (x - y)                inertia; y = x_n + h v_n + h^2 g
         + membrane_weight / 2 * sum_t A_t |F_t(x) - R_t|^2    As-Rigid-As-Possible membrane
         + bending_weight / 2 * sum_e 3 / (A_e0 + A_e1) |K_e x|^2    quadratic bending (Bergou 2006)
         + contact_weight / 2 * sum_i a_i max(0, r - d_i(x))^2       penalty contact with a collider
         + pin_weight / 2 * sum_p m_p |x_p - target_p|^2              pinned vertices (tests, hangers)
         + 1 / 2 * sum_s k_s |x_a(s) - x_b(s)|^2                         zero-length springs (sewing)

(air drag scales the velocity in y by 1 / (1 + air_damping h) before the step)
with h the timestep (s), M the lumped masses (kg), A_t the rest area of triangle t (m^2), F_t its
3 x 2 deformation gradient from the flat rest shape (the sewing pattern), R_t the nearest 3 x 2 matrix
with orthonormal columns, K_e the cotangent stencil of the hinge at edge e (4 vertices) in the flat
rest shape, a_i the rest area around vertex i, d_i its signed distance to the collider surface and r
the contact radius.  Units: membrane_weight N/m (energy per area per squared strain), bending_weight
N m (J), contact_weight N/m^3 (energy per area per squared metre of penetration), density g/m^2, spring
stiffnesses k_s N/m.

Local step: R_t the polar factor of F_t (closed form); for each vertex of the step's contact set a plane
along the body's tangent plane, offset by r where the vertex is within r, through the vertex otherwise;
after the last global solve, vertices within r of the collider are moved out to r (`contact_projection`),
except those deep in a fold of the collider (`fold_depth`).
Global step: one sparse symmetric positive definite system per coordinate, all three sharing the matrix;
the matrix changes only when the set of vertices in contact changes (it is then factorised again).  The
contact holds a vertex to its plane along the normal only, so it slides along the body (frictionless, as
the penalty above): that couples the coordinates, and the coupled system is solved by conjugate
gradients preconditioned by the shared matrix, which holds the contact weight in all three directions
(`contact_cg_iterations`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

_REST_EDGES = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])  # (x0, x1, x2) -> (x1 - x0, x2 - x0)


@dataclass(frozen=True)
class ClothParams:
    """The reference's simulation numbers (see the module docstring for how each enters the energy)."""

    timestep: float = 1.0 / 120.0
    membrane_weight: float = 1.0e5
    bending_weight: float = 1.0e-2
    density: float = 1.0e2  # g/m^2
    contact_weight: float = 1.0e8
    contact_radius: float = 1.0e-3
    pin_weight: float = 1.0e8
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    iterations: int = 10
    #: Air drag (1/s): velocities lose this fraction per second, implicitly (v / (1 + c h)).  The
    #: reference names no damping; without any, a hanging cloth swings for tens of seconds, as implicit
    #: Euler at 1/120 s damps slow modes very little.
    air_damping: float = 1.0
    #: Vertices this far (m) outside the contact radius also enter the contact set of a step, so a
    #: vertex that reaches the body during the step is caught.
    contact_margin: float = 5.0e-3
    #: After each step, vertices closer to the collider than the contact radius are moved out to it
    #: along its normal (a position correction; not in the reference).  The penalty alone leaves a
    #: residual depth of force / stiffness, and cannot be made stiffer without freezing cloth that
    #: leaves the body: in projective dynamics an inactive contact still holds a vertex's distance to
    #: the body at its previous iterate's with the full contact weight.
    contact_projection: bool = True
    #: Vertices deeper inside the collider than this (m) are checked for a fold (`MeshCollider.in_fold`:
    #: where the body intersects itself) and, in one, left where they are by the contact projection:
    #: no position there is outside the body, and the nearest body vertex's normal points across the
    #: fold, so projecting moved such a vertex through the other body part.  In the `squat`'s right
    #: armpit at frame 257 that moved one vertex 11 mm and strained its 11 mm edge 1.06 (0.21 without
    #: the projection), and the run stopped.
    fold_depth: float = 2.0e-3
    #: Conjugate-gradient iterations per global step for the contact, which holds a vertex along the
    #: body's normal only (module docstring).  Solved with the shared matrix alone, the contact also
    #: held every contact vertex near its previous iterate along the body, so cloth pressed by a fast
    #: body part could not slide: the `jump`'s cuffs on the swinging forearms stretched 0.36 -> 1.02
    #: over frames 219-224 and stopped the run.  Three iterations run it to its end (two: max strain
    #: 0.92 instead of 0.84), for about 45 % more time per frame.
    contact_cg_iterations: int = 3

    def __post_init__(self):
        if self.contact_cg_iterations < 1:
            raise ValueError(f"ClothParams.contact_cg_iterations must be >= 1, got {self.contact_cg_iterations}")
        if not self.fold_depth >= 0:
            raise ValueError(f"ClothParams.fold_depth must be >= 0 (m), got {self.fold_depth}")


@dataclass(frozen=True)
class ClothState:
    positions: np.ndarray  # (V, 3) metres
    velocities: np.ndarray  # (V, 3) metres per second


def _triangle_frames(rest: np.ndarray) -> np.ndarray:
    """Rest triangles (F, 3, 2) or (F, 3, 3) -> their flat 2D shapes (F, 3, 2) in a per-triangle frame."""
    if rest.shape[-1] == 2:
        return rest
    e1 = rest[:, 1] - rest[:, 0]
    e2 = rest[:, 2] - rest[:, 0]
    u = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    n = np.cross(e1, e2)
    v = np.cross(n / np.linalg.norm(n, axis=1, keepdims=True), u)
    local = rest - rest[:, :1]
    return np.stack([np.einsum("fjk,fk->fj", local, u), np.einsum("fjk,fk->fj", local, v)], axis=2)


def _hinges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges: (E, 2) the two faces sharing each edge, and (E, 4) local corner indices
    (edge start and end in the first face, the opposite corner in the first face, in the second)."""
    corner_a = np.repeat(np.arange(3)[None], len(faces), 0).ravel()
    face = np.repeat(np.arange(len(faces)), 3)
    a = faces[face, corner_a]
    b = faces[face, (corner_a + 1) % 3]
    key = np.minimum(a, b).astype(np.int64) * (faces.max() + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    same = key[order][1:] == key[order][:-1]
    first, second = order[:-1][same], order[1:][same]
    f0, f1 = face[first], face[second]
    c0 = corner_a[first]
    # corner in f1 opposite the shared edge: the one that is neither endpoint
    v0, v1 = a[first], b[first]
    opposite1 = np.argmax((faces[f1] != v0[:, None]) & (faces[f1] != v1[:, None]), axis=1)
    return np.stack([f0, f1], 1), np.stack([c0, (c0 + 1) % 3, (c0 + 2) % 3, opposite1], 1)


def nearest_rotations(deformation: np.ndarray) -> np.ndarray:
    """The nearest 3 x 2 matrices with orthonormal columns (F, 3, 2) to `deformation` (F, 3, 2): the
    polar factor F (F^T F)^(-1/2), in closed form for the 2 x 2 square root (10x faster than an SVD
    per triangle); triangles collapsed to a line or point fall back to the SVD."""
    c = np.einsum("fki,fkj->fij", deformation, deformation)  # F^T F
    root_det = np.sqrt(np.maximum(c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2, 0.0))
    trace = np.sqrt(np.maximum(c[:, 0, 0] + c[:, 1, 1] + 2.0 * root_det, 1e-300))
    # sqrt(C) = (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C)); its inverse in closed form
    a = (c[:, 0, 0] + root_det) / trace
    d = (c[:, 1, 1] + root_det) / trace
    b = c[:, 0, 1] / trace
    det = a * d - b * b
    good = det > 1e-12 * np.maximum(a * d, 1e-300)
    inverse = np.stack([np.stack([d, -b], -1), np.stack([-b, a], -1)], -2) / np.where(good, det, 1.0)[:, None, None]
    out = deformation @ inverse
    if not good.all():
        u, _, vt = np.linalg.svd(deformation[~good], full_matrices=False)
        out[~good] = u @ vt
    return out


def _cot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cotangent of the angle between 2D vectors a and b (..., 2)."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return np.sum(a * b, axis=-1) / np.abs(cross)


@dataclass(frozen=True, eq=False)
class ClothModel:
    """Static cloth data: faces (F, 3), masses (V,), vertex areas (V,), triangle rest areas (F,),
    the membrane operator G (2F x V) with F_t columns = G X, and the bending matrix Q (V x V)."""

    faces: np.ndarray
    masses: np.ndarray
    vertex_areas: np.ndarray
    areas: np.ndarray
    gradient: sp.csr_matrix
    bending: sp.csr_matrix
    params: ClothParams
    rest_edge_lengths: np.ndarray  # (F, 3) length of edge (k, k+1) of each triangle at rest

    @classmethod
    def build(cls, faces: np.ndarray, rest: np.ndarray, params: ClothParams = ClothParams()) -> "ClothModel":
        """`rest`: per-face rest corners (F, 3, 2) in pattern metres, or rest positions (V, 3)."""
        faces = np.asarray(faces, dtype=np.int64)
        count = int(faces.max()) + 1
        rest = np.asarray(rest, dtype=np.float64)
        corners = _triangle_frames(rest[faces] if rest.ndim == 2 else rest)  # (F, 3, 2)
        edges = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=2)  # (F, 2, 2)
        det = edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]
        if np.any(np.abs(det) < 1e-14):
            raise ValueError(f"cloth: {int((np.abs(det) < 1e-14).sum())} degenerate rest triangles")
        areas = 0.5 * np.abs(det)
        stencil = _REST_EDGES @ np.linalg.inv(edges)  # (F, 3, 2): F_t = X_t^T stencil_t
        rows = (2 * np.arange(len(faces))[:, None, None] + np.arange(2)[None, None, :]).repeat(3, 1)
        cols = np.broadcast_to(faces[:, :, None], rows.shape)
        gradient = sp.csr_matrix((stencil.ravel(), (rows.ravel(), cols.ravel())), shape=(2 * len(faces), count))
        vertex_areas = np.bincount(faces.ravel(), np.repeat(areas / 3.0, 3), minlength=count)
        masses = vertex_areas * params.density * 1e-3
        bending = _bending_matrix(faces, corners, areas, count)
        lengths = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2)
        return cls(faces, masses, vertex_areas, areas, gradient, bending, params, lengths)

    @property
    def num_vertices(self) -> int:
        return len(self.masses)

    def membrane_matrix(self) -> sp.csr_matrix:
        weights = sp.diags(np.repeat(self.areas, 2))
        return (self.gradient.T @ weights @ self.gradient).tocsr()

    def deformation(self, positions: np.ndarray) -> np.ndarray:
        """Deformation gradients (F, 3, 2) of positions (V, 3)."""
        return (self.gradient @ positions).reshape(-1, 2, 3).transpose(0, 2, 1)

    def edge_length_strain(self, positions: np.ndarray) -> np.ndarray:
        """(F, 3) length / rest length - 1 of every triangle edge: the health check's edge strain."""
        tri = positions[self.faces]
        return np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2) / self.rest_edge_lengths - 1.0

    def edge_strain(self, positions: np.ndarray) -> np.ndarray:
        """Largest principal stretch minus 1 per triangle (F,): 0.05 is 5 % stretched."""
        singular = np.linalg.svd(self.deformation(positions), compute_uv=False)
        return np.maximum(singular[:, 0] - 1.0, 1.0 - singular[:, 1])


def _bending_matrix(faces: np.ndarray, corners: np.ndarray, areas: np.ndarray, count: int) -> sp.csr_matrix:
    """Q = sum_e 3 / (A_e0 + A_e1) K_e^T K_e over interior edges (Bergou et al. 2006), flat rest."""
    pair, local = _hinges(faces)
    f0, f1 = pair[:, 0], pair[:, 1]
    p = corners[f0]  # (E, 3, 2)
    e = np.arange(len(f0))
    x0, x1, x2 = p[e, local[:, 0]], p[e, local[:, 1]], p[e, local[:, 2]]
    # Each triangle's angles come from its own rest frame: cotangents are intrinsic.
    q = corners[f1]
    v0 = faces[f0, local[:, 0]]
    v1 = faces[f0, local[:, 1]]
    i0 = np.argmax(faces[f1] == v0[:, None], axis=1)
    i1 = np.argmax(faces[f1] == v1[:, None], axis=1)
    y0, y1, y3 = q[e, i0], q[e, i1], q[e, local[:, 3]]
    cot_a0 = _cot(x1 - x0, x2 - x0)  # angle at x0 in the first triangle
    cot_a1 = _cot(x0 - x1, x2 - x1)
    cot_b0 = _cot(y1 - y0, y3 - y0)
    cot_b1 = _cot(y0 - y1, y3 - y1)
    k = np.stack([cot_a1 + cot_b1, cot_a0 + cot_b0, -(cot_a0 + cot_a1), -(cot_b0 + cot_b1)], axis=1)
    verts = np.stack([v0, v1, faces[f0, local[:, 2]], faces[f1, local[:, 3]]], axis=1)
    scale = 3.0 / (areas[f0] + areas[f1])
    values = scale[:, None, None] * k[:, :, None] * k[:, None, :]
    rows = np.broadcast_to(verts[:, :, None], values.shape)
    cols = np.broadcast_to(verts[:, None, :], values.shape)
    return sp.csr_matrix((values.ravel(), (rows.ravel(), cols.ravel())), shape=(count, count))


class MeshCollider:
    """A closed triangle mesh the cloth stays outside of, for one frame: signed distance to the tangent
    plane of the nearest vertex (vertex normals), accurate near the surface where contact happens."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import trimesh

        mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), faces, process=False)
        self.mesh = mesh
        self.vertices = mesh.vertices.view(np.ndarray)
        self.normals = mesh.vertex_normals.view(np.ndarray)
        self.tree = cKDTree(self.vertices)
        #: per probe offset of `in_fold`, (V,) int8 per body vertex: 1 inside the mesh when moved out by
        #: the offset, 0 not, -1 not tested yet (the step's projection and the health check ask alike)
        self._probed: dict[float, np.ndarray] = {}

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (N,) (negative inside) and outward normals (N, 3) at points (N, 3)."""
        _, nearest = self.tree.query(points)
        normals = self.normals[nearest]
        return np.einsum("nk,nk->n", points - self.vertices[nearest], normals), normals

    def in_fold(self, points: np.ndarray, radius: float = 0.02, offset: float = 0.002) -> np.ndarray:
        """(N,) bool: the points (N, 3) near where the mesh intersects itself, where no position is
        outside it (a thigh running into the belly as the hips flex: linear blend skinning lets body
        parts pass into each other).  A point is in a fold when a mesh vertex within `radius` (m), moved
        `offset` (m) outward along its normal, lies inside the mesh (its winding number; a mesh that is
        not watertight has no inside, and nothing is in a fold).  Each body vertex is tested once per
        collider, in one winding-number call for the vertices not tested before."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not len(points) or not self.mesh.is_watertight:
            return np.zeros(len(points), bool)
        near = self.tree.query_ball_point(points, radius)
        owner = np.repeat(np.arange(len(points)), [len(n) for n in near])  # (pairs,) the point of each pair
        vertex = np.concatenate([np.asarray(n, np.int64) for n in near])
        if not len(vertex):
            return np.zeros(len(points), bool)
        known = self._probed.setdefault(offset, np.full(len(self.vertices), -1, np.int8))
        new = np.unique(vertex[known[vertex] < 0])
        if len(new):
            known[new] = self.mesh.contains(self.vertices[new] + offset * self.normals[new])
        return np.bincount(owner, weights=known[vertex], minlength=len(points)) > 0


class ProjectiveDynamics:
    """Local-global solver for `ClothModel` (see the module docstring)."""

    def __init__(self, model: ClothModel, pinned: np.ndarray | None = None,
                 springs: np.ndarray | None = None, spring_stiffness: np.ndarray | float = 0.0):
        """`pinned` (V,) bool; `springs` (S, 2) vertex pairs joined by zero-length springs of
        `spring_stiffness` (N/m, scalar or (S,)); see `set_spring_stiffness`."""
        self.model = model
        p = model.params
        n = model.num_vertices
        self.pinned = np.zeros(n, bool) if pinned is None else np.asarray(pinned, bool)
        self.springs = np.zeros((0, 2), np.int64) if springs is None else np.asarray(springs, np.int64).reshape(-1, 2)
        # Laplacian-like incidence: D x gives x_a - x_b per spring
        rows = np.repeat(np.arange(len(self.springs)), 2)
        values = np.tile([1.0, -1.0], len(self.springs))
        self._spring_incidence = sp.csr_matrix((values, (rows, self.springs.ravel())), shape=(len(self.springs), n))
        self._fixed = (
            sp.diags(model.masses / p.timestep**2)
            + p.membrane_weight * model.membrane_matrix()
            + p.bending_weight * model.bending
            + sp.diags(p.pin_weight * model.masses * self.pinned)
        ).tocsc()
        self.set_spring_stiffness(spring_stiffness)

    def set_spring_stiffness(self, stiffness: np.ndarray | float) -> None:
        """Change the springs' stiffness (N/m); the system is factorised again on the next step."""
        self.spring_stiffness = np.broadcast_to(np.asarray(stiffness, np.float64), (len(self.springs),)).copy()
        d = self._spring_incidence
        self.base = (self._fixed + d.T @ sp.diags(self.spring_stiffness) @ d).tocsc()
        self._contact_key = None
        self._factor = None

    def spring_lengths(self, x: np.ndarray) -> np.ndarray:
        """(S,) current spring lengths (m)."""
        return np.linalg.norm(x[self.springs[:, 0]] - x[self.springs[:, 1]], axis=1)

    def _solver(self, contact: np.ndarray):
        key = np.packbits(contact).tobytes()
        if key != self._contact_key:
            p = self.model.params
            matrix = self.base + sp.diags(p.contact_weight * self.model.vertex_areas * contact)
            self._factor = spla.splu(matrix.tocsc(), permc_spec="MMD_AT_PLUS_A")
            self._contact_key = key
        return self._factor

    def _solve_sliding(self, factor, rhs: np.ndarray, x: np.ndarray, contact: np.ndarray, weights: np.ndarray,
                       normals: np.ndarray) -> np.ndarray:
        """The global step with the contact along the normals only: positions (V, 3) solving
        (Q + sum_i w_i n_i n_i^T) x = rhs, Q the matrix without contact, by conjugate gradients from `x`
        (the previous iterate), preconditioned by `factor` (Q + sum_i w_i I).  `contact` (V,) bool; the
        contact vertices' `weights` w_i (C,) N/m and `normals` n_i (C, 3)."""

        def apply(v: np.ndarray) -> np.ndarray:
            out = self.base @ v
            out[contact] += (weights * np.einsum("nk,nk->n", normals, v[contact]))[:, None] * normals
            return out

        iterations = self.model.params.contact_cg_iterations
        residual = rhs - apply(x)
        z = factor.solve(residual)
        direction, rz = z, np.sum(residual * z)
        for k in range(iterations):
            if rz <= 0.0:  # x solves the system already
                break
            product = apply(direction)
            step = rz / np.sum(direction * product)
            x = x + step * direction
            if k + 1 == iterations:
                break
            residual = residual - step * product
            z = factor.solve(residual)
            rz, previous = np.sum(residual * z), rz
            direction = z + (rz / previous) * direction
        return x

    def energy(self, x: np.ndarray, inertia_target: np.ndarray, pin_targets: np.ndarray | None = None,
               collider: MeshCollider | None = None) -> float:
        """E(x) of the module docstring (joules) for the step whose inertia target is `inertia_target`."""
        m, p = self.model, self.model.params
        value = 0.5 / p.timestep**2 * np.sum(m.masses[:, None] * (x - inertia_target) ** 2)
        deformation = m.deformation(x)
        value += 0.5 * p.membrane_weight * np.sum(m.areas[:, None, None] * (deformation - nearest_rotations(deformation)) ** 2)
        value += 0.5 * p.bending_weight * np.sum(x * (m.bending @ x))
        value += 0.5 * np.sum(self.spring_stiffness * self.spring_lengths(x) ** 2)
        if pin_targets is not None:
            value += 0.5 * p.pin_weight * np.sum(m.masses[self.pinned, None] * (x[self.pinned] - pin_targets) ** 2)
        if collider is not None:
            d, _ = collider.signed_distance(x)
            value += 0.5 * p.contact_weight * np.sum(m.vertex_areas * np.maximum(0.0, p.contact_radius - d) ** 2)
        return float(value)

    def step(self, state: ClothState, collider: MeshCollider | None = None,
             pin_targets: np.ndarray | None = None, energies: list[float] | None = None) -> ClothState:
        """Advance one timestep.  `pin_targets` (P, 3): where the pinned vertices are held this step
        (required when any are pinned); `energies`, when given, receives E(x) after every global
        solve (for tests)."""
        m, p = self.model, self.model.params
        h = p.timestep
        x0 = state.positions
        y = x0 + h * state.velocities / (1.0 + p.air_damping * h) + h * h * np.asarray(p.gravity)
        if self.pinned.any() and (pin_targets is None or np.shape(pin_targets) != (int(self.pinned.sum()), 3)):
            raise ValueError(f"cloth step: pin_targets must be ({int(self.pinned.sum())}, 3) for the pinned vertices")
        contact = np.zeros(m.num_vertices, bool)
        if collider is not None:
            d_start, _ = collider.signed_distance(y)
            contact = d_start < p.contact_radius + p.contact_margin
        factor = self._solver(contact)
        contact_weights = p.contact_weight * m.vertex_areas[contact]
        inertia_rhs = (m.masses / h**2)[:, None] * y
        pin_rhs = np.zeros_like(y)
        pin_rhs[self.pinned] = p.pin_weight * m.masses[self.pinned, None] * pin_targets
        x = y.copy()
        area_weights = np.repeat(m.areas, 2)[:, None]
        for _ in range(p.iterations):
            rotations = nearest_rotations(m.deformation(x)).transpose(0, 2, 1).reshape(-1, 3)  # row 2t+k: column k of R_t
            rhs = inertia_rhs + pin_rhs + p.membrane_weight * (m.gradient.T @ (area_weights * rotations))
            if contact.any():
                d, normals = collider.signed_distance(x[contact])
                offsets = np.einsum("nk,nk->n", normals, x[contact]) + np.maximum(0.0, p.contact_radius - d)
                rhs[contact] += (contact_weights * offsets)[:, None] * normals
                x = self._solve_sliding(factor, rhs, x, contact, contact_weights, normals)
            else:
                x = factor.solve(rhs)
            if energies is not None:
                energies.append(self.energy(x, y, pin_targets if self.pinned.any() else None, collider))
        if collider is not None and p.contact_projection:
            d, normals = collider.signed_distance(x)
            close = d < p.contact_radius
            deep = np.flatnonzero(d < -p.fold_depth)
            close[deep[collider.in_fold(x[deep])]] = False
            x[close] += (p.contact_radius - d[close])[:, None] * normals[close]
        return ClothState(positions=x, velocities=(x - x0) / h)
