"""Crop targets (`assets.pattern.observation`): which markers get a recognizer or crosspoint crop, and
that every visible crosspoint target lies in its crop."""

import dataclasses

import numpy as np
import pytest

from assets.geometry import apply_homography
from assets.pattern import CROSSPOINT_CROP, PatternSpec, crop_crosspoints_px, crop_homography, localization_rc
from assets.pattern.observation import (
    MIN_COMPLETION_CROSSPOINTS,
    ImageGroundTruth,
    completed_points,
    crosspoint_crops,
    crosspoint_markers,
    is_convex_layout,
    localizer_targets,
    recognizer_crops,
    recognizer_markers,
    sane_crop_homography,
    training_samples,
)

SPEC = PatternSpec(rows=1, cols=1, num_ids=64)
K = SPEC.crosspoints_per_side
SIZE = CROSSPOINT_CROP.size_px
#: crop -> image of a flat marker, slightly rotated and tilted, about 4 image pixels per cell
FLAT = np.array([[0.25, 0.02, 30.0], [-0.01, 0.27, 40.0], [2e-4, 1e-4, 1.0]])


def ground_truth(crosspoints_px: np.ndarray, visible: np.ndarray) -> ImageGroundTruth:
    """A 256 x 256 image's ground truth of markers with crosspoints (M, K, K, 2) and their visibility."""
    m = len(crosspoints_px)
    rc = localization_rc(SPEC)
    status = np.where(visible.all(axis=(1, 2)), 2, np.where(visible.any(axis=(1, 2)), 1, 0)).astype(np.int8)
    return ImageGroundTruth(256, 256, np.arange(m, dtype=np.int32),
                            crosspoints_px[:, rc[:, 0], rc[:, 1]].astype(np.float32), np.ones((m, 5), np.float32),
                            visible[:, rc[:, 0], rc[:, 1]], crosspoints_px.astype(np.float32), visible, status)


def flat_marker() -> np.ndarray:
    return apply_homography(FLAT, crop_crosspoints_px(SPEC, CROSSPOINT_CROP).reshape(-1, 2)).reshape(K, K, 2)


@pytest.fixture(scope="module")
def markers():
    """(crosspoints (4, K, K, 2), visible (4, K, K)): flat; flat with a bulge of seven visible top-row
    crosspoints 3 px (12 crop px) up, out of the crop; folded over at column 16, the flap covering
    columns 8-15 (its corners land beside the centre); seen edge-on and curved (the shirt's sleeves)."""
    u, v = np.meshgrid(np.arange(K, dtype=float), np.arange(K, dtype=float))
    bulge = flat_marker()
    bulge[0, 3:10, 1] -= 3.0
    folded = np.stack([150 + 3 * np.where(u <= 16, u, 32 - u), 120 + 3 * v], axis=-1)
    edge_on = np.stack([60 + 0.5 * u - 0.08 * (u - 12) ** 2, 160 + 2 * v + 0.3 * u], axis=-1)
    visible = np.ones((4, K, K), bool)
    visible[2] = (u < 8) | (u > 15)
    return np.stack([flat_marker(), bulge, folded, edge_on]), visible


def test_crosspoint_crops_skip_folded_and_edge_on_markers(markers):
    crosspoints, visible = markers
    gt = ground_truth(crosspoints, visible)
    samples = training_samples(np.zeros((256, 256, 3), np.uint8), gt, SPEC)
    ids, xy, seen = samples["crosspoint_ids"], samples["crosspoint_xy"], samples["crosspoint_visible"]
    # before, the folded marker's visible targets reached 6779 crop px and the edge-on one's 834
    np.testing.assert_array_equal(ids, [0, 1])
    assert samples["crosspoint_crops"].shape == (2, SIZE, SIZE, 3) and xy.shape == (2, K, K, 2)
    np.testing.assert_allclose(xy[0], crop_crosspoints_px(SPEC, CROSSPOINT_CROP), atol=1e-3)
    assert seen[0].all()
    pick, homography = crosspoint_markers(gt, SPEC)
    np.testing.assert_array_equal(pick, [0, 1])
    np.testing.assert_allclose(homography, crop_homography(SPEC, CROSSPOINT_CROP, gt.points_px[:2].astype(float)))


def test_visible_crosspoint_targets_lie_in_the_crop(markers):
    crosspoints, visible = markers
    _, _, xy, seen = crosspoint_crops(np.zeros((256, 256), np.uint8), ground_truth(crosspoints, visible), SPEC)
    assert np.isfinite(xy[seen]).all() and ((xy[seen] >= 0) & (xy[seen] <= SIZE)).all()
    # the bulge's seven crosspoints are seen in the image but not in the crop: hidden there, nothing else
    hidden = np.zeros((K, K), bool)
    hidden[0, 3:10] = True
    np.testing.assert_array_equal(seen[1], ~hidden)
    assert (xy[1, 0, 3:10, 1] < -2).all()


def test_sane_crop_homography_rejects_each_degenerate_fit():
    rc = localization_rc(SPEC)
    flat = flat_marker()[rc[:, 0], rc[:, 1]]
    mirrored = flat * [-1, 1] + [256, 0]
    centre_off = [flat.copy() for _ in range(2)]
    centre_off[0][0] += [1.0, 0.0]  # fitted 0.7 cells off: a curved marker
    centre_off[1][0] += [10.0, 0.0]  # 7.4 cells off: not this marker's homography
    # crop -> image whose vanishing line x = 4 crosses the crop's margin but not the marker (x >= 8)
    horizon = np.array([[-40.0, 0.0, 0.0], [0.0, 40.0, 0.0], [0.25, 0.0, -1.0]])
    wrapped = apply_homography(horizon, crop_crosspoints_px(SPEC, CROSSPOINT_CROP)[rc[:, 0], rc[:, 1]])
    points = np.stack([flat, mirrored, *centre_off, wrapped])
    homography = crop_homography(SPEC, CROSSPOINT_CROP, points)
    np.testing.assert_array_equal(sane_crop_homography(SPEC, CROSSPOINT_CROP, points, homography),
                                  [True, False, True, False, False])
    # the fit of the wrapped crop is exact and its corners convex: only the unbounded crop rejects it
    fit = apply_homography(homography[4], wrapped) - crop_crosspoints_px(SPEC, CROSSPOINT_CROP)[rc[:, 0], rc[:, 1]]
    assert np.abs(fit).max() < 1e-6 and is_convex_layout(wrapped[None])[0]
    # a larger tolerance takes the far-off centre; NaN points never pass
    assert sane_crop_homography(SPEC, CROSSPOINT_CROP, points[3:4], homography[3:4], max_fit_cells=10.0)[0]
    nan = np.full((1, 5, 2), np.nan)
    assert not sane_crop_homography(SPEC, CROSSPOINT_CROP, nan, np.full((1, 3, 3), np.nan))[0]


def test_partial_recognizer_crops_add_partial_markers_with_a_visible_centre_and_a_sane_crop(markers):
    crosspoints, visible = markers
    rc = localization_rc(SPEC)
    flat = flat_marker()
    # whole; a corner hidden; the centre hidden; folded (centre hidden); edge-on with a corner hidden
    crosspoints = np.stack([flat, flat, flat, crosspoints[2], crosspoints[3]])
    seen = np.ones((5, K, K), bool)
    seen[1, rc[1, 0], rc[1, 1]] = False
    seen[2, rc[0, 0], rc[0, 1]] = False
    seen[3] = visible[2]
    seen[4, rc[4, 0], rc[4, 1]] = False
    gt = ground_truth(crosspoints, seen)
    np.testing.assert_array_equal(recognizer_markers(gt, SPEC), [0])
    np.testing.assert_array_equal(recognizer_markers(gt, SPEC, partial=True), [0, 1])
    image = np.random.default_rng(0).integers(0, 256, (256, 256, 3), np.uint8)
    crops, ids = recognizer_crops(image, gt, SPEC, partial=True)
    np.testing.assert_array_equal(ids, [0, 1])
    # the partial marker's crop is its five points' unwarp, as the whole one's (the same points)
    assert crops.shape == (2, 96, 96, 3) and np.array_equal(crops[0], crops[1])
    assert np.array_equal(crops[:1], recognizer_crops(image, gt, SPEC)[0])


def test_a_corner_off_the_fabric_is_completed_from_the_marker_s_crosspoints():
    rc = localization_rc(SPEC)
    flat = flat_marker()
    u, v = np.meshgrid(np.arange(K), np.arange(K))
    crosspoints = np.stack([flat, flat, flat])
    visible = np.ones((3, K, K), bool)
    cut = (u + v) < 10  # the garment's edge cuts the top-left corner off: TL off the fabric
    crosspoints[1][cut] = np.nan
    visible[1][cut] = False
    # the same cut, with only the centre's neighbourhood left on the fabric: too little to complete
    little = np.abs(u - 12) + np.abs(v - 12) > 1
    crosspoints[2][little] = np.nan
    visible[2][little] = False
    gt = ground_truth(crosspoints, visible)
    depth = gt.points_depth.copy()
    depth[~np.isfinite(gt.points_px).all(axis=2)] = np.nan
    gt = dataclasses.replace(gt, points_depth=depth)  # NaN off the fabric, as the factory saves it
    assert np.isnan(gt.points_px[1, 1]).all() and MIN_COMPLETION_CROSSPOINTS > 5
    points = completed_points(gt)
    # the flat marker's plane: its crosspoints' homography puts TL exactly where the uncut one has it
    np.testing.assert_allclose(points[1], flat[rc[:, 0], rc[:, 1]], atol=1e-3)
    np.testing.assert_array_equal(points[0], gt.points_px[0])  # nothing missing, nothing moved
    assert np.isnan(points[2, 1:]).all()  # five crosspoints on the fabric are too few
    cells = localizer_targets(gt)
    cx, cy = np.floor(gt.points_px[1, 0] / 8).astype(int)
    np.testing.assert_allclose(cells[cy, cx, 1:].reshape(5, 2) + [cx * 8, cy * 8], points[1], atol=1e-3)
    np.testing.assert_array_equal(recognizer_markers(gt, SPEC, partial=True), [0, 1])
    crops, ids = recognizer_crops(np.zeros((256, 256, 3), np.uint8), gt, SPEC, partial=True)
    assert crops.shape == (2, 96, 96, 3) and list(ids) == [0, 1]
    # the cut marker gets a crosspoint crop too: its targets on the fabric are exact, off it NaN
    _, xp_ids, xy, seen = crosspoint_crops(np.zeros((256, 256, 3), np.uint8), gt, SPEC)
    assert list(xp_ids) == [0, 1]
    canonical = crop_crosspoints_px(SPEC, CROSSPOINT_CROP)
    np.testing.assert_allclose(xy[1][~cut], canonical[~cut], atol=1e-3)
    assert np.isnan(xy[1][cut]).all() and not seen[1][cut].any()
    # jittered crops move the completed corner with the others
    moved = gt.jittered(0.5, np.random.default_rng(0)).points_px
    assert np.isfinite(moved[1]).all() and 0 < np.abs(moved[1] - points[1]).max() < 3


