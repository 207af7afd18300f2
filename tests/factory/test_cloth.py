"""Projective dynamics cloth: a pinned square comes to rest with bounded strain and the energy falls
over the local-global iterations; a cloth dropped on a sphere stays outside it."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from factory.cloth import ClothModel, ClothParams, ClothState, MeshCollider, ProjectiveDynamics


def square(n=11, size=0.5, z=0.0):
    xs = np.linspace(-size / 2, size / 2, n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    positions = np.stack([gx.ravel(), gy.ravel(), np.full(n * n, z)], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    return positions, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]), idx


def test_flat_rest_shape_has_no_bending_or_membrane_energy():
    positions, faces, _ = square()
    model = ClothModel.build(faces, positions)
    assert np.abs(model.bending @ positions).max() < 1e-9
    assert model.edge_strain(positions).max() < 1e-12
    assert model.masses.sum() == pytest.approx(0.25 * 0.1)  # 0.25 m^2 at 100 g/m^2
    folded = positions.copy()
    folded[:, 2] = np.abs(folded[:, 0])  # a crease along x = 0
    assert np.sum(folded * (model.bending @ folded)) > 1e-3


def test_pinned_square_comes_to_rest_and_energy_falls_every_iteration():
    positions, faces, idx = square()
    model = ClothModel.build(faces, positions)
    pinned = np.zeros(len(positions), bool)
    pinned[[idx[0, 0], idx[-1, 0]]] = True
    solver = ProjectiveDynamics(model, pinned)
    state = ClothState(positions, np.zeros_like(positions))
    for step in range(1200):  # 10 s
        energies = [] if step % 100 == 0 else None
        state = solver.step(state, pin_targets=positions[pinned], energies=energies)
        if energies:
            assert np.all(np.diff(energies) <= 1e-12 * abs(energies[0])), (step, energies)
    assert np.abs(state.velocities).max() < 0.02
    assert model.edge_strain(state.positions).max() < 0.01  # 1e5 N/m membrane: barely stretches
    np.testing.assert_allclose(state.positions[pinned], positions[pinned], atol=1e-4)  # penalty pins give a little
    assert state.positions[:, 2].min() < -0.4  # it hangs


def test_cloth_dropped_on_a_sphere_stays_outside():
    positions, faces, _ = square(n=21, size=0.6, z=0.12)
    model = ClothModel.build(faces, positions)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    collider = MeshCollider(sphere.vertices, sphere.faces)
    solver = ProjectiveDynamics(model)
    state = ClothState(positions, np.zeros_like(positions))
    params = model.params
    for _ in range(120):
        state = solver.step(state, collider)
        depth, _ = collider.signed_distance(state.positions)
        assert depth.min() > -params.contact_radius  # penetration under the contact radius
    # It rests on the sphere's top and its edges bend down past it (the reference's bending weight,
    # 1e-2, makes a stiff sheet: a 0.2 m overhang droops by centimetres, not metres).
    top = state.positions[np.argmin(np.linalg.norm(state.positions[:, :2], axis=1)), 2]
    assert 0.1 < top < 0.1 + 3 * params.contact_radius
    assert state.positions[:, 2].min() < 0.09
    assert np.isfinite(state.positions).all()


def test_cloth_lying_on_a_body_slides_along_it_as_in_the_air():
    """The contact holds a vertex along the body's normal only: a sheet stretched 30 % lying on a floor
    (at the contact radius, every vertex in the contact set) contracts in one step as it does in the air.
    Held near its previous iterate along the floor too, it stayed 9 % stretched, up to 7 mm from where it
    goes in the air (so the `jump`'s cuffs stretched on the swinging forearms)."""
    params = ClothParams(gravity=(0.0, 0.0, 0.0))
    rest, faces, _ = square(n=21, size=0.25, z=params.contact_radius)  # 12.5 mm edges, like the 12 mm level
    model = ClothModel.build(faces, rest, params)
    floor_vertices, floor_faces, _ = square(n=31, size=0.6)  # normals +z
    floor = MeshCollider(floor_vertices, floor_faces)
    stretched = rest * [1.3, 1.0, 1.0]
    start = ClothState(stretched, np.zeros_like(stretched))
    solver = ProjectiveDynamics(model)
    in_air = solver.step(start)
    energies = []
    on_floor = solver.step(start, floor, energies=energies)
    assert np.all(np.diff(energies) <= 1e-12 * abs(energies[0]))
    assert np.abs(model.edge_length_strain(in_air.positions)).max() < 1e-3
    assert np.abs(model.edge_length_strain(on_floor.positions)).max() < 0.01
    np.testing.assert_allclose(on_floor.positions, in_air.positions, atol=1e-3)


def test_closed_form_polar_factor_matches_the_svd():
    from factory.cloth import nearest_rotations

    deformation = np.random.default_rng(0).normal(size=(500, 3, 2))
    deformation[0] = 0.0  # collapsed to a point
    deformation[1, :, 1] = deformation[1, :, 0]  # collapsed to a line
    u, _, vt = np.linalg.svd(deformation, full_matrices=False)
    rotations = nearest_rotations(deformation)
    np.testing.assert_allclose(rotations[2:], (u @ vt)[2:], atol=1e-10)
    np.testing.assert_allclose(np.einsum("fki,fkj->fij", rotations, rotations), np.broadcast_to(np.eye(2), (500, 2, 2)),
                               atol=1e-10)


def _two_overlapping_spheres():
    """One mesh of two spheres 14 cm apart, 10 cm in radius: it intersects itself between x = -3 and 3 cm."""
    a = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    b = a.copy()
    a.apply_translation([-0.07, 0.0, 0.0])
    b.apply_translation([0.07, 0.0, 0.0])
    return trimesh.util.concatenate([a, b])


def test_a_point_where_the_mesh_intersects_itself_is_in_a_fold():
    body = _two_overlapping_spheres()
    collider = MeshCollider(body.vertices, body.faces)
    points = np.array([[0.025, 0.0, 0.0],    # inside both, 5 mm from the first sphere's surface in the second
                       [-0.155, 0.0, 0.0],   # inside the first only, near its far side
                       [-0.185, 0.0, 0.0],   # outside, near the same side
                       [0.0, 0.0, 0.12]])    # outside, above the fold, beyond the radius
    np.testing.assert_array_equal(collider.in_fold(points), [True, False, False, False])
    assert collider.in_fold(points, radius=0.001).sum() == 0  # no body vertex that near
    open_mesh = trimesh.Trimesh(body.vertices, body.faces[1:], process=False)  # a hole: no inside
    assert not MeshCollider(open_mesh.vertices, open_mesh.faces).in_fold(points).any()
    assert collider.in_fold(np.zeros((0, 3))).shape == (0,)


def test_the_contact_projection_leaves_a_vertex_deep_in_a_fold_where_it_is():
    """Where the body intersects itself no position is outside it, and the nearest body vertex's normal
    points across the fold: projected along it, a vertex went through the other body part (the
    `squat`'s armpit: 11 mm, its edge strained 1.06).  Deep in a fold the projection leaves the
    vertex where the solve put it; elsewhere it still moves vertices out to the contact radius."""
    body = _two_overlapping_spheres()
    collider = MeshCollider(body.vertices, body.faces)
    rest, faces, _ = square(n=5, size=0.048)  # 12 mm edges, like the 12 mm level
    rest += [0.0, 0.045, 0.0]  # across the fold, near where the spheres' surfaces cross
    # no contact in the solve, as for the squat's vertex, which entered the fold within a step
    params = ClothParams(gravity=(0.0, 0.0, 0.0), contact_weight=0.0)
    start = ClothState(rest, np.zeros_like(rest))
    solved = ProjectiveDynamics(ClothModel.build(faces, rest, replace(params, contact_projection=False))).step(start, collider)
    projected = ProjectiveDynamics(ClothModel.build(faces, rest, params)).step(start, collider)
    depth, _ = collider.signed_distance(solved.positions)
    folded = (depth < -params.fold_depth) & collider.in_fold(solved.positions)
    assert 0 < folded.sum() < len(rest)
    np.testing.assert_array_equal(projected.positions[folded], solved.positions[folded])
    depth_after, _ = collider.signed_distance(projected.positions)
    assert depth_after[~folded].min() > params.contact_radius - 1e-9


@pytest.mark.parametrize("field, value", [("contact_cg_iterations", 0), ("fold_depth", -1e-3)])
def test_cloth_params_refuse_a_bad_contact_setting_by_name(field, value):
    with pytest.raises(ValueError, match=f"ClothParams.{field}"):
        ClothParams(**{field: value})
