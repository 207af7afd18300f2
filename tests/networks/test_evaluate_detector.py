"""The whole Detector's evaluation: `match_detections` / `detector_metrics` on hand-made detections
against a hand-made ground truth (exact answers), and `networks.evaluate_detector` with real untrained
networks on a tiny dataset folder (the one of test_evaluate, plus a garment template)."""

import json
from dataclasses import replace
from pathlib import Path
from typing import Sequence

import numpy as np
import pytest

from assets.fileio import save_npz
from assets.pattern import PatternSpec
from assets.pattern.observation import ImageGroundTruth
from networks.checkpoint import save_checkpoint
from networks.config import TrainConfig
from networks.detections import Detections
from networks.detector import STAGES, DetectorConfig
from networks.evaluate_detector import evaluate_detector, garment_tables, load_detector, main
from networks.metrics import detector_metrics, match_detections, rows_by_id
from tests.networks.test_detector import _networks
from tests.networks.test_evaluate import SPEC, write_factory_dataset

K = SPEC.crosspoints_per_side
SIDE = 48.0  # marker side in pixels: 2 px per cell


# ---- hand-made detections against a hand-made ground truth ---------------------------------------

def _square(x0: float, y0: float) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned marker with its TL corner at (x0, y0): five points (5, 2), crosspoints (K, K, 2)."""
    points = np.array([[x0 + SIDE / 2, y0 + SIDE / 2], [x0, y0], [x0 + SIDE, y0], [x0, y0 + SIDE],
                       [x0 + SIDE, y0 + SIDE]])
    step = SIDE / (K - 1)
    rows, cols = np.mgrid[0:K, 0:K]
    return points, np.stack([x0 + cols * step, y0 + rows * step], axis=-1)


#: ground truth: markers 0-3 fully visible, 4 partly (crosspoint rows 0-9 seen), 5 partly with its
#: centre hidden (not present for the matching); marker 3's own points are off a homography by 0.5 cell
GT_ORIGINS = [(10, 10), (100, 10), (190, 10), (280, 10), (10, 100), (100, 100)]
GT_IDS = [10, 11, 13, 14, 15, 16]


def _ground_truth() -> ImageGroundTruth:
    m = len(GT_ORIGINS)
    points, crosspoints = map(np.stack, zip(*(_square(*o) for o in GT_ORIGINS)))
    points[3, 0, 0] += 1.0  # 1 px = 0.5 cell: a curved marker
    visible = np.ones((m, K, K), bool)
    visible[4, 10:] = False
    visible[5, K // 2:] = False
    point_visible = np.ones((m, 5), bool)
    point_visible[4, 3:] = point_visible[5, [0, 3, 4]] = False
    return ImageGroundTruth(
        width=400, height=200, marker_id=np.array(GT_IDS, np.int32), points_px=points.astype(np.float32),
        points_depth=np.ones((m, 5), np.float32), point_visible=point_visible,
        crosspoints_px=crosspoints.astype(np.float32), crosspoint_visible=visible,
        status=np.array([2, 2, 2, 2, 1, 1], np.int8))


def _detections(gt: ImageGroundTruth) -> Detections:
    """a: marker 0, its TL 5 px off, every crosspoint 1 px off, one not seen; b: marker 1 with a wrong
    ID; c: marker 2 flagged partial; d: marker 4 flagged partial, two hidden crosspoint rows called
    visible; e: a false positive; marker 3 is missed."""
    pick = [0, 1, 2, 4]
    points = np.concatenate([gt.points_px[pick], _square(300, 120)[0][None]]).copy()
    points[0, 1] += [3.0, 4.0]
    crosspoints = np.concatenate([gt.crosspoints_px[pick], _square(300, 120)[1][None]]).copy()
    crosspoints[0] += [0.6, 0.8]
    visible = np.concatenate([gt.crosspoint_visible[pick], np.ones((1, K, K), bool)]).copy()
    visible[0, 3, 7] = False
    visible[3, 10:12] = True
    return Detections(
        marker_id=np.array([10, 12, 13, 15, 20], np.int64), confidence=np.full(5, 0.9, np.float32),
        points_px=points.astype(np.float32), crosspoints_px=crosspoints.astype(np.float32),
        crosspoint_visible=visible, partial=np.array([False, False, True, True, False]))


def _localized(gt: ImageGroundTruth) -> np.ndarray:
    """The localizer's own points: marker 0 with its centre 1 cell off, 1 exact, 2 with its centre 1.5
    cells off (why it was cut), 4 (partly visible, not counted), and one far from any marker."""
    points = np.concatenate([gt.points_px[[0, 1, 2, 4]].astype(np.float64), _square(300, 120)[0][None]])
    points[0, 0, 0] += 2.0
    points[2, 0, 1] += 3.0
    return points


def test_rows_by_id_finds_each_id_once_and_marks_the_absent():
    assert rows_by_id([5, 3, -1, 9], [9, 3, 4, -1, 5]).tolist() == [3, 1, -1, -1, 0]
    assert rows_by_id([], [1, 2]).tolist() == [-1, -1] and rows_by_id([1], []).tolist() == []


def test_match_detections_exact_counts():
    gt = _ground_truth()
    record = match_detections(_detections(gt), gt, SPEC, radius_px=4.0, localized_px=_localized(gt))
    assert (record["detections"], record["gt_markers"], record["gt_full"]) == (5, 5, 4)
    assert record["matched_full"].tolist() == [True, True, True, False]
    assert record["id_correct"].tolist() == [True, False, True, True]
    assert record["partial"].tolist() == [False, False, True, True]
    np.testing.assert_allclose(record["point_error_px"][:, 1], [5.0, 0, 0, 0], atol=1e-5)
    # right-ID matches a, c, d: a sees 624 of 625; d calls 50 hidden ones visible
    assert record["crosspoint_counts"].tolist() == [624 + 625 + 250, 50, 1]
    np.testing.assert_allclose(np.sort(record["crosspoint_error_px"])[-624:], 1.0, atol=1e-5)
    np.testing.assert_allclose(record["localizer_residual_cells"], [1.0, 0.0, 1.5], atol=1e-6)
    np.testing.assert_allclose(record["gt_residual_cells"], [0, 0, 0, 0.5], atol=1e-6)
    # not voted on and partial: c and d count as grown; scored by ID where the truth is visible
    assert (record["grown"], record["grown_shown"]) == (2, 2)
    assert np.isnan(record["grown_point_error_px"][1, 3:]).all()
    np.testing.assert_allclose(record["grown_point_error_px"][[0, 0, 0, 0, 0, 1, 1, 1], [0, 1, 2, 3, 4, 0, 1, 2]], 0,
                               atol=1e-5)
    assert len(record["grown_crosspoint_error_px"]) == 625 + 250
    # a voted partial marker (a cut one) is not grown; a grown ID the image does not show is not scored
    voted = _detections(gt)
    support = np.array([1, 1, 2, -1, -1], np.int16)
    marker_id = voted.marker_id.copy()
    marker_id[3] = 40
    partial = voted.partial.copy()
    partial[4] = True
    again = match_detections(replace(voted, id_support=support, marker_id=marker_id, partial=partial), gt, SPEC,
                             radius_px=4.0)
    assert (again["grown"], again["grown_shown"]) == (2, 0) and again["grown_point_error_px"].shape == (0, 5)
    with pytest.raises(ValueError, match="crosspoints per side"):
        match_detections(Detections.empty(K - 1), gt, SPEC)


def test_detector_metrics_pool_images():
    gt = _ground_truth()
    record = match_detections(_detections(gt), gt, SPEC, radius_px=4.0, localized_px=_localized(gt))
    nothing = match_detections(Detections.empty(K), gt, SPEC)  # an image where nothing was found
    # one marker's layout residual is one cell by construction, 1 within 1e-12 through the homography
    # fit: the threshold sits just above it, so that marker is not above
    one = detector_metrics([record], max_residual_cells=1.0 + 1e-9)
    assert one["images"] == 1 and one["detections"] == 5
    markers = one["markers"]["all"]
    assert (markers["true_positive"], markers["false_positive"], markers["false_negative"]) == (4, 1, 1)
    assert markers["precision"] == pytest.approx(0.8) and markers["recall"] == pytest.approx(0.8)
    assert one["markers"]["full"] == {"recall": 0.75, "true_positive": 3, "false_negative": 1}
    assert one["id_accuracy"]["all"] == {"accuracy": 0.75, "count": 4}
    assert one["id_accuracy"]["full"]["accuracy"] == pytest.approx(2 / 3)
    assert one["partial"]["full"]["fraction"] == pytest.approx(1 / 3) and one["partial"]["partly"]["fraction"] == 1.0
    tl = one["point_error_px"]["all"]["TL"]
    assert tl["count"] == 3 and tl["median"] == pytest.approx(0, abs=1e-5)
    assert tl["p95"] == pytest.approx(np.percentile([5.0, 0, 0], 95), abs=1e-4)
    assert one["point_error_px"]["not_partial"]["TL"]["median"] == pytest.approx(2.5, abs=1e-5)
    assert one["point_error_px"]["not_partial"]["centre"]["count"] == 2
    xp = one["crosspoints"]
    assert xp["markers"] == 3 and xp["error_px"]["count"] == 1499
    assert xp["error_px"]["median"] == pytest.approx(0, abs=1e-5) and xp["error_px"]["p95"] == pytest.approx(1, abs=1e-5)
    assert xp["visibility"]["precision"] == pytest.approx(1499 / 1549)
    assert xp["visibility"]["recall"] == pytest.approx(1499 / 1500)
    residual = one["layout_residual_cells"]
    assert residual["threshold"] == pytest.approx(1.0)
    assert residual["localizer"]["median"] == pytest.approx(1.0) and residual["localizer"]["p90"] == pytest.approx(1.4)
    assert residual["localizer"]["above_threshold"] == pytest.approx(1 / 3)  # 1.0 itself is not above
    assert residual["ground_truth"]["p90"] == pytest.approx(0.35) and residual["ground_truth"]["above_threshold"] == 0
    assert one["layout_residual_cells"]["localizer"]["count"] == 3
    grown = one["grown"]
    assert (grown["count"], grown["shown"]) == (2, 2)
    assert grown["centre_px"]["count"] == 2 and grown["corners_px"]["count"] == 6
    assert grown["crosspoints_px"] == {"median": pytest.approx(0, abs=1e-5), "p95": pytest.approx(0, abs=1e-5),
                                       "count": 875}

    two = detector_metrics([record, nothing])
    assert two["images"] == 2 and two["markers"]["all"]["false_negative"] == 1 + 5
    assert two["markers"]["full"]["recall"] == pytest.approx(3 / 8)
    assert two["id_accuracy"] == one["id_accuracy"] and two["partial"] == one["partial"]
    assert two["layout_residual_cells"]["localizer"]["above_threshold"] is None  # no threshold given
    assert two["layout_residual_cells"]["ground_truth"]["count"] == 8
    json.dumps(two)
    with pytest.raises(ValueError, match="no images"):
        detector_metrics([])


# ---- the Detector on a dataset folder ------------------------------------------------------------

def write_garment_dataset(root: Path, splits: dict[str, int]) -> Path:
    """`write_factory_dataset` of the synthesizer's images with a template.npz whose one panel holds
    all 64 IDs (only its layout_json: what the evaluation reads)."""
    root = write_factory_dataset(root, SPEC, splits)
    panel = PatternSpec(rows=8, cols=8, num_ids=64)
    layout = {"spec": SPEC.to_dict(), "panels": [{"name": "front", "spec": panel.to_dict(), "first_id": 0}]}
    save_npz(root / "template.npz", {"layout_json": np.frombuffer(json.dumps(layout).encode(), np.uint8)})
    return root


def untrained_checkpoints(folder: Path, names: Sequence[str] = ("localizer", "recognizer", "crosspoints")
                          ) -> list[Path]:
    """The test's untrained networks (localizer, recognizer, crosspoints) saved as `folder`/<name>.pt."""
    return [save_checkpoint(folder / f"{name}.pt", task, model, TrainConfig(task=task), SPEC)
            for name, task, model in zip(names, ("localizer", "recognizer", "crosspoints"), _networks(0))]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two test images of the synthesizer, and the garment's template."""
    return write_garment_dataset(tmp_path_factory.mktemp("ds"), {"test": 2})


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    return untrained_checkpoints(tmp_path_factory.mktemp("ckpt"))


def test_evaluate_detector_counts_add_up(dataset, checkpoints):
    detector = load_detector(*checkpoints, dataset, device="cpu", config=DetectorConfig(nms_radius_px=40.0,
                                                                                         localizer_scale=1.0),
                             batch_size=8)
    assert detector.layout is not None and len(garment_tables(dataset, detector.codebook)) == 1
    # untrained networks put centres tens of pixels off: a wide radius lets every metric see matches
    result = evaluate_detector(detector, dataset, "test", progress=False, radius_px=32.0)
    assert set(result) == {"data", "split", "radius_px", "tables", "presence_threshold", "images", "detections",
                           "markers", "id_accuracy", "partial", "point_error_px", "crosspoints",
                           "layout_residual_cells", "grown", "seconds", "seconds_per_image", "stage_seconds", "localizer_scale"}
    assert result["localizer_scale"] == {"config": 1.0, "median": 1.0, "min": 1.0, "max": 1.0, "per_image": [1.0, 1.0]}
    assert result["images"] == 2 and result["tables"] is True and result["seconds"] > 0
    assert tuple(result["stage_seconds"]) == STAGES
    assert 0 < sum(result["stage_seconds"].values()) <= result["seconds"]
    gt = [ImageGroundTruth.load(p) for p in sorted((dataset / "gt").glob("*.npz"))]
    present = sum(int(((g.status > 0) & g.point_visible[:, 0]).sum()) for g in gt)
    markers = result["markers"]["all"]
    assert markers["true_positive"] + markers["false_negative"] == present
    assert markers["true_positive"] + markers["false_positive"] + result["markers"]["on_hidden"] + \
        result["markers"]["by_id"] == result["detections"]
    assert markers["true_positive"] > 0 and result["point_error_px"]["all"]["centre"]["count"] > 0
    full = result["markers"]["full"]
    assert full["true_positive"] + full["false_negative"] == sum(int((g.status == 2).sum()) for g in gt)
    assert result["id_accuracy"]["all"]["count"] == markers["true_positive"]
    assert result["partial"]["full"]["count"] + result["partial"]["partly"]["count"] == markers["true_positive"]
    assert result["layout_residual_cells"]["ground_truth"]["count"] == full["true_positive"] + full["false_negative"]
    assert result["layout_residual_cells"]["threshold"] == detector.config.max_layout_residual_cells
    json.dumps(result)
    assert evaluate_detector(detector, dataset, "test", progress=False, limit=1)["images"] == 1
    with pytest.raises(ValueError, match="no images in split 'val'"):
        evaluate_detector(detector, dataset, "val", progress=False)


def test_cli(dataset, checkpoints, tmp_path, capsys):
    paths = [str(p) for p in checkpoints]
    args = ["--localizer", paths[0], "--recognizer", paths[1], "--crosspoints", paths[2], "--device", "cpu",
            "--nms-radius", "40", "--max-layout-residual", "2.5", "--no-progress"]
    out = tmp_path / "detector.json"
    assert main(args + ["--data", str(dataset), "--limit", "1", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["images"] == 1 and written["checkpoints"]["localizer"] == paths[0]
    assert written["layout_residual_cells"]["threshold"] == 2.5
    assert "markers.all.recall" in capsys.readouterr().out
    assert main(args + ["--data", str(tmp_path / "none")]) == 2
    assert "no such dataset folder" in capsys.readouterr().err
    assert main(args[2:] + ["--data", str(dataset)]) == 2
    assert "the Detector needs all three networks: --localizer missing" in capsys.readouterr().err
    assert main(args[6:] + ["--data", str(dataset)]) == 2
    assert "give the three networks: --localizer, --recognizer and --crosspoints" in capsys.readouterr().err
    swapped = ["--localizer", paths[1], "--recognizer", paths[1], "--crosspoints", paths[2]]
    assert main(swapped + ["--data", str(dataset), "--device", "cpu"]) == 2
    assert "expected a localizer checkpoint" in capsys.readouterr().err
    assert main(args + ["--data", str(dataset), "--localizer-scale", "0"]) == 2
    assert "localizer_scale must be in" in capsys.readouterr().err
    automatic = tmp_path / "auto.json"
    assert main(args + ["--data", str(dataset), "--limit", "1", "--localizer-scale", "auto", "--json", str(automatic)]) == 0
    chosen = json.loads(automatic.read_text())["localizer_scale"]
    assert chosen["config"] is None and 0 < chosen["min"] <= chosen["median"] <= chosen["max"] <= 1
    assert written["presence_threshold"] == 0.5
    lower = tmp_path / "lower.json"
    assert main(args + ["--data", str(dataset), "--limit", "1", "--presence-threshold", "0.3", "--json", str(lower)]) == 0
    assert json.loads(lower.read_text())["presence_threshold"] == 0.3
    assert main(args + ["--data", str(dataset), "--presence-threshold", "1.5"]) == 2
    assert "presence_threshold" in capsys.readouterr().err


def test_a_detection_of_a_marker_whose_centre_is_hidden_is_neither_true_nor_false():
    """Marker 5 is shown but its centre is hidden (no ground-truth marker of the matching): a detection
    on it found a real marker, and the precision does not count it; the far one stays false."""
    gt = _ground_truth()
    detections = _detections(gt)
    hidden = Detections(
        marker_id=np.array([16], np.int64), confidence=np.full(1, 0.9, np.float32),
        points_px=gt.points_px[[5]] + np.float32(1.0), crosspoints_px=gt.crosspoints_px[[5]],
        crosspoint_visible=gt.crosspoint_visible[[5]], partial=np.array([True]))
    both = Detections(**{field: np.concatenate([getattr(detections, field), getattr(hidden, field)])
                         for field in ("marker_id", "confidence", "points_px", "crosspoints_px",
                                       "crosspoint_visible", "partial")})
    before = match_detections(detections, gt, SPEC, radius_px=4.0)
    record = match_detections(both, gt, SPEC, radius_px=4.0)
    assert before["on_hidden"] == 0 and record["on_hidden"] == 1 and record["detections"] == 6
    markers = detector_metrics([record])["markers"]
    assert (markers["all"]["true_positive"], markers["all"]["false_positive"]) == (4, 1)
    assert markers["on_hidden"] == 1 and markers["all"]["precision"] == pytest.approx(0.8)


def test_a_detection_of_a_cut_marker_is_matched_by_its_id_and_crosspoints():
    """Marker 5's centre is off the fabric (NaN): no centre match can find it.  A detection with its ID
    whose visible crosspoints lie on its crosspoints found it (by_id); one 10 px off did not."""
    gt = _ground_truth()
    gt.points_px[5, 0] = np.nan
    detections = _detections(gt)

    def with_marker_5(shift: float) -> Detections:
        extra = Detections(
            marker_id=np.array([16], np.int64), confidence=np.full(1, 0.9, np.float32),
            points_px=gt.points_px[[5]] + np.float32(shift), crosspoints_px=gt.crosspoints_px[[5]] + np.float32(shift),
            crosspoint_visible=np.ones((1, K, K), bool), partial=np.array([True]))
        return Detections(**{field: np.concatenate([getattr(detections, field), getattr(extra, field)])
                             for field in ("marker_id", "confidence", "points_px", "crosspoints_px",
                                           "crosspoint_visible", "partial")})

    right = match_detections(with_marker_5(0.5), gt, SPEC, radius_px=4.0)
    assert (right["on_hidden"], right["by_id"]) == (0, 1)
    markers = detector_metrics([right])["markers"]
    assert (markers["all"]["true_positive"], markers["all"]["false_positive"], markers["by_id"]) == (4, 1, 1)
    off = match_detections(with_marker_5(10.0), gt, SPEC, radius_px=4.0)
    assert off["by_id"] == 0 and detector_metrics([off])["markers"]["all"]["false_positive"] == 2
