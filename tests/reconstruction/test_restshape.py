"""The dynamic rest shape's rules on a small mesh: observed where a stencil is captured, the previous
frame's elsewhere, the template's where there is none, and the bidirectional smoothing."""

import newton
import numpy as np
import pytest
import warp as wp

from reconstruction.restshape import (
    RestShape, dynamic_rest, hinge_angles, measure, pattern_rest, smoothed_rest, stencils_captured, triangle_rest,
)

N = 4  # a 4 x 4 vertex sheet, 10 mm apart


def sheet() -> tuple[np.ndarray, np.ndarray]:
    i, j = np.meshgrid(np.arange(N), np.arange(N), indexing="ij")
    xy = np.stack([i.ravel(), j.ravel()], axis=1) * 0.01
    index = np.arange(N * N).reshape(N, N)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return xy, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def folded(xy: np.ndarray, angle: float) -> np.ndarray:
    """The sheet folded about its vertex line x = 0.01 by `angle` radians (then rotated and moved)."""
    x, y = xy[:, 0] - 0.01, xy[:, 1]
    bent = np.where(x > 0, x * np.cos(angle), x)
    z = np.where(x > 0, x * np.sin(angle), 0.0)
    shape = np.stack([bent, y, z], axis=1)
    c, s = np.cos(0.3), np.sin(0.3)
    return shape @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + np.array([0.1, 0.2, 0.3])


def newton_hinges(xy: np.ndarray, faces: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Newton's bending edges of the mesh and the rest angles it measures on `shape`."""
    builder = newton.ModelBuilder()
    builder.add_cloth_mesh(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                           vertices=shape, indices=faces.ravel(), density=1.0)
    return np.asarray(builder.edge_indices, dtype=np.int64), np.asarray(builder.edge_rest_angle)


def test_measured_values_follow_newtons_conventions():
    xy, faces = sheet()
    shape = folded(xy, 0.7)
    hinges, newton_angles = newton_hinges(xy, faces, shape)
    angles = hinge_angles(shape, hinges)
    assert np.allclose(angles, newton_angles, atol=1e-6)
    assert np.isclose(np.abs(angles).max(), 0.7, atol=1e-9)  # the fold line's hinges
    # a rigidly moved and bent (isometric) sheet has the pattern's triangles: F^T F = I
    rest = triangle_rest(xy, faces)
    edges = np.stack([shape[faces[:, 1]] - shape[faces[:, 0]], shape[faces[:, 2]] - shape[faces[:, 0]]], axis=2)
    gradient = edges @ np.linalg.inv(rest)
    assert np.allclose(np.einsum("fki,fkj->fij", gradient, gradient), np.eye(2), atol=1e-9)
    assert np.allclose(triangle_rest(shape, faces), rest, atol=1e-12)
    assert np.allclose(RestShape(rest, angles, np.ones(len(angles))).areas, 0.5e-4)


def test_captured_stencils_take_the_observed_value_others_the_previous_frames():
    xy, faces = sheet()
    hinges, _ = newton_hinges(xy, faces, folded(xy, 0.0))
    template = pattern_rest(xy, faces, faces, hinges)
    assert np.allclose(template.hinge_angle, 0.0) and np.allclose(template.triangle, triangle_rest(xy, faces))
    assert np.allclose(template.hinge_length[hinges[:, 2] // N == hinges[:, 3] // N], 0.01)
    previous = measure(folded(xy, 0.4), faces, hinges)
    observed_shape = folded(xy, -0.9)
    observed_shape[:, 1] *= 1.1  # stretched along y, so triangle values differ from the previous frame's
    observed = measure(observed_shape, faces, hinges)
    captured = xy[:, 1] < 0.015  # the two rows of vertices at y = 0 and 0.01
    triangle, hinge = stencils_captured(captured, faces, hinges)
    assert triangle.any() and not triangle.all() and hinge.any() and not hinge.all()
    assert not hinge[(hinges < 0).any(axis=1)].any()  # boundary edges never bend
    rest = dynamic_rest(observed, triangle, hinge, previous, template)
    assert np.allclose(rest.triangle[triangle], observed.triangle[triangle])
    assert np.allclose(rest.triangle[~triangle], previous.triangle[~triangle])
    assert np.allclose(rest.hinge_angle[hinge], observed.hinge_angle[hinge])
    assert np.allclose(rest.hinge_angle[~hinge], previous.hinge_angle[~hinge])
    assert np.allclose(rest.hinge_length[hinge], observed.hinge_length[hinge])
    # the first frame has no previous one: the template's rest
    first = dynamic_rest(observed, triangle, hinge, None, template)
    assert np.allclose(first.triangle[~triangle], template.triangle[~triangle])
    assert np.allclose(first.hinge_angle[~hinge], 0.0)
    # a crushed observed triangle is not a rest shape: it falls back
    crushed_shape = observed_shape.copy()
    crushed_shape[faces[0, 2]] = 0.5 * (crushed_shape[faces[0, 0]] + crushed_shape[faces[0, 1]])
    crushed = dynamic_rest(measure(crushed_shape, faces, hinges), triangle, hinge, previous, template)
    assert triangle[0] and np.allclose(crushed.triangle[0], previous.triangle[0])


def test_smoothing_averages_the_previous_and_next_frames_where_not_observed():
    xy, faces = sheet()
    hinges, _ = newton_hinges(xy, faces, folded(xy, 0.0))
    template = pattern_rest(xy, faces, faces, hinges)
    before, after = measure(folded(xy, 0.2), faces, hinges), measure(folded(xy, 0.6), faces, hinges)
    stretched = folded(xy, -0.5)
    stretched[:, 1] *= 1.2
    after = RestShape(measure(stretched, faces, hinges).triangle, after.hinge_angle, after.hinge_length)
    observed = measure(folded(xy, 1.0), faces, hinges)
    captured = xy[:, 0] > 0.015
    triangle, hinge = stencils_captured(captured, faces, hinges)
    rest = smoothed_rest(observed, triangle, hinge, before, after, template)
    fold = np.isclose(np.abs(before.hinge_angle), 0.2)  # the fold line's hinges (not observed)
    assert fold.any() and not hinge[fold].any()
    assert np.allclose(np.abs(rest.hinge_angle[fold]), 0.4)
    assert np.allclose(rest.triangle[~triangle], 0.5 * (before.triangle + after.triangle)[~triangle])
    assert np.allclose(rest.hinge_angle[hinge], observed.hinge_angle[hinge])
    assert np.allclose(rest.triangle[triangle], observed.triangle[triangle])
    # at either end of the sequence, the one neighbour there is
    end = smoothed_rest(observed, triangle, hinge, before, None, template)
    assert np.allclose(end.hinge_angle[~hinge], before.hinge_angle[~hinge])
    # angles average on the circle: +3.1 and -3.1 rad are both almost pi
    wrap_before = RestShape(before.triangle, np.full(len(hinges), 3.1), before.hinge_length)
    wrap_after = RestShape(before.triangle, np.full(len(hinges), -3.1), before.hinge_length)
    wrapped = smoothed_rest(observed, triangle, hinge, wrap_before, wrap_after, template)
    assert np.allclose(np.abs(wrapped.hinge_angle[~hinge]), np.pi)
    with pytest.raises(ValueError, match="previous or the next"):
        smoothed_rest(observed, triangle, hinge, None, None, template)
