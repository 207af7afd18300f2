"""Placing a marker from its neighbours' points (`networks.neighbours.place_from_neighbours`): one
homography over the neighbourhood, or local weighted fits with the corners neighbours share, on a flat
panel (both exact) and on a panel wrapped round a cylinder (the local fit follows the curvature)."""

import numpy as np
import pytest

from assets.geometry import apply_homography, fit_homography
from assets.pattern import MarkerTable, PatternSpec, generate_codebook
from networks.homography import fit_homography_masked, fit_homography_weighted
from networks.neighbours import MarkerLayout, estimate_from_neighbours, place_from_neighbours, predict_missing

SPEC = PatternSpec(rows=5, cols=5, num_ids=64)
IMAGE_SIZE = (4000, 4000)
CENTRE = 12  # the middle marker of the 5 x 5 panel (IDs 0..24 row-major)


@pytest.fixture(scope="module")
def table():
    return MarkerTable.build(SPEC, generate_codebook(SPEC), first_id=0)


@pytest.fixture(scope="module")
def layout(table):
    return MarkerLayout.from_tables([table], SPEC.num_ids)


def flat_camera(xy: np.ndarray) -> np.ndarray:
    """A plane seen in perspective: one homography."""
    h = np.array([[3000.0, 400.0, 1800.0], [-300.0, 2800.0, 1900.0], [0.2, 0.3, 1.0]])
    return apply_homography(h, xy.reshape(1, -1, 2)).reshape(xy.shape)


def cylinder_camera(table: MarkerTable):
    """The panel wrapped round a vertical cylinder of radius 3 marker widths, seen from 10 widths away
    (markers about 100 px), the middle marker on its slope (the axis 0.7 widths to its side: no
    symmetry hides the curvature)."""
    xy = table.localization_xy
    centre = xy[CENTRE, 0]
    width = np.linalg.norm(xy[0, 2] - xy[0, 1])

    def project(points: np.ndarray) -> np.ndarray:
        x, y = (points[..., 0] - centre[0]) / width - 0.7, (points[..., 1] - centre[1]) / width
        angle = x / 3.0
        depth = 10.0 + 3.0 * (1.0 - np.cos(angle))
        return np.stack([2000.0 + 1000.0 * 3.0 * np.sin(angle) / depth, 2000.0 + 1000.0 * y / depth], axis=-1)

    return project


def test_weighted_fit_is_the_masked_fit_for_0_1_weights_and_refuses_bad_weights():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 1, (3, 12, 2))
    h = np.array([[1.2, 0.1, 3.0], [-0.2, 0.9, 1.0], [0.05, 0.02, 1.0]])
    dst = apply_homography(h, src) + rng.normal(0, 0.01, src.shape)
    mask = rng.random((3, 12)) < 0.7
    mask[:, :4] = True
    assert np.allclose(fit_homography_weighted(src, dst, mask.astype(float)), fit_homography_masked(src, dst, mask))
    # exact points: any positive weights give the homography back; a weight of 0 hides a wrong point
    exact = apply_homography(h, src)
    exact[:, 0] += 50.0
    weight = rng.uniform(0.01, 1.0, (3, 12))
    weight[:, 0] = 0.0
    assert np.allclose(fit_homography_weighted(src, exact, weight), np.broadcast_to(h, (3, 3, 3)), atol=1e-8)
    # fewer than 4 points of positive weight: NaN
    few = np.zeros((1, 12))
    few[0, :3] = 1.0
    assert np.isnan(fit_homography_weighted(src[:1], dst[:1], few)).all()
    with pytest.raises(ValueError, match="weights must be finite and >= 0"):
        fit_homography_weighted(src, dst, -weight)
    with pytest.raises(ValueError, match="expected src, dst"):
        fit_homography_weighted(src, dst, weight[:, :5])


def _neighbourhood(layout: MarkerLayout, table: MarkerTable, project, marker: int):
    """src, dst, mask of `marker`'s 8 neighbours' five points, its own pattern points and side."""
    neighbours = layout.neighbours(np.array([marker]))[0]
    src = table.localization_xy[neighbours].reshape(1, 40, 2)
    own_xy = table.localization_xy[[marker]]
    side = np.array([np.linalg.norm(own_xy[0, 2] - own_xy[0, 1])])
    return src, project(src), np.ones((1, 40), bool), own_xy, side


def test_a_flat_panel_is_placed_exactly_by_every_model(layout, table):
    src, dst, mask, own_xy, side = _neighbourhood(layout, table, flat_camera, CENTRE)
    truth = flat_camera(own_xy)
    for sigma, degree in ((None, 0), (0.5, 0), (3.0, 0), (None, 2), (1.5, 2), (1.0, 3)):
        assert np.abs(place_from_neighbours(src, dst, mask, own_xy, side, sigma, degree) - truth).max() < 1e-6


def test_on_a_curved_panel_the_local_fits_follow_the_curvature(layout, table):
    project = cylinder_camera(table)
    src, dst, mask, own_xy, side = _neighbourhood(layout, table, project, CENTRE)
    truth = project(own_xy)[0]
    plane = place_from_neighbours(src, dst, mask, own_xy, side, None)[0]
    plane_error = np.linalg.norm(plane - truth, axis=-1)
    assert plane_error[0] > 2.0 and plane_error[1:].max() > 2.0  # the plane is off on this cylinder
    for sigma, degree, centre_error in ((1.0, 0, 1.2), (None, 2, 0.3), (None, 3, 0.3)):
        local = place_from_neighbours(src, dst, mask, own_xy, side, sigma, degree)[0]
        error = np.linalg.norm(local - truth, axis=-1)
        assert error[1:].max() < 1e-6  # the corners are the neighbours' shared corners: exact here
        assert error[0] < centre_error  # the centre bends with the cloth (the plane: 2.6 px)
    # a corner no neighbour shares (only the right-hand neighbours seen) comes from the fit, extrapolated:
    # where a bend is least sure
    right = np.array([2, 4, 7])  # the slots of the top-right, right and bottom-right neighbours
    one_side = np.repeat(np.isin(np.arange(8), right), 5)[None]
    partial = place_from_neighbours(src, dst, one_side, own_xy, side, 1.5, 2)[0]
    assert np.abs(partial[[2, 4]] - truth[[2, 4]]).max() < 1e-6  # TR, BR shared with the right-hand ones
    assert np.isfinite(partial).all() and np.linalg.norm(partial[[1, 3]] - truth[[1, 3]], axis=-1).min() > 1e-3
    # a target with fewer than 4 seen points: NaN; a width of 0 or a negative degree is refused
    assert np.isnan(place_from_neighbours(src, dst, np.zeros((1, 40), bool), own_xy, side, None, 2)).all()
    with pytest.raises(ValueError, match="sigma_sides must be > 0 or None"):
        place_from_neighbours(src, dst, mask, own_xy, side, 0.0)
    with pytest.raises(ValueError, match="degree must be >= 0"):
        place_from_neighbours(src, dst, mask, own_xy, side, None, -1)


def test_growth_and_completion_place_markers_with_the_bend(layout, table):
    """The middle marker missed (growth) or cut (completion) on the cylinder: with a bend, its corners
    are its neighbours' and its centre is far closer to the truth than one homography puts it."""
    project = cylinder_camera(table)
    ids = np.arange(25, dtype=np.int64)
    points = project(table.localization_xy)
    others = ids != CENTRE
    errors = {}
    for degree in (0, 2):
        grown, placed, _ = predict_missing(layout, ids[others], points[others], np.ones(24, bool), np.ones(24),
                                           IMAGE_SIZE, 2, None, degree)
        assert grown.tolist() == [CENTRE]
        errors[degree] = np.linalg.norm(placed[0] - points[CENTRE], axis=-1)
    assert errors[2][1:].max() < 1e-6 and errors[2][0] < errors[0][0] / 8
    # completion: the middle marker's own TR, BR lost beyond a boundary, its other points right
    detected = points.copy()
    detected[CENTRE, [2, 4]] += [[300.0, -100.0], [250.0, 180.0]]
    full = others.copy()
    completed = {}
    for degree in (0, 2):
        estimate, estimated = estimate_from_neighbours(layout, SPEC, ids, detected, full, np.ones(25), IMAGE_SIZE,
                                                       1.0, None, None, degree)
        assert estimated.tolist() == (~others).tolist()
        completed[degree] = np.linalg.norm(estimate[CENTRE] - points[CENTRE], axis=-1)
    # the corners are neighbours' and the centre its own (consistent with the bent estimate, so in the fit)
    assert completed[2].max() < 1e-6
    assert completed[0].max() > 1.0
