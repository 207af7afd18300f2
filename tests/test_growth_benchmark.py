"""`benchmarks/growth.py`: the markers growth places, scored against the truth per model, on the true
points of a 5 x 5 panel wrapped round a cylinder (where one homography is off and a bent fit is not)."""

import numpy as np
import pytest

from assets.pattern import MarkerTable, PatternSpec, generate_codebook
from assets.pattern.observation import ImageGroundTruth
from networks.neighbours import MarkerLayout

SPEC = PatternSpec(rows=5, cols=5, num_ids=64)


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("growth")


def _cylinder(table: MarkerTable) -> ImageGroundTruth:
    """Every marker fully visible, its five points on a cylinder of radius 3 marker widths seen from 10
    (markers about 100 px), the rightmost column only partly visible (its right-hand corners hidden)."""
    xy = table.localization_xy
    width = np.linalg.norm(xy[0, 2] - xy[0, 1])
    x = (xy[..., 0] - xy[12, 0, 0]) / width - 0.7
    y = (xy[..., 1] - xy[12, 0, 1]) / width
    angle = x / 3.0
    depth = 10.0 + 3.0 * (1.0 - np.cos(angle))
    points = np.stack([1000 + 1000 * 3.0 * np.sin(angle) / depth, 1000 + 1000 * y / depth], axis=-1)
    m, k = len(xy), SPEC.crosspoints_per_side
    visible = np.ones((m, 5), bool)
    status = np.full(m, 2, np.int8)
    right = table.marker_rc[:, 1] == 4
    visible[np.ix_(right, [2, 4])] = False
    status[right] = 1
    return ImageGroundTruth(2000, 2000, table.marker_ids.astype(np.int32), points.astype(np.float32),
                            np.ones((m, 5), np.float32), visible, np.zeros((m, k, k, 2), np.float32),
                            np.ones((m, k, k), bool), status)


def test_models_are_parsed_and_checked(bench):
    assert bench.parse_models("none/0, 1.5/2") == [(None, 0), (1.5, 2)]
    for bad in ("1.5", "0/2", "none/-1", "x/1"):
        with pytest.raises(SystemExit, match="--models"):
            bench.parse_models(bad)


def test_grown_markers_are_scored_where_the_truth_is_visible(bench):
    table = MarkerTable.build(SPEC, generate_codebook(SPEC), first_id=0)
    layout = MarkerLayout.from_tables([table], SPEC.num_ids)
    truth = [_cylinder(table)]
    plane = bench.grow_errors(layout, truth, (None, 0), 0.0, 0.3, 2)
    bent = bench.grow_errors(layout, truth, (None, 2), 0.0, 0.3, 2)
    # the dropped full markers are scored at all five points, the partial column at its visible ones only
    assert len(plane["full"]) == len(bent["full"]) > 0 and np.isfinite(plane["full"]).all()
    assert 0 < len(plane["partial"]) <= 3 * 5  # the partial column, where 2 neighbours were left, in 3 draws
    assert np.isnan(plane["partial"][:, [2, 4]]).all() and np.isfinite(plane["partial"][:, [0, 1, 3]]).all()
    # one homography is off on the cylinder; the bent fit takes the shared corners and bends to the centre
    plane_stats, bent_stats = bench.summary(plane["full"]), bench.summary(bent["full"])
    assert plane_stats["centre_median"] > 0.5 and bent_stats["centre_median"] < plane_stats["centre_median"] / 3
    assert bent_stats["corner_median"] < 1e-6 and bent_stats["markers"] == plane_stats["markers"]


def test_surrounded_needs_a_detected_neighbour_on_each_side(bench):
    table = MarkerTable.build(SPEC, generate_codebook(SPEC), first_id=0)
    layout = MarkerLayout.from_tables([table], SPEC.num_ids)
    # the middle marker (12) with its four diagonal neighbours: each side has one
    assert bench.surrounded(layout, np.array([12]), np.array([6, 8, 16, 18])).tolist() == [True]
    # with only the right-hand column of its neighbours, or a marker on the panel's edge: not
    assert bench.surrounded(layout, np.array([12]), np.array([8, 13, 18])).tolist() == [False]
    assert bench.surrounded(layout, np.array([10]), np.array([5, 6, 11, 15, 16])).tolist() == [False]
