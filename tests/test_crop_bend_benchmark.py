"""`benchmarks/crop_bend.py`: the crop maps' crosspoint errors on exact ground truth, on markers wrapped
round a cylinder (where the five points fit no homography) and on a flat one (where both maps agree)."""

import numpy as np
import pytest

from assets.pattern import RECOGNIZER_CROP, PatternSpec, crop_crosspoints_px, crop_localization_px
from assets.pattern.observation import ImageGroundTruth

SPEC = PatternSpec()


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("crop_bend")


def _truth(radius: float) -> ImageGroundTruth:
    """Two markers side by side, each wrapped round a cylinder of `radius` marker sides (None: flat)
    whose axis runs along its left edge, seen from 6 sides away (about 100 px a side)."""
    k = SPEC.crosspoints_per_side

    def project(uv: np.ndarray, shift: float) -> np.ndarray:
        x, y = uv[..., 0] / 96, uv[..., 1] / 96 - 0.5
        if radius is None:
            across, depth = x, 6.0
        else:
            angle = x / radius
            across, depth = radius * np.sin(angle), 6.0 + radius * (1.0 - np.cos(angle))
        return np.stack([shift + 600.0 * across / depth, 300.0 + 600.0 * y / depth], axis=-1)

    points = np.stack([project(crop_localization_px(SPEC, RECOGNIZER_CROP), s) for s in (100.0, 300.0)])
    crosspoints = np.stack([project(crop_crosspoints_px(SPEC, RECOGNIZER_CROP), s) for s in (100.0, 300.0)])
    return ImageGroundTruth(600, 600, np.array([3, 7], np.int32), points.astype(np.float32),
                            np.ones((2, 5), np.float32), np.ones((2, 5), bool), crosspoints.astype(np.float32),
                            np.ones((2, k, k), bool), np.full(2, 2, np.int8))


def test_the_bent_map_places_a_curved_marker_s_crosspoints_closer(bench):
    curved = bench.marker_errors(_truth(1.5), SPEC)
    homography, bent = (curved[name] for name in bench.MAPS)
    assert len(homography) == 2 and (homography > 0.2).all()  # cells: the plane is off on the cylinder
    assert (bent < homography / 2.5).all()
    flat = bench.marker_errors(_truth(None), SPEC)
    assert np.allclose(flat[bench.MAPS[0]], 0, atol=1e-4) and np.allclose(flat[bench.MAPS[1]], 0, atol=1e-4)  # float32
    assert np.allclose(flat["residual_cells"], 0, atol=1e-3) and (curved["residual_cells"] > 0.1).all()
    rows = bench.table(curved)
    assert rows[0]["markers"] == "all" and rows[0]["count"] == 2
    assert rows[0][bench.MAPS[1]] == pytest.approx(np.median(bent))


def test_markers_with_few_visible_crosspoints_are_left_out(bench):
    truth = _truth(1.5)
    truth.crosspoint_visible[1, :, 5:] = False  # 125 of 625 left: still counted
    truth.crosspoint_visible[0, :, 3:] = False  # 75 left: out
    assert len(bench.marker_errors(truth, SPEC)["bent"]) == 1
