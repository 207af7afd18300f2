"""The ground-truth detections mode on a real tiny capture made here with the factory (the session's
short shirt walk rendered by Blender from three cameras), and triangulation of them."""

import shutil

import numpy as np
import pytest

from reconstruction.groundtruth import GroundTruthCapture, GroundTruthConfig, ground_truth_detections
from reconstruction.triangulation import TriangulationConfig, triangulate_frame
from reconstruction.views import Views

pytestmark = pytest.mark.slow  # the shared shirt simulation (about 70 s, once per session) and renders


@pytest.fixture(scope="module")
def ground_truth(capture_folder):
    return GroundTruthCapture(capture_folder)


def test_noise_free_ground_truth_triangulates_to_the_garment(ground_truth):
    assert ground_truth.frames == [3, 4] and [c.name for c in ground_truth.cameras] == ["cam00", "cam01", "cam02"]
    crosspoints = ground_truth.crosspoint_map
    config = GroundTruthConfig()
    for frame in ground_truth.frames:
        detections = ground_truth.detections(frame, config)
        points = triangulate_frame(crosspoints, ground_truth.cameras, detections,
                                   TriangulationConfig(neighbours=None), frame=frame, source=config.source)
        assert points.source == "groundtruth(noise=0px, dropout=0, unit=crosspoint, seed=0)"
        assert points.level_mm == 12 and points.frame == frame
        # every crosspoint visible in two or more views is captured, from exactly those views
        seen = np.zeros((crosspoints.num_crosspoints, 3), bool)
        for c in range(3):
            gt = ground_truth.ground_truth(frame, c)
            marker, row, col = np.nonzero(gt.crosspoint_visible)
            key, known = crosspoints.lookup(gt.marker_id[marker], row, col)
            assert known.all()
            seen[crosspoints.flat(key), c] = True
        captured = crosspoints.flat(points.key)
        assert len(points) > 1000
        np.testing.assert_array_equal(captured, np.flatnonzero(seen.sum(axis=1) >= 2))
        np.testing.assert_array_equal(points.views, seen[captured])
        # at the ground-truth garment's positions (garment.npz interpolated at the crosspoints)
        truth = ground_truth.crosspoints(frame, points.key)
        assert np.abs(points.xyz - truth).max() < 1e-6
        # the neighbour check (on by default) drops only what no other marker's crosspoint confirms:
        # here a few small patches of these 96 x 64 views
        checked = triangulate_frame(crosspoints, ground_truth.cameras, detections, frame=frame)
        assert np.isin(crosspoints.flat(checked.key), captured).all() and len(checked) > 0.95 * len(points)


def test_detections_are_the_visible_crosspoints(ground_truth):
    gt = ground_truth.ground_truth(3, 1)
    detections = ground_truth_detections(gt, GroundTruthConfig(), np.random.default_rng(0))
    present = gt.crosspoint_visible.any(axis=(1, 2))
    np.testing.assert_array_equal(detections.marker_id, gt.marker_id[present])
    np.testing.assert_array_equal(detections.crosspoint_visible, gt.crosspoint_visible[present])
    visible = detections.crosspoint_visible
    np.testing.assert_array_equal(detections.crosspoints_px[visible], gt.crosspoints_px[present][visible])
    assert (detections.confidence == 1).all()
    np.testing.assert_array_equal(detections.partial, ~gt.point_visible[present].all(axis=1))
    np.testing.assert_array_equal(detections.points_px[:, 1], detections.crosspoints_px[:, 0, 0])  # TL


def test_noise_and_dropout_are_seeded_and_named(ground_truth):
    config = GroundTruthConfig(noise_px=0.3, dropout=0.1, seed=5)
    assert config.source == "groundtruth(noise=0.3px, dropout=0.1, unit=crosspoint, seed=5)"
    first, again = ground_truth.detections(3, config), ground_truth.detections(3, config)
    other = ground_truth.detections(3, GroundTruthConfig(noise_px=0.3, dropout=0.1, seed=6))
    offsets, kept, total = [], 0, 0
    for c, (a, b, d) in enumerate(zip(first, again, other)):
        for name, array in a.to_dict().items():
            np.testing.assert_array_equal(array, b.to_dict()[name])
        assert not np.array_equal(a.crosspoint_visible, d.crosspoint_visible)
        gt = ground_truth.ground_truth(3, c)
        rows = np.searchsorted(gt.marker_id, a.marker_id)
        assert (a.crosspoint_visible <= gt.crosspoint_visible[rows]).all()
        kept += a.crosspoint_visible.sum()
        total += gt.crosspoint_visible.sum()
        offsets.append((a.crosspoints_px - gt.crosspoints_px[rows])[a.crosspoint_visible])
    offsets = np.concatenate(offsets)
    assert len(offsets) > 10000
    assert abs(offsets.std() - 0.3) < 0.01 and abs(offsets.mean()) < 0.01
    assert abs(kept / total - 0.9) < 0.01
    markers = GroundTruthConfig(dropout=0.25, unit="marker")
    dropped = ground_truth.detections(4, markers)
    present = [ground_truth.ground_truth(4, c).crosspoint_visible.any(axis=(1, 2)).sum() for c in range(3)]
    share = sum(len(d) for d in dropped) / sum(present)
    assert 0.6 < share < 0.9
    for c, d in enumerate(dropped):  # whole markers go; the others keep every visible crosspoint
        gt = ground_truth.ground_truth(4, c)
        np.testing.assert_array_equal(d.crosspoint_visible, gt.crosspoint_visible[np.searchsorted(gt.marker_id,
                                                                                                   d.marker_id)])
    with pytest.raises(ValueError, match="dropout must be a fraction"):
        GroundTruthConfig(dropout=1.0)


def test_id_errors_replace_ids_with_garment_ids_and_leave_the_rest(ground_truth):
    exact = GroundTruthConfig(noise_px=0.3, seed=2)
    wrong = GroundTruthConfig(noise_px=0.3, seed=2, id_error=0.3)
    assert wrong.source == "groundtruth(noise=0.3px, dropout=0, unit=crosspoint, id_error=0.3, seed=2)"
    garment = set(ground_truth.garment_ids.tolist())
    changed = total = 0
    for a, b in zip(ground_truth.detections(3, exact), ground_truth.detections(3, wrong)):
        for name in ("crosspoints_px", "crosspoint_visible", "points_px", "partial"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))  # only the IDs differ
        assert set(b.marker_id.tolist()) <= garment
        changed += int((a.marker_id != b.marker_id).sum())
        total += len(a)
    # each ID is replaced with probability 0.3 by a garment ID, which may be the true one; within four
    # standard deviations of that binomial share (the fixture's markers follow its simulated cloth)
    share = 0.3 * (1 - 1 / len(garment))
    assert abs(changed / total - share) < 4 * np.sqrt(share * (1 - share) / total)
    gt = ground_truth.ground_truth(3, 0)
    with pytest.raises(ValueError, match="garment_ids"):
        ground_truth_detections(gt, wrong, np.random.default_rng(0))
    with pytest.raises(ValueError, match="id_error must be a fraction"):
        GroundTruthConfig(id_error=1.0)


def test_the_capture_folder_is_read_as_views_and_checked(capture_folder, ground_truth, tmp_path):
    views = Views.open(capture_folder, ground_truth.cameras)
    assert views.frames == (3, 4)
    image = views.image(4, "cam02")
    assert image.shape == (64, 96, 3) and image.dtype == np.uint8 and image.std() > 0
    partial = tmp_path / "partial"
    partial.mkdir()
    shutil.copy(capture_folder / "cameras.json", partial)
    for c in ("cam00", "cam01", "cam02"):
        shutil.copytree(capture_folder / c, partial / c)
    (partial / "cam01" / "f000004_gt.npz").unlink()
    with pytest.raises(ValueError, match=r"not synchronised: cam01 lacks frame\(s\) 4"):
        GroundTruthCapture(partial)
    with pytest.raises(ValueError, match="not a capture folder"):
        GroundTruthCapture(tmp_path)
    with pytest.raises(ValueError, match=r"no ground truth for frame 5"):
        ground_truth.detections(5)
