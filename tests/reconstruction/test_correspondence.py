"""Correspondence lookups on a small real template (the two-panel tube of the garment tests)."""

import logging

import numpy as np
import pytest

from assets.garments.template import Template
from networks.detections import Detections
from reconstruction.correspondence import CrosspointMap
from tests.assets.garment_fixtures import tube

K = 25


@pytest.fixture(scope="module")
def tube_template():
    template = Template.build(tube(), dpi=150.0)
    return template, template.layout.tables()


@pytest.fixture(scope="module")
def maps(tube_template):
    template, tables = tube_template
    return {mm: CrosspointMap.build(template, mm, tables) for mm in (12, 2)}


def _pattern_xy(template, level_mm, face, bary):
    level = template.level(level_mm)
    return np.einsum("nkd,nk->nd", level.pattern_xy[level.faces[face]], bary)


def test_neighbouring_markers_share_border_crosspoints(tube_template, maps):
    template, tables = tube_template
    crosspoints = maps[12]
    pairs = 0
    for table in tables:
        rc = table.marker_rc
        for di, dj, mine, theirs in ((0, 1, (slice(None), K - 1), (slice(None), 0)),
                                     (1, 0, (K - 1, slice(None)), (0, slice(None)))):
            # every marker with a right (or lower) neighbour: its last column (row) is the neighbour's first
            right = {(int(i), int(j)): m for m, (i, j) in enumerate(rc)}
            for m, (i, j) in enumerate(rc):
                n = right.get((int(i) + di, int(j) + dj))
                if n is None:
                    continue
                rows, cols = np.meshgrid(np.arange(K), np.arange(K), indexing="ij")
                a_key, a_known = crosspoints.lookup(np.full(K, table.marker_ids[m]), rows[mine], cols[mine])
                b_key, b_known = crosspoints.lookup(np.full(K, table.marker_ids[n]), rows[theirs], cols[theirs])
                assert a_known.all() and b_known.all()
                np.testing.assert_array_equal(a_key, b_key)
                for got, expected in zip(crosspoints.locate(a_key), crosspoints.locate(b_key)):
                    np.testing.assert_array_equal(got, expected)
                pairs += 1
    assert pairs > 20


@pytest.mark.parametrize("level_mm", [12, 2])
def test_face_and_barycentric_weights_reproduce_the_pattern_position(tube_template, maps, level_mm):
    template, tables = tube_template
    crosspoints = maps[level_mm]
    ids = np.concatenate([t.marker_ids for t in tables])
    marker, row, col = (a.reshape(-1) for a in np.meshgrid(np.arange(len(ids)), np.arange(K), np.arange(K),
                                                           indexing="ij"))
    key, known = crosspoints.lookup(ids[marker], row, col)
    assert known.all()
    expected = np.concatenate([t.marker_crosspoint_xy for t in tables]).reshape(-1, 2)
    panel_of_marker = np.concatenate([np.full(t.num_markers, p) for p, t in enumerate(tables)])
    np.testing.assert_array_equal(key[:, 0], panel_of_marker[marker])
    face, bary = crosspoints.locate(key)
    on = face >= 0
    assert 0.5 < on.mean() < 1.0  # the tube's curved outlines cut the markers along its edges
    np.testing.assert_allclose(_pattern_xy(template, level_mm, face[on], bary[on]), expected[on], atol=1e-12)
    np.testing.assert_allclose(bary[on].sum(axis=1), 1.0, atol=1e-12)
    # the garment-wide numbering is Level.crosspoint's, and unflat inverts flat
    flat = crosspoints.flat(key)
    np.testing.assert_array_equal(crosspoints.unflat(flat), key)
    level = template.level(level_mm)
    at_vertex = level.crosspoint >= 0
    np.testing.assert_allclose(_pattern_xy(template, level_mm, crosspoints.face[level.crosspoint[at_vertex]],
                                           crosspoints.bary[level.crosspoint[at_vertex]]),
                               level.pattern_xy[at_vertex], atol=1e-12)


@pytest.mark.parametrize("level_mm", [12, 2])
def test_crosspoints_on_mesh_vertices(tube_template, maps, level_mm):
    """vertex_of finds exactly the level's vertices that are crosspoints (every crosspoint on the
    fabric at the crosspoint pitch but near the outline; every 6th at 12 mm)."""
    template, _ = tube_template
    crosspoints = maps[level_mm]
    level = template.level(level_mm)
    on_fabric = np.flatnonzero(crosspoints.face >= 0)
    vertex = crosspoints.vertex_of(crosspoints.unflat(on_fabric))
    at_vertex = np.flatnonzero(level.crosspoint >= 0)
    assert set(on_fabric[vertex >= 0]) == set(level.crosspoint[at_vertex])
    by_crosspoint = dict(zip(level.crosspoint[at_vertex], level.sewn_index[at_vertex]))
    np.testing.assert_array_equal(vertex[vertex >= 0], [by_crosspoint[g] for g in on_fabric[vertex >= 0]])
    share = (vertex >= 0).mean()
    if level_mm == 2:
        assert share > 0.95
    else:
        assert 1 / 36 * 0.8 < share < 1 / 36 * 1.2
    # a posed mesh: vertex crosspoints sit exactly on their vertex
    positions = np.random.default_rng(0).normal(size=(level.num_sewn_vertices, 3))
    points = crosspoints.points(positions, crosspoints.unflat(on_fabric[vertex >= 0]))
    np.testing.assert_allclose(points, positions[vertex[vertex >= 0]], atol=1e-12)


def test_unknown_markers_and_bad_rows_are_reported_and_dropped(tube_template, maps, caplog):
    _, tables = tube_template
    crosspoints = maps[12]
    inside = (crosspoints.face[crosspoints.first_crosspoint[1] + tables[1].crosspoint_index] >= 0).all(axis=(1, 2))
    ids = tables[1].marker_ids[np.flatnonzero(inside)[[0, -1]]]  # two markers wholly on the back panel
    key, known = crosspoints.lookup([ids[0], 4000, ids[1], ids[1]], [0, 0, 25, 3], [0, 0, 0, -1])
    assert known.tolist() == [True, False, False, False]
    assert (key[~known] == -1).all() and (key[0] >= 0).all()
    marker_ids = np.array([ids[0], 4000, ids[1], 3999], dtype=np.int64)
    visible = np.zeros((4, K, K), bool)
    visible[:, 10:13, 10:12] = True  # six crosspoints each, inside every marker
    pixels = np.random.default_rng(1).uniform(0, 100, (4, K, K, 2)).astype(np.float32)
    pixels[2, 10, 10] = np.nan  # a non-finite pixel is dropped too
    detections = Detections(marker_id=marker_ids, confidence=np.array([0.9, 0.8, 0.7, 0.6], np.float32),
                            points_px=np.zeros((4, 5, 2), np.float32), crosspoints_px=pixels,
                            crosspoint_visible=visible, partial=np.zeros(4, bool))
    with caplog.at_level(logging.WARNING, logger="reconstruction.correspondence"):
        observations, unknown = crosspoints.observations(detections, where="camera 'cam03'")
    assert unknown.tolist() == [3999, 4000]
    assert "camera 'cam03': 2 marker ID(s) not in this garment's layout dropped: [3999, 4000]" in caplog.text
    assert len(observations) == 11 and sorted(set(observations.marker_id.tolist())) == sorted(ids.tolist())
    np.testing.assert_allclose(observations.confidence, [0.9] * 6 + [0.7] * 5, atol=1e-6)
    assert np.isfinite(observations.pixels).all()
    np.testing.assert_array_equal(observations.key[:6], crosspoints.lookup(
        np.full(6, ids[0]), *np.nonzero(visible[0]))[0])
    with pytest.raises(ValueError, match=r"keys: 1 of 2 are not crosspoints of this garment, e.g. \[2, 0\]"):
        crosspoints.locate(np.array([[0, 0], [2, 0]]))
