"""The marker-shape measure of `benchmarks/foreshortening.py`: how oblique and how large a marker is."""


import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("foreshortening")


def _points(linear: np.ndarray, edge: float, offset=(100.0, 50.0)) -> np.ndarray:
    """Five points (centre, TL, TR, BL, BR) of a marker of `edge` px seen through `linear` (2 x 2)."""
    square = np.array([[0.5, 0.5], [0, 0], [1, 0], [0, 1], [1, 1]]) * edge
    return (square @ linear.T + offset)[None]


def test_a_rotated_compressed_square_gives_its_compression_and_size(bench):
    angle, across = np.radians(25.0), np.radians(60.0)
    rotate = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    direction = np.array([[np.cos(across), -np.sin(across)], [np.sin(across), np.cos(across)]])
    linear = rotate @ direction @ np.diag([0.4, 1.0]) @ direction.T
    ratio, size = bench.marker_shape(_points(linear, 20.0))
    assert ratio[0] == pytest.approx(0.4) and size[0] == pytest.approx(20.0 * np.sqrt(0.4))
    ratio, size = bench.marker_shape(_points(np.eye(2) * 1.5, 20.0))
    assert ratio[0] == pytest.approx(1.0) and size[0] == pytest.approx(30.0)


def test_markers_with_an_unknown_corner_are_left_out(bench):
    points = np.concatenate([_points(np.eye(2), 20.0), _points(np.eye(2), 10.0)])
    points[1, 3] = np.nan  # a partial marker's corner off the fabric
    ratio, size = bench.marker_shape(points)
    assert len(ratio) == 1 and size[0] == pytest.approx(20.0)
    summary = bench.summary(np.array([0.3, 0.5, 0.9, 1.0]), np.array([10.0, 12.0, 14.0, 16.0]))
    assert summary["markers"] == 4 and summary["oblique_share"] == pytest.approx(0.5)


@pytest.mark.parametrize("degrees", [0.0, 30.0, -60.0, 120.0, 180.0])
def test_a_marker_s_in_plane_rotation_is_measured_through_compression(bench, degrees):
    angle, across = np.radians(degrees), np.radians(40.0)
    rotate = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    direction = np.array([[np.cos(across), -np.sin(across)], [np.sin(across), np.cos(across)]])
    compressed = direction @ np.diag([0.5, 1.0]) @ direction.T  # symmetric: no rotation of its own
    measured = bench.marker_rotation(_points(rotate @ compressed, 20.0))
    assert abs((measured[0] - degrees + 180) % 360 - 180) < 1e-6
    summary = bench.summary(np.ones(4), np.full(4, 20.0), np.array([0.0, 10.0, -50.0, 170.0]))
    assert summary["rotated_share"] == pytest.approx(0.5)
