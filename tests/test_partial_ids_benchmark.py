"""`benchmarks/partial_ids.py`: the recognizer's top-1 tallied by group, marker size and (with
--by-motion) any subset of the same per-image records."""

from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("partial_ids")


def test_tally_counts_each_group_and_size_bin(bench):
    whole, partial = bench.GROUPS
    records = [(Path("a.png"), whole, np.array([True, True, False]), np.array([10.0, 20.0, 40.0])),
               (Path("b.png"), whole, np.array([True]), np.array([40.0])),
               (Path("b.png"), partial, np.array([False, True]), np.array([14.0, 14.0]))]
    groups, by_size = bench.tally(records)
    assert groups[whole] == {"markers": 4, "top1": 0.75} and groups[partial] == {"markers": 2, "top1": 0.5}
    assert by_size[whole][bench.size_bin(32.0, np.inf)] == {"markers": 2, "top1": 0.5}
    assert by_size[whole][bench.size_bin(0.0, 12.0)] == {"markers": 1, "top1": 1.0}
    assert list(by_size[partial]) == [bench.size_bin(12.0, 16.0)]
    only_b = bench.tally([r for r in records if r[0] == Path("b.png")])[0]  # as --by-motion takes a motion's
    assert only_b[whole] == {"markers": 1, "top1": 1.0} and only_b[partial]["markers"] == 2
    assert bench.tally([])[0][whole] == {"markers": 0, "top1": 0.0}


def test_whole_markers_are_tallied_by_how_far_they_are_off_a_homography_and_how_much_shows(bench):
    whole, partial = bench.GROUPS
    records = [(Path("a.png"), whole, np.array([True, False, True]), np.array([10.0, 12.0, 20.0]),
                np.array([0.5, 5.0, 1.5]), np.array([1.0, 0.9, 0.96])),
               (Path("b.png"), whole, np.array([False]), np.array([9.0]), np.array([4.5]), np.array([0.5])),
               (Path("b.png"), partial, np.array([False]), np.array([14.0]), np.array([0.2]), np.array([1.0]))]
    rows = bench.by_residual(records)
    assert rows == {"residual 0-1 cells": {"markers": 1, "top1": 1.0},
                    "residual 1-2 cells": {"markers": 1, "top1": 1.0},
                    "residual >= 4 cells": {"markers": 2, "top1": 0.0}}  # partial markers are not in it
    assert bench.tally(records)[0][whole] == {"markers": 4, "top1": 0.5}  # the residual leaves the tally as it was
    assert bench.by_residual([]) == {}
    # and by the share of their crosspoints visible: every one apart, the bins holding all of them
    assert bench.by_visible(records) == {"0%-80% of its crosspoints visible": {"markers": 1, "top1": 0.0},
                                         "80%-95% of its crosspoints visible": {"markers": 1, "top1": 0.0},
                                         "95%-100% of its crosspoints visible (not all)": {"markers": 1, "top1": 1.0},
                                         "every crosspoint visible": {"markers": 1, "top1": 1.0}}
    assert bench.by_visible([]) == {}
