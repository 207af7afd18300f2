"""The Detector: its geometry on a fabric seen through a known homography (exact answers), partial
markers from neighbours, and the whole chain with real (untrained, seeded) networks on CPU."""

import dataclasses
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest
import torch

from assets.geometry import apply_homography, fit_homography
from assets.pattern import (
    CROSSPOINT_CROP,
    RECOGNIZER_CROP,
    CropGeometry,
    CropSpec,
    MarkerTable,
    PatternSpec,
    crop_crosspoints_px,
    generate_codebook,
    reference_textures,
    render_region,
    xy_to_pixel,
)
from networks.checkpoint import save_checkpoint
from networks.config import TrainConfig
from networks.detections import Detections
from networks.detector import (STAGES, Detector, DetectorConfig, DetectorResult, fully_observed, pad_images,
                               unwarp_markers, usable_points)
from networks.device_geometry import (crop_to_image_on_device, images_on_device, smooth_crosspoints_on_device,
                                      unwarp_markers_on_device)
from networks.homography import (
    auto_localizer_scale,
    crop_to_image,
    fit_homography_masked,
    layout_residual,
    marker_side_px,
)
from networks.localizer_scale import AUTO_LEVELS, auto_levels, sees_markers
from networks.neighbours import MarkerLayout, estimate_from_neighbours, predict_missing, vote_ids
from networks import homography as homography_module
from networks.models import CrosspointLocalizer, MarkerLocalizer, MarkerRecognizer

#: 64 IDs keep the codebook fast; 2 x 3 markers with IDs from 7 and an off-zero origin
SPEC = PatternSpec(rows=2, cols=3, num_ids=64, origin_xy=(0.031, -0.017))
FIRST_ID = 7
PX_PER_CELL = 8
#: flat render (continuous pixels) -> camera image (continuous pixels): rotation, shear, perspective
CAMERA = np.array([[0.78, 0.22, 60.0], [-0.12, 0.74, 70.0], [2.0e-4, 3.0e-4, 1.0]])
IMAGE_SIZE = (560, 470)  # (W, H)


@pytest.fixture(scope="module")
def codebook():
    return generate_codebook(SPEC)


@pytest.fixture(scope="module")
def table(codebook):
    return MarkerTable.build(SPEC, codebook, first_id=FIRST_ID)


@pytest.fixture(scope="module")
def scene(table):
    """The fabric rendered flat and warped by CAMERA: (image, true five points (M, 5, 2), true
    crosspoints (M, K, K, 2)), all in camera image pixels."""
    dpi = PX_PER_CELL / SPEC.pitch_mm * 25.4
    flat = render_region(table, dpi=dpi)
    to_cv = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]])  # OpenCV's pixel centres are at integers
    image = cv2.warpPerspective(flat, to_cv @ CAMERA @ np.linalg.inv(to_cv), IMAGE_SIZE, flags=cv2.INTER_AREA)
    bounds = SPEC.fabric_bounds
    points = apply_homography(CAMERA, xy_to_pixel(table.localization_xy, bounds, dpi))
    crosspoints = apply_homography(CAMERA, xy_to_pixel(table.marker_crosspoint_xy, bounds, dpi))
    return image, points, crosspoints


def test_unwarp_with_the_true_points_gives_the_reference_textures(table, scene):
    image, points, _ = scene
    m = table.num_markers
    for crop in (RECOGNIZER_CROP, CROSSPOINT_CROP):
        crops = unwarp_markers([image], np.zeros(m, np.int64), points, SPEC, crop).astype(np.float64)
        refs = reference_textures(SPEC, table.codes, crop).astype(np.float64)
        lo = round(crop.margin_cells * crop.px_per_cell(SPEC)) + 4
        hi = crop.size_px - lo
        # (marker, reference) mean absolute difference over the marker's inside
        error = np.abs(crops[:, None, lo:hi, lo:hi] - refs[None, :, lo:hi, lo:hi]).mean(axis=(2, 3, 4))
        assert (error.argmin(axis=1) == np.arange(m)).all()
        assert error.diagonal().max() < 12, error.diagonal()
        off = error + np.diag(np.full(m, np.inf))
        assert (error.diagonal() < 0.5 * off.min(axis=1)).all()


def test_crops_cut_on_the_device_are_the_host_crops_unrounded(scene):
    """The GPU path's crops (grid_sample through the same homographies), on CPU tensors: two images of
    different sizes, markers shifted off the image's edge (zero outside), in any order."""
    image, points, _ = scene
    second = np.ascontiguousarray(image[: image.shape[0] - 7, : image.shape[1] - 11, ::-1])
    shifted = points + np.array([image.shape[1] * 0.45, 3.0])  # some markers now cross the right edge
    images = [image, second]
    index = np.array([1, 0] * (len(points) // 2) + [0] * (len(points) % 2), dtype=np.int64)
    chosen = np.where(index[:, None, None] == 0, points, shifted)
    for crop in (RECOGNIZER_CROP, CROSSPOINT_CROP):
        host = unwarp_markers(images, index, chosen, SPEC, crop).astype(np.float64)
        device = unwarp_markers_on_device(images_on_device(images, torch.device("cpu")), index, chosen, SPEC, crop)
        device = device.permute(0, 2, 3, 1).numpy()
        assert device.shape == host.shape and device.dtype == np.float32
        difference = np.abs(device - host)
        # OpenCV interpolates at 1/32 px and rounds to uint8, the device path does neither: on a black to
        # white edge (255 a pixel) that is at most 2 x 255 / 64 + 0.5 apart
        assert difference.mean() < 0.6 and np.percentile(difference, 99.9) < 6.0 and difference.max() < 8.5
        outside = host.reshape(len(host), -1).max(axis=1) == 0
        assert not outside.all() and (device.reshape(len(device), -1)[outside].max(initial=0.0) < 1.0)
    empty = unwarp_markers_on_device(images_on_device(images, torch.device("cpu")), np.zeros(0, np.int64),
                                     np.zeros((0, 5, 2)), SPEC, CROSSPOINT_CROP)
    assert empty.shape == (0, 3, CROSSPOINT_CROP.size_px, CROSSPOINT_CROP.size_px)


def test_crop_crosspoints_map_back_to_the_true_image_crosspoints(scene):
    _, points, crosspoints = scene
    for crop in (RECOGNIZER_CROP, CROSSPOINT_CROP):
        canonical = np.broadcast_to(crop_crosspoints_px(SPEC, crop), crosspoints.shape)
        mapped = crop_to_image(SPEC, crop, points, canonical)
        assert mapped.shape == crosspoints.shape
        assert np.abs(mapped - crosspoints).max() < 1e-6


def test_layout_checks_tell_full_markers_from_cut_ones(scene):
    _, points, _ = scene
    assert layout_residual(SPEC, points).max() < 1e-6
    assert fully_observed(SPEC, points, IMAGE_SIZE, 1.0).all()
    bent = points.copy()
    bent[2, 2] += [18.0, 8.0]  # TR of marker 2 off its place by about 6 cells
    mirrored = points.copy()
    mirrored[4] = points[4][[0, 2, 1, 4, 3]]  # left and right swapped: a homography fits, but mirrored
    assert layout_residual(SPEC, bent)[2] > 1.0
    assert layout_residual(SPEC, mirrored)[4] < 1e-6
    for changed, index in ((bent, 2), (mirrored, 4)):
        full = fully_observed(SPEC, changed, IMAGE_SIZE, 1.0)
        assert not full[index] and full[np.arange(len(full)) != index].all()
    # the same markers in a smaller image: those reaching beyond its right edge are cut
    narrow = (int(np.ceil(points[:, :, 0].max())) - 20, IMAGE_SIZE[1])
    expected = (points[:, :, 0] <= narrow[0]).all(axis=1)
    assert 0 < expected.sum() < len(points)
    assert (fully_observed(SPEC, points, narrow, 1.0) == expected).all()
    degenerate = points.copy()
    degenerate[1] = points[1, :1]  # all five points at the centre
    degenerate[3, 2] = np.nan
    assert usable_points(SPEC, degenerate).tolist() == [True, False, True, False, True, True]


def test_smoothing_averages_noise_out_of_a_smooth_field_and_keeps_what_it_cannot_follow():
    """A smooth (cubic) crosspoint field with noise: the smoothed field is nearer the truth; a fold (a
    crosspoint 3 px off the field) keeps its own value; hidden crosspoints and markers with too few
    visible ones are untouched."""
    rng = np.random.default_rng(5)
    k = 25
    row, col = np.meshgrid(np.linspace(-1, 1, k), np.linspace(-1, 1, k), indexing="ij")
    truth = np.stack([8 + 96 * (col + 1) / 2 + 1.5 * col * row ** 2 - 0.8 * col ** 3,
                      8 + 96 * (row + 1) / 2 + 1.2 * row * col + 0.6 * row ** 3], axis=-1)
    truth = np.broadcast_to(truth, (3, k, k, 2)).copy()
    predicted = truth + rng.normal(0.0, 0.3, truth.shape)
    predicted[0, 10, 10] += [3.0, 0.0]  # a fold the network saw
    visible = np.ones((3, k, k), bool)
    visible[0, :, 20:] = False  # part of the first marker hidden
    visible[2] = False
    visible[2, :2, :3] = True  # six visible: too few for ten coefficients
    smoothed = homography_module.smooth_crosspoints(predicted, visible, 1.0)
    error = np.linalg.norm(smoothed - truth, axis=-1)
    before = np.linalg.norm(predicted - truth, axis=-1)
    seen = visible[:2].copy()
    seen[0, 10, 10] = False
    assert np.median(error[:2][seen]) < 0.5 * np.median(before[:2][seen])
    assert np.array_equal(smoothed[0, 10, 10], predicted[0, 10, 10])  # the fold is kept
    assert np.array_equal(smoothed[~visible], predicted[~visible])  # hidden ones untouched
    assert np.array_equal(smoothed[2], predicted[2])  # too few to fit
    with pytest.raises(ValueError, match="tolerance_px must be > 0"):
        homography_module.smooth_crosspoints(predicted, visible, 0.0)
    with pytest.raises(ValueError, match="must be in \\(0, 8\\]"):
        DetectorConfig(smooth_crosspoints_px=0.0)
    # the device version (CPU tensors here): the same fits, in float64, so the same values
    on_device = smooth_crosspoints_on_device(torch.from_numpy(predicted), torch.from_numpy(visible), 1.0)
    assert on_device.dtype == torch.float64 and np.abs(on_device.numpy() - smoothed).max() < 1e-9
    assert torch.equal(smooth_crosspoints_on_device(torch.zeros(0, k, k, 2), torch.zeros(0, k, k, dtype=torch.bool),
                                                    1.0), torch.zeros(0, k, k, 2, dtype=torch.float64))
    with pytest.raises(ValueError, match="tolerance_px must be > 0"):
        smooth_crosspoints_on_device(torch.from_numpy(predicted), torch.from_numpy(visible), 0.0)


def test_crop_to_image_on_device_is_the_host_map(scene):
    _, points, crosspoints = scene
    for crop in (RECOGNIZER_CROP, CROSSPOINT_CROP):
        canonical = np.broadcast_to(crop_crosspoints_px(SPEC, crop), crosspoints.shape) + 0.3
        host = crop_to_image(SPEC, crop, points, canonical)
        device = crop_to_image_on_device(SPEC, crop, points, torch.from_numpy(np.ascontiguousarray(canonical)))
        assert device.shape == host.shape and np.abs(device.numpy() - host).max() < 1e-9
    assert crop_to_image_on_device(SPEC, CROSSPOINT_CROP, np.zeros((0, 5, 2)), torch.zeros(0, 25, 25, 2)).shape == (0, 25, 25, 2)


def test_masked_homography_fit_ignores_masked_points():
    rng = np.random.default_rng(3)
    truth = np.array([[0.9, -0.2, 15.0], [0.3, 1.1, -4.0], [3e-4, -1e-4, 1.0]])
    src = rng.uniform(-50, 50, (4, 9, 2))
    dst = apply_homography(truth, src)
    mask = rng.random((4, 9)) < 0.7
    mask[:, :4] = True
    mask[3] = [True] * 3 + [False] * 6  # too few points: NaN
    dst[~mask] = np.nan  # masked-out points may be anything, NaN included
    src[~mask] += 1e3
    fitted = fit_homography_masked(src, dst, mask)
    assert np.allclose(fitted[:3], truth, atol=1e-9)
    assert np.isnan(fitted[3]).all()
    full = np.ones((1, 9), bool)
    clean = rng.uniform(-50, 50, (1, 9, 2))
    noisy = apply_homography(truth, clean) + rng.normal(0, 0.5, (1, 9, 2))
    assert np.allclose(fit_homography_masked(clean, noisy, full), fit_homography(clean, noisy), atol=1e-9)


def test_marker_layout_neighbours(table):
    other = MarkerTable.build(dataclasses.replace(SPEC, rows=1, cols=2), generate_codebook(SPEC), first_id=30)
    layout = MarkerLayout.from_tables([table, other], SPEC.num_ids)
    # panel 0 is 2 x 3 from ID 7: (0, 0) = 7 touches 8, 10, 11; (1, 1) = 11 touches all five others
    neighbours = layout.neighbours(np.array([7, 11, 30, 5, 99]))
    assert sorted(neighbours[0][neighbours[0] >= 0]) == [8, 10, 11]
    assert sorted(neighbours[1][neighbours[1] >= 0]) == [7, 8, 9, 10, 12]
    assert sorted(neighbours[2][neighbours[2] >= 0]) == [31]  # other panels are not neighbours
    assert (neighbours[3:] == -1).all()  # not on the garment, not an ID
    assert layout.contains(np.array([7, 12, 13, 30, 31, 32])).tolist() == [True, True, False, True, True, False]
    assert np.allclose(layout.localization_xy[11], table.localization_xy[4])
    with pytest.raises(ValueError, match=r"tables\[1\].*also in"):
        MarkerLayout.from_tables([table, table], SPEC.num_ids)


def test_cut_marker_is_recovered_from_its_neighbours(table, scene):
    _, points, _ = scene
    layout = MarkerLayout.from_tables([table], SPEC.num_ids)
    ids = table.marker_ids.astype(np.int64)
    detected = points.copy()
    detected[1, [2, 4]] += [[35.0, -12.0], [28.0, 20.0]]  # TR and BR of marker 8 are lost beyond a boundary
    detected[5, 1:] = detected[5, 0] + 3.0  # marker 12 collapsed: all five points are wrong
    full = fully_observed(SPEC, detected, IMAGE_SIZE, 1.0)
    assert full.tolist() == [True, False, True, True, True, False]
    confidence = np.linspace(0.9, 0.4, len(ids))
    estimate, estimated = estimate_from_neighbours(layout, SPEC, ids, detected, full, confidence, IMAGE_SIZE, 1.0)
    assert estimated.tolist() == [False, True, False, False, False, True]
    assert np.abs(estimate[[1, 5]] - points[[1, 5]]).max() < 1e-6
    assert np.array_equal(estimate[full], detected[full])
    # keep_own_cells: marker 8 keeps its own centre, TL and BL (0.3 px off, within 2 cells of the estimate)
    # and takes the estimate for TR and BR; marker 12's corners are too far off to keep, its centre is kept
    side = np.linalg.norm(points[1, 2] - points[1, 1])
    assert 0.3 < 2 * side / SPEC.cells_per_side < 0.8 * np.linalg.norm(detected[5, 1] - points[5, 1])
    noisy = detected.copy()
    noisy[1, [0, 1, 3]] += 0.3
    kept, estimated = estimate_from_neighbours(layout, SPEC, ids, noisy, full, confidence, IMAGE_SIZE, 1.0, 2.0)
    assert estimated.tolist() == [False, True, False, False, False, True]
    assert np.array_equal(kept[1, [0, 1, 3]], noisy[1, [0, 1, 3]])
    assert np.abs(kept[1, [2, 4]] - points[1, [2, 4]]).max() < 0.3  # the kept points joined the fit with their 0.3 px
    assert np.array_equal(kept[5, 0], noisy[5, 0]) and np.abs(kept[5, 1:] - points[5, 1:]).max() < 1e-6
    assert np.array_equal(kept[full], detected[full])
    with pytest.raises(ValueError, match="keep_own_cells must be > 0 or None, got 0.0"):
        DetectorConfig(keep_own_cells=0.0)
    # a wrong duplicate of a neighbour's ID with less confidence is ignored
    dup_ids = np.append(ids, ids[0])
    dup_points = np.concatenate([detected, detected[:1] + 40.0])
    dup_conf = np.append(confidence, 0.1)
    estimate, _ = estimate_from_neighbours(layout, SPEC, dup_ids, dup_points, np.append(full, True), dup_conf,
                                           IMAGE_SIZE, 1.0)
    assert np.abs(estimate[[1, 5]] - points[[1, 5]]).max() < 1e-6
    # without a detected full neighbour nothing is estimated
    alone = ~np.isin(np.arange(len(ids)), [0, 2, 3, 4])
    _, estimated = estimate_from_neighbours(layout, SPEC, ids[alone], detected[alone], full[alone],
                                            confidence[alone], IMAGE_SIZE, 1.0)
    assert not estimated.any()


def test_missed_markers_are_placed_by_their_full_neighbours(table, scene):
    """Markers 8 and 11 (middle column of 7 8 9 / 10 11 12) were not detected: each has four or five
    full detected neighbours, which place it exactly (the scene is one homography)."""
    _, points, _ = scene
    layout = MarkerLayout.from_tables([table], SPEC.num_ids)
    ids = table.marker_ids.astype(np.int64)
    seen = np.array([0, 2, 3, 5])  # 7, 9, 10, 12
    confidence = np.array([0.9, 0.8, 0.7, 0.6])
    grown, placed, conf = predict_missing(layout, ids[seen], points[seen], np.ones(4, bool), confidence, IMAGE_SIZE)
    assert grown.tolist() == [8, 11]
    assert np.abs(placed - points[[1, 4]]).max() < 1e-6
    assert conf == pytest.approx([0.75, 0.75])  # the mean of their four full neighbours'
    # a detected marker is not grown again, even when it is not full; nor is an ID beyond the panel
    grown, _, _ = predict_missing(layout, ids[[0, 1, 2, 3, 5]], points[[0, 1, 2, 3, 5]],
                                  np.array([True, False, True, True, True]), np.ones(5), IMAGE_SIZE)
    assert grown.tolist() == [11]
    # with one full neighbour, too few by default; markers entirely outside the image are dropped
    grown, _, _ = predict_missing(layout, ids[:1], points[:1], np.ones(1, bool), np.ones(1), IMAGE_SIZE)
    assert len(grown) == 0
    grown, _, _ = predict_missing(layout, ids[:1], points[:1], np.ones(1, bool), np.ones(1), IMAGE_SIZE,
                                  min_neighbours=1)
    assert grown.tolist() == [8, 10, 11]
    grown, _, _ = predict_missing(layout, ids[seen], points[seen] + 1e4, np.ones(4, bool), confidence, IMAGE_SIZE)
    assert len(grown) == 0
    # no full detection: nothing
    assert len(predict_missing(layout, ids[seen], points[seen], np.zeros(4, bool), confidence, IMAGE_SIZE)[0]) == 0


def test_vote_ids_restores_ids_that_the_neighbours_contradict(table, scene):
    _, points, _ = scene
    layout = MarkerLayout.from_tables([table], SPEC.num_ids)
    ids = table.marker_ids.astype(np.int64)  # 2 x 3 from 7: 7 8 9 / 10 11 12
    full = np.ones(len(ids), bool)
    voted, support = vote_ids(layout, SPEC, ids, points, full)
    assert np.array_equal(voted, ids)  # true IDs stay: each has all its neighbours' votes
    assert support.tolist() == [3, 5, 3, 3, 5, 3]
    wrong = ids.copy()
    wrong[4] = 9  # marker 11 (middle of the bottom row) read as 9, 8 read as an ID off the garment
    wrong[1] = 40
    voted, support = vote_ids(layout, SPEC, wrong, points, full)
    assert np.array_equal(voted, ids)
    assert support.tolist() == [3, 5, 3, 3, 5, 3]  # counted again with the corrected voters
    # cut markers (not voters) need min_votes_partial votes: with 7 and 11 cut, 11 gets 4 (8, 9, 10,
    # 12) and 7 gets 2 (8, 10)
    cut = full.copy()
    cut[[0, 4]] = False
    wrong = ids.copy()
    wrong[[0, 4]] = [12, 8]
    voted, _ = vote_ids(layout, SPEC, wrong, points, cut)
    assert voted.tolist() == [12] + ids[1:].tolist()
    voted, _ = vote_ids(layout, SPEC, wrong, points, cut, min_votes_partial=2)
    assert np.array_equal(voted, ids)
    # a neighbour further than `tolerance` marker sides from its slot is not found
    moved = points.copy()
    moved[4] += 0.4 * np.linalg.norm(points[4, 2] - points[4, 1])
    wrong = ids.copy()
    wrong[4] = 9
    assert vote_ids(layout, SPEC, wrong, moved, full)[0][4] == 9
    # a marker without a centre (its points off the fabric) takes no part; the others vote on
    lost = points.copy()
    lost[0] = np.nan
    wrong = ids.copy()
    wrong[4] = 9
    voted, support = vote_ids(layout, SPEC, wrong, lost, full)
    assert voted[4] == 11 and voted[0] == ids[0] and support[0] == 0 and support[4] == 4
    # one marker alone, or no voter: nothing to go by
    assert vote_ids(layout, SPEC, wrong[4:5], points[4:5], full[4:5])[0].tolist() == [9]
    assert np.array_equal(vote_ids(layout, SPEC, wrong, points, np.zeros(6, bool))[0], wrong)


def test_detector_votes_per_image_and_scores_a_voted_id_by_its_probability(detector, table, scene):
    image, points, _ = scene
    ids = table.marker_ids.astype(np.int64)
    wrong = ids.copy()
    wrong[4] = 9
    index = np.array([0] * 6 + [1])  # image 1 shows marker 11 alone, with the same wrong ID
    voted, support = detector.vote([image, image], index, np.concatenate([points, points[4:5]]), np.append(wrong, 9))
    assert np.array_equal(voted[:6], ids) and voted[6] == 9
    assert support.dtype == np.int16 and support.tolist() == [3, 5, 3, 3, 5, 3, 0]
    off = dataclasses.replace(detector.config, vote_ids=False)
    plain = Detector(detector.localizer, detector.recognizer, detector.crosspoints, SPEC, tables=[table],
                     codebook=detector.codebook, config=off)
    kept, support = plain.vote([image], index[:6], points, wrong)
    assert np.array_equal(kept, wrong) and (support == -1).all()
    # the probability of a given ID is the softmax entry the argmax path reports for its own pick
    best, probability = detector.recognize([image], np.zeros(6, np.int64), points)
    again = detector.recognize([image], np.zeros(6, np.int64), points, best)[1]
    assert np.allclose(again, probability, atol=1e-6)
    other = detector.recognize([image], np.zeros(6, np.int64), points, ids)[1]
    assert ((other <= probability + 1e-6) & (other > 0)).all()
    with pytest.raises(ValueError, match="vote_tolerance"):
        DetectorConfig(vote_tolerance=0.6)


def test_pad_images():
    a = np.full((5, 9, 3), 7, np.uint8)
    b = np.full((17, 3, 3), 9, np.uint8)
    batch = pad_images([a, b])
    assert batch.shape == (2, 24, 16, 3) and batch.dtype == np.uint8
    assert (batch[0, :5, :9] == 7).all() and batch[0, 5:].sum() == 0 and batch[0, :, 9:].sum() == 0
    assert (batch[1, :17, :3] == 9).all() and batch[1, 17:].sum() == 0


# ---- the whole chain with real networks ------------------------------------------------------

def _networks(seed):
    """Untrained networks; the localizer's last layer is scaled down and biased towards markers
    of 40 px with a centre inside each cell, so that every stage downstream has work to do."""
    torch.manual_seed(seed)
    localizer = MarkerLocalizer()
    with torch.no_grad():
        out = localizer.head.out
        out.weight.mul_(0.01)
        layout = torch.tensor([[4, 4], [-16, -16], [24, -16], [-16, 24], [24, 24]], dtype=torch.float32)
        out.bias.copy_(torch.cat([torch.tensor([3.0]), layout.reshape(-1)]))
    return localizer, MarkerRecognizer(SPEC.num_ids), CrosspointLocalizer()


@pytest.fixture(scope="module")
def detector(codebook, table):
    localizer, recognizer, crosspoints = _networks(0)
    config = DetectorConfig(nms_radius_px=40.0, localizer_scale=1.0)  # the tests' images at their own scale
    return Detector(localizer, recognizer, crosspoints, SPEC, batch_size=4, tables=[table], config=config,
                    codebook=codebook)


def _check(detections, image):
    k = SPEC.crosspoints_per_side
    n = len(detections)
    assert detections.marker_id.shape == (n,) and detections.marker_id.dtype == np.int64
    assert detections.confidence.shape == (n,) and detections.confidence.dtype == np.float32
    assert detections.points_px.shape == (n, 5, 2) and detections.points_px.dtype == np.float32
    assert detections.crosspoints_px.shape == (n, k, k, 2) and detections.crosspoints_px.dtype == np.float32
    assert detections.crosspoint_visible.shape == (n, k, k) and detections.crosspoint_visible.dtype == np.bool_
    assert detections.partial.shape == (n,) and detections.partial.dtype == np.bool_
    assert detections.id_support.shape == (n,) and (detections.id_support >= 0).all()  # a garment: votes taken
    assert ((detections.confidence >= 0) & (detections.confidence <= 1)).all()
    assert ((detections.marker_id >= FIRST_ID) & (detections.marker_id < FIRST_ID + 6)).all()  # on the garment
    assert np.isfinite(detections.points_px).all() and np.isfinite(detections.crosspoints_px).all()
    height, width = image.shape[:2]
    centre = detections.points_px[:, 0]
    assert ((centre >= 0) & (centre <= [width, height])).all()
    seen = detections.crosspoints_px[detections.crosspoint_visible]
    assert ((seen >= 0) & (seen <= [width, height])).all()


def test_detector_end_to_end_on_cpu(detector, table, scene):
    rng = np.random.default_rng(0)
    small = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    wide = np.ascontiguousarray(scene[0][200:296, 200:328])  # 96 x 128 of the fabric
    result = detector([small, wide])
    assert len(result) == 2
    for detections, image in zip(result, (small, wide)):
        _check(detections, image)
    for detections in result:  # every cell fires; the 40 px NMS leaves a few markers further apart
        assert 1 <= len(detections) <= 9
        centre = detections.points_px[:, 0].astype(np.float64)
        gaps = np.linalg.norm(centre[:, None] - centre[None], axis=-1) + np.eye(len(centre)) * 1e9
        assert gaps.min() > 40.0
    # NHWC on the CPU as on a GPU: less time per network
    for network in (detector.localizer, detector.recognizer, detector.crosspoints):
        kernels = [p for p in network.parameters() if p.dim() == 4 and p.shape[-1] > 1]
        assert kernels and all(p.is_contiguous(memory_format=torch.channels_last) for p in kernels)
    assert set(detector._references) == set(table.marker_ids.tolist())  # the garment's, rendered at construction
    alone = detector([wide])[0]  # batching does not change the answer
    assert np.array_equal(alone.marker_id, result[1].marker_id)
    assert np.allclose(alone.crosspoints_px, result[1].crosspoints_px, atol=1e-3)
    assert detector([]) == []
    # detect: the same detections, the localizer's own points (before completion) and scale per image,
    # and the seconds of this call's stages, in its result: the Detector keeps nothing of the call
    state = dict(vars(detector))
    run = detector.detect([small, wide])
    assert isinstance(run, DetectorResult) and run.localizer_scales == [1.0, 1.0]
    assert tuple(run.stage_seconds) == STAGES and all(seconds > 0 for seconds in run.stage_seconds.values())
    own, scales = detector.localize([small, wide])
    assert scales == [1.0, 1.0]
    for (points, presence), (own_points, own_presence) in zip(run.located, own):
        assert np.array_equal(points, own_points) and np.array_equal(presence, own_presence)
    for a, b in zip(run.detections, result):
        assert np.array_equal(a.marker_id, b.marker_id) and np.array_equal(a.points_px, b.points_px)
    assert vars(detector).keys() == state.keys() and all(vars(detector)[k] is v for k, v in state.items())
    empty = detector.detect([])
    assert empty.detections == empty.located == empty.localizer_scales == []
    with pytest.raises(ValueError, match=r"images\[1\]: expected uint8"):
        detector([small, small.astype(np.float32)])


def test_one_detector_serves_several_threads_at_once(detector, scene):
    """Calls from two threads at once give what each call gives alone, with its own scales."""
    images = [np.ascontiguousarray(scene[0][200:296, 200:328]), np.ascontiguousarray(scene[0][150:347, 180:441])]
    alone = [detector.detect([image]) for image in images]
    with ThreadPoolExecutor(max_workers=2) as pool:
        together = list(pool.map(lambda image: detector.detect([image]), images * 2))
    for run, expected in zip(together, alone * 2):
        assert run.localizer_scales == expected.localizer_scales
        (got,), (want,) = run.detections, expected.detections
        assert np.array_equal(got.marker_id, want.marker_id) and np.array_equal(got.points_px, want.points_px)
        assert np.allclose(got.crosspoints_px, want.crosspoints_px, atol=1e-4)


def test_the_detector_smooths_crosspoints_only_when_configured(codebook, table, scene):
    """smooth_crosspoints_px: the same markers and visibility, the visible crosspoints moved (a
    crosspoint network with a noisy last layer), the hidden ones not."""
    image = [np.ascontiguousarray(scene[0][200:296, 200:328])]
    localizer, recognizer, crosspoints = _networks(0)
    with torch.no_grad():
        crosspoints.decoder.out.weight.normal_(0.0, 0.02)
    made = {}
    for smooth in (None, 0.5):
        config = DetectorConfig(nms_radius_px=40.0, localizer_scale=1.0, smooth_crosspoints_px=smooth)
        made[smooth] = Detector(localizer, recognizer, crosspoints, SPEC, tables=[table], config=config,
                                codebook=codebook)(image)[0]
    raw, smoothed = made[None], made[0.5]
    assert np.array_equal(raw.marker_id, smoothed.marker_id) and np.array_equal(raw.points_px, smoothed.points_px)
    # visibility may change only at the image's edge, which a moved crosspoint can cross
    height, width = image[0].shape[:2]
    xy = raw.crosspoints_px
    at_edge = (xy < 2).any(axis=-1) | (xy[..., 0] > width - 2) | (xy[..., 1] > height - 2)
    assert np.array_equal(raw.crosspoint_visible[~at_edge], smoothed.crosspoint_visible[~at_edge])
    seen = raw.crosspoint_visible & smoothed.crosspoint_visible
    hidden = ~raw.crosspoint_visible & ~smoothed.crosspoint_visible & ~at_edge
    moved = np.linalg.norm(smoothed.crosspoints_px - raw.crosspoints_px, axis=-1)
    assert seen.sum() > 100 and (moved[seen] > 1e-3).mean() > 0.2 and np.allclose(moved[hidden], 0.0)


def test_detections_save_load_round_trip(tmp_path, detector, scene):
    image = np.ascontiguousarray(scene[0][200:264, 260:324])
    detections = detector([image])[0]
    assert len(detections) > 0
    path = tmp_path / "cache" / "view0.npz"
    detections.save(path)
    loaded = Detections.load(path)
    for name, array in detections.to_dict().items():
        assert np.array_equal(getattr(loaded, name), array) and getattr(loaded, name).dtype == array.dtype
    empty = Detections.empty(SPEC.crosspoints_per_side)
    empty.save(tmp_path / "empty.npz")
    assert len(Detections.load(tmp_path / "empty.npz")) == 0
    bad = dict(detections.to_dict(), partial=np.zeros(len(detections) + 1, bool))
    np.savez(tmp_path / "bad.npz", **bad)
    with pytest.raises(ValueError, match=r"bad\.npz: Detections\.partial: expected shape"):
        Detections.load(tmp_path / "bad.npz")
    older = {k: v for k, v in detections.to_dict().items() if k != "id_support"}  # saved before id_support
    np.savez(tmp_path / "older.npz", **older)
    assert (Detections.load(tmp_path / "older.npz").id_support == -1).all()
    assert (detections.select(np.arange(len(detections))[::-1]).id_support == detections.id_support[::-1]).all()
    with pytest.raises(ValueError, match="missing array"):
        np.savez(tmp_path / "short.npz", marker_id=detections.marker_id)
        Detections.load(tmp_path / "short.npz")


def test_from_checkpoints_rebuilds_the_detector_and_refuses_mixed_patterns(tmp_path, detector, table):
    paths = {}
    for task, model in (("localizer", detector.localizer), ("recognizer", detector.recognizer),
                        ("crosspoints", detector.crosspoints)):
        paths[task] = save_checkpoint(tmp_path / f"{task}.pt", task, model, TrainConfig(task=task), SPEC)
    loaded = Detector.from_checkpoints(paths["localizer"], paths["recognizer"], paths["crosspoints"], device="cpu",
                                       batch_size=4, tables=[table], config=detector.config)
    assert loaded.spec == SPEC and loaded.layout is not None and loaded.device == torch.device("cpu")
    for name in ("localizer", "recognizer", "crosspoints"):
        mine, theirs = getattr(detector, name).state_dict(), getattr(loaded, name).state_dict()
        assert mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)
        assert not getattr(loaded, name).training
    other = dataclasses.replace(SPEC, seed=1)  # another codebook
    save_checkpoint(tmp_path / "other.pt", "localizer", detector.localizer, TrainConfig(task="localizer"), other)
    with pytest.raises(ValueError, match="do not share one pattern"):
        Detector.from_checkpoints(tmp_path / "other.pt", paths["recognizer"], paths["crosspoints"], device="cpu")
    with pytest.raises(ValueError, match="expected a crosspoints checkpoint"):
        Detector.from_checkpoints(paths["localizer"], paths["recognizer"], paths["localizer"], device="cpu")


def test_detector_completes_cut_markers_of_each_image(detector, table, scene):
    _, points, _ = scene
    ids = table.marker_ids.astype(np.int64)
    detected = points.copy()
    detected[4, [3, 4]] += [[40.0, -60.0], [-40.0, -60.0]]  # marker 11 cut: BL, BR guessed on its visible part
    image = np.zeros((IMAGE_SIZE[1], IMAGE_SIZE[0], 3), np.uint8)
    # two images: in the second, marker 11 is alone, so it keeps its own points
    image_index = np.array([0] * 6 + [1])
    both = np.concatenate([detected, detected[[4]]])
    both_ids = np.concatenate([ids, ids[[4]]])
    completed, partial = detector.complete_partial([image, image], image_index, both, both_ids, np.ones(7))
    assert partial.tolist() == [False] * 4 + [True] + [False] * 2
    assert np.abs(completed[4] - points[4]).max() < 1e-6
    assert np.array_equal(completed[np.arange(7) != 4], both[np.arange(7) != 4])


def test_detector_grows_missed_markers_of_each_image(detector, table, scene):
    """Image 0 misses markers 8 and 11, image 1 shows 7 alone: only image 0 grows, its two markers
    placed by their neighbours; with grow_missing off, nothing grows."""
    _, points, _ = scene
    ids = table.marker_ids.astype(np.int64)
    seen = [0, 2, 3, 5]
    image = np.zeros((IMAGE_SIZE[1], IMAGE_SIZE[0], 3), np.uint8)
    image_index = np.array([0] * 4 + [1])
    both, both_ids = np.concatenate([points[seen], points[:1]]), np.concatenate([ids[seen], ids[:1]])
    index, grown, placed, confidence = detector.grow([image, image], image_index, both, both_ids, np.ones(5),
                                                    np.zeros(5, bool))
    assert index.tolist() == [0, 0] and grown.tolist() == ids[[1, 4]].tolist()
    assert np.abs(placed - points[[1, 4]]).max() < 1e-6 and confidence.tolist() == [1.0, 1.0]
    saved = detector.config
    detector.config = dataclasses.replace(saved, grow_missing=False)
    try:
        assert len(detector.grow([image, image], image_index, both, both_ids, np.ones(5), np.zeros(5, bool))[0]) == 0
    finally:
        detector.config = saved
    with pytest.raises(ValueError, match="grow_min_neighbours"):
        DetectorConfig(grow_min_neighbours=0)


def test_detector_checks_its_inputs(codebook, table):
    with pytest.raises(ValueError, match="presence_threshold must be in"):
        DetectorConfig(presence_threshold=1.5)
    other = MarkerTable.build(SPEC, generate_codebook(dataclasses.replace(SPEC, seed=3)), first_id=FIRST_ID)
    localizer, recognizer, crosspoints = _networks(1)
    with pytest.raises(ValueError, match=r"tables\[0\].*codebook"):
        Detector(localizer, recognizer, crosspoints, SPEC, tables=[other], codebook=codebook)
    with pytest.raises(ValueError, match="recognizer has 64 IDs, the codebook only 32"):
        Detector(localizer, recognizer, crosspoints, SPEC, codebook=codebook[:32])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_detector_on_cuda_matches_cpu(detector, table, scene):
    import copy

    networks = [copy.deepcopy(getattr(detector, name)) for name in ("localizer", "recognizer", "crosspoints")]
    on_gpu = Detector(*networks, SPEC, device="cuda", batch_size=3, tables=[table], config=detector.config,
                      codebook=detector.codebook)
    images = [np.ascontiguousarray(scene[0][200:296, 200:328]), np.ascontiguousarray(scene[0][100:164, 300:364])]
    for cpu, gpu, image in zip(detector(images), on_gpu(images), images):
        _check(gpu, image)
        assert np.array_equal(cpu.marker_id, gpu.marker_id) and np.array_equal(cpu.partial, gpu.partial)
        assert np.abs(cpu.points_px - gpu.points_px).max() < 1e-2
        assert np.abs(cpu.crosspoints_px - gpu.crosspoints_px).max() < 0.1


def test_stages_given_the_images_on_the_device_match_the_host_crops(detector, scene):
    """What the GPU path runs (crops cut from images already on the device), on the CPU: the same IDs
    and nearly the same probabilities and crosspoints as from OpenCV's crops."""
    image, points, _ = scene
    index = np.zeros(len(points), np.int64)
    on_device = images_on_device([image], torch.device("cpu"))
    ids, probability = detector.recognize([image], index, points)
    ids_device, probability_device = detector.recognize([image], index, points, on_device=on_device)
    assert np.array_equal(ids, ids_device) and np.abs(probability - probability_device).max() < 0.02
    xy, visible = detector.locate_crosspoints([image], index, points, ids)
    xy_device, visible_device = detector.locate_crosspoints([image], index, points, ids, on_device)
    assert (visible == visible_device).mean() > 0.99
    assert np.median(np.abs(xy - xy_device)) < 0.01 and np.abs(xy - xy_device).max() < 0.2


def test_localizer_scale_maps_points_back_to_full_resolution(detector, scene):
    """The localizer on an image at localizer_scale s gives the points it gives on the image resized
    by s (the same network, area resampling), times the per-axis size ratio."""
    image = np.ascontiguousarray(scene[0][150:347, 180:441])  # 261 x 197: the halves round, per axis
    scaled = Detector(detector.localizer, detector.recognizer, detector.crosspoints, SPEC, codebook=detector.codebook,
                      config=dataclasses.replace(detector.config, localizer_scale=0.5))
    (points, score), = scaled.localize([image])[0]
    small = cv2.resize(image, (130, 98), interpolation=cv2.INTER_AREA)
    (expected, expected_score), = detector.localize([small])[0]
    assert scaled.localize([image])[1] == [0.5] and detector.localize([image], scales=[0.5])[1] == [0.5]
    assert all(np.array_equal(a, b) for a, b in zip(detector.localize([image], scales=[0.5])[0][0], (points, score)))
    with pytest.raises(ValueError, match="2 scales for 1 images"):
        detector.localize([image], scales=[0.5, 1.0])
    assert len(points) >= 1 and len(points) == len(expected)
    assert np.allclose(score, expected_score)
    assert np.allclose(points, expected * np.array([261 / 130, 197 / 98], np.float32), atol=1e-3)
    centre = points[:, 0]
    assert ((centre >= 0) & (centre <= [261, 197])).all()
    with pytest.raises(ValueError, match="localizer_scale must be in"):
        DetectorConfig(localizer_scale=0.0)


def _square_marker(side, angle, centre):
    """Five points (centre, TL, TR, BL, BR) of a square marker of `side` px turned by `angle`."""
    local = np.array([[0, 0], [-1, -1], [1, -1], [-1, 1], [1, 1]], np.float64) * side / 2
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return local @ turn.T + centre


def test_marker_side_is_the_square_root_of_its_corner_quad_area():
    square = _square_marker(20.0, 0.3, [100.0, 50.0])
    stretched = square * [2.0, 1.0]  # area doubled
    assert np.allclose(marker_side_px(np.stack([square, stretched])), [20.0, 20.0 * np.sqrt(2)])


def test_auto_localizer_scale_aims_at_the_marker_size():
    def markers(side, count=8):
        return np.stack([_square_marker(side, 0.1 * i, [50.0 * i, 30.0]) for i in range(count)])
    assert auto_localizer_scale(markers(44.0), 0.5, 22.0) == pytest.approx(0.5)
    assert auto_localizer_scale(markers(110.0), 0.5, 22.0) == pytest.approx(0.2)
    assert auto_localizer_scale(markers(11.0), 0.5, 22.0) == 1.0  # never enlarged
    assert auto_localizer_scale(markers(1000.0), 0.5, 22.0) == 1 / 16
    assert auto_localizer_scale(markers(44.0, count=7), 0.3, 22.0) == 0.3  # too few to measure
    with pytest.raises(ValueError, match="localizer_marker_px"):
        DetectorConfig(localizer_scale=None, localizer_marker_px=2.0)


def test_auto_levels_start_at_a_64_px_image_and_a_pass_sees_markers_when_they_are_confident():
    assert auto_levels((1080, 1920)) == list(AUTO_LEVELS)  # 1/16 shows 120 px
    assert auto_levels((470, 560)) == [1 / 8, 1 / 4, 1 / 2, 1.0]  # 1/16 would show 35 px
    assert auto_levels((64, 96)) == [1.0]
    assert auto_levels((20, 30)) == [1.0]  # 1 always
    assert sees_markers(np.full(8, 0.9, np.float32)) and not sees_markers(np.full(7, 0.99, np.float32))
    assert not sees_markers(np.array([0.99] * 4 + [0.6] * 5, np.float32))  # median 0.6
    assert not sees_markers(np.zeros(0, np.float32))


def test_auto_localizer_scale_is_a_pass_at_the_scale_it_reports(detector, scene):
    """localizer_scale None: whatever the search chose for each image (here with untrained networks),
    the markers are those of a pass at the reported scale, in a batch of images of different sizes as
    alone; an image too small for a coarser level is seen at 1."""
    def at(scale):
        return Detector(detector.localizer, detector.recognizer, detector.crosspoints, SPEC, codebook=detector.codebook,
                        config=dataclasses.replace(detector.config, localizer_scale=scale))

    image, small = scene[0], np.ascontiguousarray(scene[0][200:264, 250:346])
    auto = at(None)
    found, scales = auto.localize([image, small])
    assert scales[1] == 1.0 and 1 / 16 <= scales[0] <= 1.0
    for one, (points, score), scale in zip((image, small), found, scales):
        (expected, expected_score), = at(scale).localize([one])[0]
        assert len(points) == len(expected)
        assert np.allclose(points, expected, atol=1e-3) and np.allclose(score, expected_score, atol=1e-5)
    assert auto.detect([image, small]).localizer_scales == scales


def test_the_detector_cuts_the_recognizers_crops_as_its_network_carries_them(codebook, table, scene):
    """The recognizer's crops are its `crops.recognizer` (from its checkpoint's crop geometry), not a
    Detector's own constant: a 64 px recognizer gets 64 px crops, and its probabilities on them."""
    image, points, _ = scene
    localizer, _, crosspoints = _networks(0)
    torch.manual_seed(3)
    small = CropGeometry(recognizer=CropSpec(64, 0))
    recognizer = MarkerRecognizer(SPEC.num_ids, crops=small).eval()
    detector = Detector(localizer, recognizer, crosspoints, SPEC, tables=[table], codebook=codebook)
    index = np.zeros(len(points), np.int64)
    ids, probability = detector.recognize([image], index, points)
    crops = unwarp_markers([image], index, points, SPEC, small.recognizer)
    with torch.inference_mode():
        expected = torch.softmax(recognizer(detector._to_device(crops)).float(), dim=1).numpy()
    assert crops.shape[1:3] == (64, 64)
    assert np.allclose(expected[np.arange(len(ids)), ids], probability, atol=1e-5)
