"""Captured crosspoints -> captured vertices and anchor targets; level-to-level transfer; rigid fit."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.garments.export import placed_positions
from assets.garments.loading import load_template
from reconstruction.anchors import LevelAnchoring, rigid_fit
from reconstruction.hierarchy import Hierarchy
from tests.reconstruction.cylinder import (
    HEIGHT, WIDTH, bent, cylinder_template, every_key, key_pattern_xy, sewn_pattern_xy, wrapped,
)


@pytest.fixture(scope="module")
def cylinder():
    template = cylinder_template()
    return template, LevelAnchoring(template, 12)


def test_every_crosspoint_captured_anchors_every_vertex_on_its_exact_position(cylinder):
    template, anchoring = cylinder
    rest = wrapped(template, 12)
    truth = bent(rest, 0.15, (0.05, -0.02, 0.03))
    key = every_key(anchoring)
    anchors = anchoring.anchors(key, anchoring.points_on(truth, key), np.ones(len(key)), reference=truth)
    assert anchors.captured.all() and anchors.points == len(key)
    assert np.abs(anchors.targets - truth).max() < 1e-9
    # from a reference that is not bent, the small Laplacian term still leaves them within 0.1 mm
    anchors = anchoring.anchors(key, anchoring.points_on(truth, key), np.ones(len(key)), reference=rest)
    assert np.linalg.norm(anchors.targets - truth, axis=1).max() < 1e-4
    assert anchors.fit_rms < 1e-5


def test_only_vertices_surrounded_by_captured_crosspoints_are_captured(cylinder):
    template, anchoring = cylinder
    truth = wrapped(template, 12)
    key = every_key(anchoring)
    panel, xy = key_pattern_xy(template, anchoring, key)
    centre = np.array([WIDTH / 2, HEIGHT / 2])
    hidden = (panel == 0) & (np.linalg.norm(xy - centre, axis=1) < 0.05)
    seen = key[~hidden]
    anchors = anchoring.anchors(seen, anchoring.points_on(truth, seen), np.ones(len(seen)), reference=truth)
    vertex_panel, vertex_xy = sewn_pattern_xy(template, 12)
    distance = np.where(vertex_panel == 0, np.linalg.norm(vertex_xy - centre, axis=1), np.inf)
    assert not anchors.captured[distance < 0.05].any()
    assert anchors.captured[distance > 0.05 + anchoring.radius].all()
    # just outside the hidden disc about half of a vertex's neighbourhood is seen: enough for coverage
    # 0.5 where every sector still holds a seen crosspoint, never for 0.9
    band = (distance > 0.05) & (distance < 0.05 + anchoring.radius / 3)
    assert band.sum() >= 5 and anchors.captured[band].any()
    strict = LevelAnchoring(template, 12, coverage=0.9)
    assert not strict.captured_vertices(seen)[band].any()
    assert np.isnan(anchors.targets[~anchors.captured]).all()
    assert np.abs(anchors.targets[anchors.captured] - truth[anchors.captured]).max() < 1e-9
    # a seam vertex must be captured on both panels it joins: hide the back panel
    front = key[panel == 0]
    captured = anchoring.captured_vertices(front)
    level = template.level(12)
    seam = np.unique(level.sewn_index[level.seam_pairs.ravel()])
    assert not captured[seam].any() and captured[vertex_panel == 0].sum() > 0.8 * (vertex_panel == 0).sum() - len(seam)


def test_keys_outside_the_layout_are_named(cylinder):
    _, anchoring = cylinder
    with pytest.raises(ValueError, match="CapturedPoints.key"):
        anchoring.rows(np.array([[0, 10**9]]))
    with pytest.raises(ValueError, match="CapturedPoints.key"):
        anchoring.rows(np.array([[5, 0]]))


def test_the_shirt_is_anchored_where_it_is_captured():
    template = load_template("shirt")
    anchoring = LevelAnchoring(template, 12)
    level = template.level(12)
    placed = level.sew(placed_positions(template, 12))
    truth = placed + 0.02 * np.sin(5.0 * placed[:, [2, 0, 1]])  # a smooth deformation of the placed pose
    key = every_key(anchoring)
    points = anchoring.points_on(truth, key)
    seen = points[:, 0] > 0.0  # the garment's left half
    anchors = anchoring.anchors(key[seen], points[seen], np.ones(seen.sum()), reference=placed)
    left, right = truth[:, 0] > 0.02, truth[:, 0] < -0.02
    assert anchors.captured[left].mean() > 0.95 and not anchors.captured[right].any()
    error = np.linalg.norm(anchors.targets[anchors.captured] - truth[anchors.captured], axis=1)
    assert np.median(error) < 1e-5 and error.max() < 1e-3


def test_levels_transfer_barycentrically(cylinder):
    template, _ = cylinder
    hierarchy = Hierarchy(template, (4, 12))
    assert hierarchy.levels_mm == (12, 4) and hierarchy.coarsest_mm == 12 and hierarchy.finest_mm == 4
    fine = hierarchy.transfer(wrapped(template, 12), 12, 4)
    # every 4 mm vertex lies on the 12 mm chords of the circle: within their sagitta of it
    sagitta = 0.012**2 / (8 * (WIDTH / np.pi))
    radial = np.linalg.norm(fine[:, :2], axis=1)
    assert fine.shape == (template.level(4).num_sewn_vertices, 3)
    assert np.all(radial <= WIDTH / np.pi + 1e-9) and np.all(radial >= WIDTH / np.pi - 1.01 * sagitta)
    assert np.allclose(fine[:, 2], wrapped(template, 4)[:, 2], atol=1e-9)
    with pytest.raises(ValueError, match="positions"):
        hierarchy.transfer(fine, 12, 4)


def test_rigid_fit_recovers_a_rotation_and_translation():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(50, 3))
    rotation = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    target = source @ rotation.T + np.array([1.0, 2.0, -3.0])
    found_rotation, found_translation = rigid_fit(source, target, rng.uniform(0.5, 1.0, 50))
    assert np.allclose(found_rotation, rotation) and np.allclose(found_translation, [1.0, 2.0, -3.0])
    with pytest.raises(ValueError, match="at least 3"):
        rigid_fit(source[:2], target[:2])
