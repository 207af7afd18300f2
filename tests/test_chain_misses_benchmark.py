"""`benchmarks/chain_misses.py`: the reason a fully visible marker is missing from the Detector's output,
from where the localizer's cells and the detections lie around its true centre."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("chain_misses")


def _points(*centres):
    """(L, 5, 2): markers of side 10 px around the centres."""
    offsets = np.array([[0, 0], [-5, -5], [5, -5], [-5, 5], [5, 5]], np.float64)
    return np.array([offsets + c for c in centres], np.float64).reshape(-1, 5, 2)


def test_each_reason_from_the_cells_and_detections_around_the_centre(bench):
    below, lost, unusable, moved, taken = bench.REASONS
    centre = np.array([50.0, 50.0])
    none = np.zeros((0, 2))
    located = _points([51.0, 50.0], [200.0, 200.0])
    low_centres, low_scores = np.array([[200.0, 200.0], [52.0, 51.0]]), np.array([0.9, 0.2])
    # a cell at the lower threshold within the radius, none at the threshold: below it, with its probability
    assert bench.reason(centre, _points([200.0, 200.0]), np.ones(1, bool), low_centres, low_scores, none, 4.0) == \
        (below, pytest.approx(0.2))
    # nothing within the radius at either threshold (the 52, 51 cell is 2.2 px away: outside 2 px)
    assert bench.reason(centre, np.zeros((0, 5, 2)), np.zeros(0, bool), low_centres, low_scores, none, 2.0) == \
        (lost, None)
    # found at the threshold but not usable
    assert bench.reason(centre, located, np.array([False, True]), low_centres, low_scores, none, 4.0)[0] == unusable
    # found and usable, no detection left near it: the completion moved its points
    assert bench.reason(centre, located, np.ones(2, bool), low_centres, low_scores,
                        np.array([[200.0, 200.0], [60.0, 50.0]]), 4.0)[0] == moved
    # a detection within the radius that the match gave to another marker
    assert bench.reason(centre, located, np.ones(2, bool), low_centres, low_scores,
                        np.array([[51.0, 50.0]]), 4.0)[0] == taken
