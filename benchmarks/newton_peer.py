"""The benchmark's peer for our projective-dynamics cloth (`factory.cloth`): the same garment on the same
moving body, simulated by Newton's Vertex Block Descent solver (`newton.solvers.SolverVBD`) on the CPU.

Our parameters are mapped onto Newton's so that both solvers minimise, to first order, the same energy
(see `factory.cloth` for ours):

- Mass: lumped, a third of each pattern triangle's area per corner, kg = m^2 * density_g_m2 * 1e-3.
- Membrane: ours is As-Rigid-As-Possible, membrane_weight / 2 * A |F - R|^2; for small strain e that is
  membrane_weight / 2 * |e|^2 per area, the linear-elastic energy mu |e|^2 + lambda / 2 tr(e)^2 with
  mu = membrane_weight / 2 and lambda = 0.  Newton's cloth triangles are stable Neo-Hookean with Lame
  parameters (tri_ke = mu, tri_ka = lambda), linearising to the same energy: tri_ke = membrane_weight / 2,
  tri_ka = 0, no damping (tri_kd = 0).  The rest shape is the flat sewing pattern: each triangle's
  inverse 2 x 2 rest matrix and rest area come from `rest_corners`, not from `start_positions`.
- Bending: ours is the quadratic hinge energy bending_weight / 2 * 3 / (A0 + A1) |K_e x|^2 with a flat
  rest, which is bending_weight / 2 * 3 L^2 / (A0 + A1) * theta^2 for a hinge of length L bent by a
  small angle theta.  Newton's dihedral bending is edge_ke / 2 * L * (theta - rest)^2, so each hinge
  gets edge_ke = 3 * bending_weight * L / (A0 + A1) (pattern lengths and areas), rest angle 0 and no
  damping.  A single edge_ke = bending_weight would make bending about 3 / h times softer than ours on
  a mesh of edge length h (x250 at 12 mm).
- Contact: ours is contact_weight / 2 * a_i * max(0, r - d_i)^2, a spring of stiffness
  contact_weight * a_i (N/m) per vertex of rest area a_i.  Newton's body-particle contact is a penalty
  spring of one stiffness for all particles, contact_weight times the median vertex area, acting when
  a particle comes closer than its radius r = contact_radius to the body surface (shape margin 0).
  Frictionless and undamped, as ours.  Contacts are detected once per substep, including every particle
  within r + gap of the surface (gap: the larger of 5 mm and twice the body's largest displacement per
  substep), by Newton's collision pipeline, which the solver owns.
- Gravity (0, 0, -9.81) m/s^2, Z up.  No self-contact (ours has none).  Newton's implicit Euler damps
  like ours; our air drag has no counterpart.

VBD runs a fixed number of Gauss-Seidel sweeps per substep, not to convergence: with the membrane this
much stiffer than gravity, a fine mesh stays stretched by a few per cent and fast-moving cloth sinks a
few millimetres into the body at 5 substeps x 10 iterations; more of either reduces both.

The body is a static triangle-mesh shape whose Warp mesh is rewritten at every substep, interpolating
linearly between the body's frames, and refitted; its vertex velocities are set per frame.
"""

from __future__ import annotations

import logging
import time

import newton
import numpy as np
import warp as wp
from tqdm import tqdm

logger = logging.getLogger(__name__)

GRAVITY = (0.0, 0.0, -9.81)  # m/s^2, Z up
MIN_CONTACT_GAP = 5.0e-3  # m, detection slack beyond the contact radius (our contact_margin)


def _check_inputs(
    faces: np.ndarray,
    rest_corners: np.ndarray,
    start_positions: np.ndarray,
    body_vertices: np.ndarray,
    body_faces: np.ndarray,
    timestep: float,
    substeps: int,
    iterations: int,
) -> None:
    """Raise ValueError naming the first argument whose shape or range is inconsistent."""
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces: expected (F, 3) with F > 0, got {faces.shape}")
    if rest_corners.shape != (len(faces), 3, 2):
        raise ValueError(
            f"rest_corners: expected {(len(faces), 3, 2)} (one flat triangle per face), got {rest_corners.shape}"
        )
    if start_positions.ndim != 2 or start_positions.shape[1] != 3:
        raise ValueError(f"start_positions: expected (V, 3), got {start_positions.shape}")
    if faces.min() < 0 or faces.max() >= len(start_positions):
        raise ValueError(
            f"faces: indices must lie in [0, {len(start_positions)}) (rows of start_positions), "
            f"got [{faces.min()}, {faces.max()}]"
        )
    if body_vertices.ndim != 3 or body_vertices.shape[2] != 3 or len(body_vertices) == 0:
        raise ValueError(f"body_vertices: expected (T, Vb, 3) with T > 0, got {body_vertices.shape}")
    if body_faces.ndim != 2 or body_faces.shape[1] != 3 or len(body_faces) == 0:
        raise ValueError(f"body_faces: expected (Fb, 3) with Fb > 0, got {body_faces.shape}")
    if body_faces.min() < 0 or body_faces.max() >= body_vertices.shape[1]:
        raise ValueError(
            f"body_faces: indices must lie in [0, {body_vertices.shape[1]}) (body_vertices' Vb), "
            f"got [{body_faces.min()}, {body_faces.max()}]"
        )
    arrays = {"rest_corners": rest_corners, "start_positions": start_positions, "body_vertices": body_vertices}
    for name, values in arrays.items():
        if not np.isfinite(values).all():
            raise ValueError(f"{name}: expected finite values")
    if timestep <= 0.0 or substeps < 1 or iterations < 1:
        raise ValueError(
            f"timestep > 0, substeps >= 1 and iterations >= 1 expected, got {timestep}, {substeps}, {iterations}"
        )


def _pattern_geometry(rest_corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat rest triangles (F, 3, 2) m -> inverse rest matrices (F, 2, 2), areas (F,) m^2 and edge
    lengths (F, 3) m, length k of the edge from corner k to corner k + 1."""
    edges = np.stack([rest_corners[:, 1] - rest_corners[:, 0], rest_corners[:, 2] - rest_corners[:, 0]], 2)
    det = np.linalg.det(edges)
    if np.any(np.abs(det) < 1e-14):
        raise ValueError(f"rest_corners: {int((np.abs(det) < 1e-14).sum())} degenerate rest triangles")
    # Newton's F = [x1 - x0, x2 - x0] @ pose with pose = D^-1, D's columns the rest edges in any 2D
    # frame; a mirrored frame gives the same |F| and area ratio, so the pattern's winding is irrelevant.
    poses = np.linalg.inv(edges)
    lengths = np.linalg.norm(rest_corners[:, [1, 2, 0]] - rest_corners, axis=2)
    return poses, 0.5 * np.abs(det), lengths


def _hinge_stiffness(
    faces: np.ndarray, areas: np.ndarray, lengths: np.ndarray, edge_indices: np.ndarray, bending_weight: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per Newton edge (E, 4) (opposite 0, opposite 1, start, end): pattern rest length (E,) m, the mean
    over the faces sharing it, and edge_ke (E,) N = 3 bending_weight L / (A0 + A1); 0 on the boundary."""
    count = int(faces.max()) + 1
    start, end = faces, faces[:, [1, 2, 0]]
    face_keys = (np.minimum(start, end).astype(np.int64) * count + np.maximum(start, end)).ravel()
    keys, inverse = np.unique(face_keys, return_inverse=True)
    uses = np.bincount(inverse, minlength=len(keys))
    rest_length = np.bincount(inverse, lengths.ravel(), minlength=len(keys)) / uses
    hinge_area = np.bincount(inverse, np.repeat(areas, 3), minlength=len(keys))
    a, b = edge_indices[:, 2], edge_indices[:, 3]
    slot = np.searchsorted(keys, np.minimum(a, b).astype(np.int64) * count + np.maximum(a, b))
    interior = (edge_indices[:, 0] >= 0) & (edge_indices[:, 1] >= 0)
    edge_ke = np.where(interior, 3.0 * bending_weight * rest_length[slot] / hinge_area[slot], 0.0)
    return rest_length[slot], edge_ke


def _build_model(
    faces: np.ndarray,
    rest_corners: np.ndarray,
    start_positions: np.ndarray,
    body_start: np.ndarray,
    body_faces: np.ndarray,
    *,
    density_g_m2: float,
    membrane_weight: float,
    bending_weight: float,
    contact_radius: float,
    contact_weight: float,
) -> tuple[newton.Model, newton.Mesh]:
    """The garment (particles 0..V-1, triangles in `faces` order) and the body as a static mesh shape
    with its Warp mesh at `body_start` (Vb, 3); parameters mapped as the module docstring says."""
    poses, areas, lengths = _pattern_geometry(rest_corners)
    vertex_areas = np.bincount(faces.ravel(), np.repeat(areas / 3.0, 3), minlength=len(start_positions))
    contact_ke = contact_weight * float(np.median(vertex_areas[vertex_areas > 0.0]))
    builder = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=GRAVITY)
    builder.add_cloth_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=start_positions,
        indices=faces.ravel(),
        density=0.0,
        tri_ke=0.5 * membrane_weight,
        tri_ka=0.0,
        tri_kd=0.0,
        edge_ke=0.0,  # per hinge below
        edge_kd=0.0,
        particle_radius=contact_radius,
    )
    if len(builder.tri_indices) != len(faces):
        raise ValueError(
            f"start_positions: Newton dropped {len(faces) - len(builder.tri_indices)} triangles that are "
            "degenerate in the dressed shape"
        )
    # Rest shape from the sewing pattern instead of the dressed positions add_cloth_mesh used.
    builder.particle_mass = (vertex_areas * density_g_m2 * 1e-3).tolist()
    builder.tri_poses = poses.tolist()
    builder.tri_areas = areas.tolist()
    edge_indices = np.asarray(builder.edge_indices, dtype=np.int64)
    rest_length, edge_ke = _hinge_stiffness(faces, areas, lengths, edge_indices, bending_weight)
    builder.edge_rest_angle = [0.0] * len(edge_indices)
    builder.edge_rest_length = rest_length.tolist()
    builder.edge_bending_properties = [(ke, 0.0) for ke in edge_ke.tolist()]

    body_mesh = newton.Mesh(body_start, body_faces.ravel(), compute_inertia=False)
    builder.add_shape_mesh(
        -1,
        mesh=body_mesh,
        cfg=newton.ModelBuilder.ShapeConfig(
            ke=contact_ke, kd=0.0, mu=0.0, margin=0.0, gap=0.0, has_shape_collision=False
        ),
        label="body",
    )
    builder.color(include_bending=True)
    model = builder.finalize(device="cpu")
    # Body-particle contacts use the mean of these and the shape's material; make both ours.
    model.soft_contact_ke = contact_ke
    model.soft_contact_kd = 0.0
    model.soft_contact_mu = 0.0
    return model, body_mesh


def simulate_vbd(
    faces: np.ndarray,
    rest_corners: np.ndarray,
    start_positions: np.ndarray,
    body_vertices: np.ndarray,
    body_faces: np.ndarray,
    *,
    timestep: float = 1 / 120,
    density_g_m2: float = 100.0,
    membrane_weight: float = 1e5,
    bending_weight: float = 1e-2,
    contact_radius: float = 1e-3,
    contact_weight: float = 1e8,
    substeps: int = 5,
    iterations: int = 10,
    progress: bool = True,
) -> tuple[np.ndarray, float, float]:
    """Simulate the garment on the moving body with Newton's VBD on the CPU.

    Args:
        faces: (F, 3) int, the sewn garment mesh.
        rest_corners: (F, 3, 2) float64, each triangle's flat rest shape in metres (the sewing pattern).
        start_positions: (V, 3) float64, garment positions (m) at frame 0, dressed, outside the body.
        body_vertices: (T, Vb, 3) float32, the body mesh (m) per frame, one frame per `timestep`;
            frame 0 matches start_positions.
        body_faces: (Fb, 3) int, closed body mesh, outward (counter-clockwise) winding.
        timestep: seconds between body frames; each frame is `substeps` solver steps.
        density_g_m2, membrane_weight (N/m), bending_weight (N m), contact_radius (m), contact_weight
            (N/m^3): our cloth parameters (`factory.cloth.ClothParams`), mapped as the module says.
        iterations: VBD iterations per substep.
        progress: show a tqdm bar over the frames.

    Returns:
        positions (T, V, 3) float32 with frame 0 = start_positions; seconds per frame, the mean over
        frames 2.. (frame 1 compiles Warp's kernels; with T = 2 it is frame 1's time); seconds of setup
        (model, solver and frame 1).  Both times are 0 when T = 1.
    """
    faces = np.asarray(faces, dtype=np.int64)
    rest_corners = np.asarray(rest_corners, dtype=np.float64)
    start_positions = np.asarray(start_positions, dtype=np.float64)
    body_vertices = np.asarray(body_vertices, dtype=np.float32)
    body_faces = np.asarray(body_faces, dtype=np.int64)
    _check_inputs(faces, rest_corners, start_positions, body_vertices, body_faces, timestep, substeps, iterations)
    frames = len(body_vertices)
    positions = np.empty((frames, len(start_positions), 3), dtype=np.float32)
    positions[0] = start_positions
    if frames == 1:
        return positions, 0.0, 0.0

    setup_start = time.perf_counter()
    substep_dt = timestep / substeps
    body_step = float(np.linalg.norm(np.diff(body_vertices, axis=0), axis=2).max()) / substeps
    contact_gap = max(MIN_CONTACT_GAP, 2.0 * body_step)

    with wp.ScopedDevice("cpu"):
        model, body_mesh = _build_model(
            faces, rest_corners, start_positions, body_vertices[0], body_faces,
            density_g_m2=density_g_m2, membrane_weight=membrane_weight, bending_weight=bending_weight,
            contact_radius=contact_radius, contact_weight=contact_weight,
        )
        logger.info(
            "newton vbd: %d particles, %d triangles, contact ke %.3g N/m, gap %.1f mm, %d substeps x %d iter.",
            len(start_positions), len(faces), model.soft_contact_ke, contact_gap * 1e3, substeps, iterations,
        )
        pipeline = newton.CollisionPipeline(model, soft_contact_gap=contact_gap)
        solver = newton.solvers.SolverVBD(model, iterations=iterations, collision_pipeline=pipeline)
        state, next_state = model.state(), model.state()
        control = model.control()
        warp_mesh = body_mesh.mesh

        frame_seconds: list[float] = []
        setup_seconds = 0.0
        for frame in tqdm(range(1, frames), desc="newton vbd", unit="frame", disable=not progress):
            frame_start = time.perf_counter()
            before, after = body_vertices[frame - 1], body_vertices[frame]
            warp_mesh.velocities.assign((after - before) / timestep)
            # The contact query culls particles outside the shape's local box (the model's only shape,
            # computed once at finalize): keep it around the moving body.
            model.shape_collision_aabb_lower.assign(np.minimum(before.min(0), after.min(0))[None])
            model.shape_collision_aabb_upper.assign(np.maximum(before.max(0), after.max(0))[None])
            for substep in range(1, substeps + 1):
                fraction = substep / substeps  # the body where this implicit substep ends
                warp_mesh.points.assign((1.0 - fraction) * before + fraction * after)
                warp_mesh.refit()
                solver.step(state, next_state, control, None, substep_dt)
                state, next_state = next_state, state
            positions[frame] = state.particle_q.numpy()
            frame_seconds.append(time.perf_counter() - frame_start)
            if frame == 1:
                setup_seconds = time.perf_counter() - setup_start

    finite = np.isfinite(positions).all(axis=(1, 2))
    if not finite.all():
        logger.warning("newton vbd: non-finite positions from frame %d on", int(np.argmin(finite)))
    seconds_per_frame = float(np.mean(frame_seconds[1:] if len(frame_seconds) > 1 else frame_seconds))
    return positions, seconds_per_frame, setup_seconds
