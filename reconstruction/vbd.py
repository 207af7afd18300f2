"""One template level as a Newton VBD cloth for the post-processing: anchors, membrane, bending and
barrier self-contact, solved quasi-statically.

Energies (weights from `reconstruction.refinement.RefineConfig`, the reference's numbers):
- anchors: a zero-rest-length spring of stiffness `anchor_weight` (N/m) from every captured vertex to a
  kinematic anchor particle (mass 0) at its target; targets are written into `state.particle_q`, and
  an uncaptured vertex's spring has stiffness 0.  The anchor particles live in a Newton world of their
  own (world 1, the cloth is world 0): Newton's self-contact only pairs a vertex with triangles of its
  own world, so anchors never collide with the cloth they pull.
- membrane: Newton's VBD cloth triangle, stable Neo-Hookean (not StVK) with Lame parameters
  mu = `membrane_mu`, lambda = `membrane_lambda` (N/m: energy per rest area), rest shape per triangle
  from `RestShape` (`model.tri_poses`, `model.tri_areas`).
- bending: Newton's dihedral-angle bending, 1/2 `bending_weight` L (theta - theta_rest)^2 per hinge of
  rest length L (`model.edge_rest_angle`, `model.edge_rest_length`).
- contact: Newton's vertex-triangle and edge-edge barrier self-contact, stiffness `contact_weight`
  (`model.soft_contact_ke`, N/m), interaction distance `contact_radius`, frictionless, with Newton's
  conservative (divide-and-truncate) step bounds, so a shape that starts free of intersections stays
  so.  Detection queries `contact_radius + contact_gap` once per step, before it: with detection
  before every iteration (Newton 1.8's ITERATIONS schedule) we measured vertices crossing triangles
  within a step under the stiff anchors, never with one detection per step.  So one step moves a
  vertex at most 0.425 (radius + gap): many short steps of few iterations.  Self-contact skips pairs
  of topological neighbours within `contact_filter_rings` rings (the caller chooses: 1 where every
  triangle is taller than the query, so that folds at seams are caught, else Newton's default 2).
- inertia: lumped masses from the sewing pattern's areas at `density_g_m2`, over a pseudo-time step
  `timestep`; velocities are reset before every step, so each step is a quasi-static solve (the
  inertia only damps it; no gravity: the captured shape already shows its effect).
"""

from __future__ import annotations

import logging

import numpy as np

from reconstruction.restshape import RestShape

log = logging.getLogger(__name__)


class ClothSolver:
    """A Newton VBD model and solver of one level's sewn mesh (V vertices, F faces) plus V anchors.

    faces (F, 3) int: the sewn mesh; positions (V, 3): any shape in which no triangle is degenerate
    (Newton drops those; its rest shape is this shape's until `set_rest`); vertex_mass (V,) kg;
    weights as in the module docstring (N/m, N m, m, s); contact_filter_rings: self-contact ignores
    vertex-triangle and edge-edge pairs within this many rings of each other (Newton's topological
    filter; below 2 only a triangle's own vertices and edges).  device: warp's device for the model and
    the solve ("cpu", "cuda", "cuda:1"); positions go in and come out as host arrays either way.
    `hinges` (E, 4): Newton's bending edges (o0, o1, v0, v1), the order `set_rest` expects."""

    def __init__(self, faces: np.ndarray, positions: np.ndarray, vertex_mass: np.ndarray, *,
                 anchor_weight: float, membrane_mu: float, membrane_lambda: float, bending_weight: float,
                 contact_weight: float, contact_radius: float, contact_gap: float, timestep: float,
                 iterations: int, contact_filter_rings: int = 2, device: str = "cpu"):
        import newton
        import warp as wp

        if str(device).startswith("cuda") and not wp.is_cuda_available():
            raise ValueError(f"refine device {device!r}: warp sees no CUDA device here (use --device cpu)")
        self.device = str(device)

        faces = np.asarray(faces, dtype=np.int64)
        positions = np.asarray(positions, dtype=np.float64)
        n = len(positions)
        self.num_vertices, self.anchor_weight, self.timestep = n, float(anchor_weight), float(timestep)
        self._wp = wp
        with wp.ScopedDevice(self.device):
            builder = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=(0.0, 0.0, 0.0))
            builder.begin_world()
            builder.add_cloth_mesh(
                pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                vertices=positions, indices=faces.ravel(), density=0.0, tri_ke=membrane_mu, tri_ka=membrane_lambda,
                tri_kd=0.0, edge_ke=bending_weight, edge_kd=0.0, particle_radius=contact_radius,
            )
            builder.end_world()
            if len(builder.tri_indices) != len(faces):
                raise ValueError(f"positions: Newton dropped {len(faces) - len(builder.tri_indices)} triangles that "
                                 "are degenerate in the shape the cloth was built from")
            builder.particle_mass = np.asarray(vertex_mass, dtype=np.float64).tolist()
            builder.begin_world()  # the anchors: a world of their own, so self-contact ignores them
            builder.add_particles(pos=positions.tolist(), vel=[(0.0, 0.0, 0.0)] * n, mass=[0.0] * n,
                                  radius=[contact_radius] * n)
            builder.end_world()
            # what builder.add_spring appends, for all V springs at once: vertex i to anchor V + i,
            # rest length 0, stiffness set per solve
            builder.spring_indices.extend(np.stack([np.arange(n), n + np.arange(n)], axis=1).ravel().tolist())
            builder.spring_rest_length.extend([0.0] * n)
            builder.spring_stiffness.extend([0.0] * n)
            builder.spring_damping.extend([0.0] * n)
            builder.spring_control.extend([0.0] * n)
            self.hinges = np.asarray(builder.edge_indices, dtype=np.int64).reshape(-1, 4)
            builder.color(include_bending=True)
            self.model = builder.finalize(device=self.device)
            self.model.soft_contact_ke = float(contact_weight)
            self.model.soft_contact_kd = 0.0
            self.model.soft_contact_mu = 0.0
            slot, kind = newton.solvers.SolverBase.CollisionSlot, newton.solvers.SolverBase.CollisionFrequencyType
            self.solver = newton.solvers.SolverVBD(
                self.model, iterations=iterations, particle_enable_self_contact=True,
                particle_self_contact_margin=contact_radius, particle_self_contact_gap=contact_gap,
                particle_topological_contact_filter_threshold=contact_filter_rings,
                collision_frequency_type={slot.SOFT_SELF_CONTACT: kind.PRE_INIT},
            )
            self.state, self.next_state = self.model.state(), self.model.state()
            self.control = self.model.control()

    def set_rest(self, rest: RestShape) -> None:
        """Write a rest shape (triangles in face order, hinges in `self.hinges` order) into the model."""
        if rest.triangle.shape[0] != self.model.tri_count or rest.hinge_angle.shape[0] != len(self.hinges):
            raise ValueError(f"rest: expected {self.model.tri_count} triangles and {len(self.hinges)} hinges, got "
                             f"{rest.triangle.shape[0]} and {rest.hinge_angle.shape[0]}")
        self.model.tri_poses.assign(rest.poses.astype(np.float32))
        self.model.tri_areas.assign(rest.areas.astype(np.float32))
        self.model.edge_rest_angle.assign(rest.hinge_angle.astype(np.float32))
        self.model.edge_rest_length.assign(rest.hinge_length.astype(np.float32))

    def solve(self, positions: np.ndarray, targets: np.ndarray, captured: np.ndarray, steps: int,
              anchor_weight: float | None = None) -> np.ndarray:
        """`steps` quasi-static VBD steps from `positions` (V, 3) with the captured (V,) vertices pulled
        to `targets` (V, 3) (anchor_weight N/m, default the model's); returns the positions (V, 3)
        float64."""
        n = self.num_vertices
        captured = np.asarray(captured, dtype=bool)
        weight = self.anchor_weight if anchor_weight is None else float(anchor_weight)
        q = np.concatenate([positions, np.where(captured[:, None], targets, positions)]).astype(np.float32)
        with self._wp.ScopedDevice(self.device):
            self.state.particle_q.assign(q)
            self.model.spring_stiffness.assign(np.where(captured, weight, 0.0).astype(np.float32))
            self.solver.rebuild_bvh(self.state)
            for _ in range(steps):
                self.state.particle_qd.zero_()
                self.solver.step(self.state, self.next_state, self.control, None, self.timestep)
                self.state, self.next_state = self.next_state, self.state
            out = self.state.particle_q.numpy()[:n].astype(np.float64)
        if not np.isfinite(out).all():
            raise FloatingPointError(f"newton vbd: {int((~np.isfinite(out)).any(axis=1).sum())} vertices became "
                                     "non-finite")
        return out
