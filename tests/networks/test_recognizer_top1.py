"""`networks.recognizer_top1`: a marker's shape in the image, and the recognizer's top-1 tallied by group,
marker size, layout residual and share of crosspoints visible."""

from pathlib import Path

import numpy as np
import pytest

from networks.recognizer_top1 import GROUPS, by_residual, by_visible, marker_shape, size_bin, tally


def _points(linear: np.ndarray, edge: float, offset=(100.0, 50.0)) -> np.ndarray:
    """Five points (centre, TL, TR, BL, BR) of a marker of `edge` px seen through `linear` (2 x 2)."""
    square = np.array([[0.5, 0.5], [0, 0], [1, 0], [0, 1], [1, 1]]) * edge
    return (square @ linear.T + offset)[None]


def test_a_rotated_compressed_square_gives_its_compression_and_size():
    angle, across = np.radians(25.0), np.radians(60.0)
    rotate = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    direction = np.array([[np.cos(across), -np.sin(across)], [np.sin(across), np.cos(across)]])
    linear = rotate @ direction @ np.diag([0.4, 1.0]) @ direction.T
    ratio, size = marker_shape(_points(linear, 20.0))
    assert ratio[0] == pytest.approx(0.4) and size[0] == pytest.approx(20.0 * np.sqrt(0.4))
    ratio, size = marker_shape(_points(np.eye(2) * 1.5, 20.0))
    assert ratio[0] == pytest.approx(1.0) and size[0] == pytest.approx(30.0)


def test_markers_with_an_unknown_corner_are_left_out():
    points = np.concatenate([_points(np.eye(2), 20.0), _points(np.eye(2), 10.0)])
    points[1, 3] = np.nan  # a partial marker's corner off the fabric
    ratio, size = marker_shape(points)
    assert len(ratio) == 1 and size[0] == pytest.approx(20.0)


def test_tally_counts_each_group_and_size_bin():
    whole, partial = GROUPS
    records = [(Path("a.png"), whole, np.array([True, True, False]), np.array([10.0, 20.0, 40.0])),
               (Path("b.png"), whole, np.array([True]), np.array([40.0])),
               (Path("b.png"), partial, np.array([False, True]), np.array([14.0, 14.0]))]
    groups, by_size = tally(records)
    assert groups[whole] == {"markers": 4, "top1": 0.75} and groups[partial] == {"markers": 2, "top1": 0.5}
    assert by_size[whole][size_bin(32.0, np.inf)] == {"markers": 2, "top1": 0.5}
    assert by_size[whole][size_bin(0.0, 12.0)] == {"markers": 1, "top1": 1.0}
    assert list(by_size[partial]) == [size_bin(12.0, 16.0)]
    only_b = tally([r for r in records if r[0] == Path("b.png")])[0]  # any subset of the records, e.g. a motion's
    assert only_b[whole] == {"markers": 1, "top1": 1.0} and only_b[partial]["markers"] == 2
    assert tally([])[0][whole] == {"markers": 0, "top1": 0.0}


def test_whole_markers_are_tallied_by_how_far_they_are_off_a_homography_and_how_much_shows():
    whole, partial = GROUPS
    records = [(Path("a.png"), whole, np.array([True, False, True]), np.array([10.0, 12.0, 20.0]),
                np.array([0.5, 5.0, 1.5]), np.array([1.0, 0.9, 0.96])),
               (Path("b.png"), whole, np.array([False]), np.array([9.0]), np.array([4.5]), np.array([0.5])),
               (Path("b.png"), partial, np.array([False]), np.array([14.0]), np.array([0.2]), np.array([1.0]))]
    rows = by_residual(records)
    assert rows == {"residual 0-1 cells": {"markers": 1, "top1": 1.0},
                    "residual 1-2 cells": {"markers": 1, "top1": 1.0},
                    "residual >= 4 cells": {"markers": 2, "top1": 0.0}}  # partial markers are not in it
    assert tally(records)[0][whole] == {"markers": 4, "top1": 0.5}  # the residual leaves the tally as it was
    assert by_residual([]) == {}
    # and by the share of their crosspoints visible: every one apart, the bins holding all of them
    assert by_visible(records) == {"0%-80% of its crosspoints visible": {"markers": 1, "top1": 0.0},
                                   "80%-95% of its crosspoints visible": {"markers": 1, "top1": 0.0},
                                   "95%-100% of its crosspoints visible (not all)": {"markers": 1, "top1": 1.0},
                                   "every crosspoint visible": {"markers": 1, "top1": 1.0}}
    assert by_visible([]) == {}
