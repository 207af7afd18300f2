"""`benchmarks/crosspoint_rings.py`: the crosspoint error by ring of the grid (0: the crop's edge)."""

import numpy as np
import pytest
import torch

from assets.pattern import PatternSpec
from networks.checkpoint import save_checkpoint
from networks.config import TrainConfig
from networks.shards import write_shards
from networks.synth import SynthConfig
from networks.tasks import build_model


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("crosspoint_rings")


def test_rings_count_grid_steps_to_the_nearest_edge(bench):
    ring = bench.rings(5)
    assert ring.tolist() == [[0, 0, 0, 0, 0], [0, 1, 1, 1, 0], [0, 1, 2, 1, 0], [0, 1, 1, 1, 0], [0, 0, 0, 0, 0]]
    assert bench.rings(25).max() == 12 and (bench.rings(25) == 0).sum() == 96


def test_by_ring_takes_the_visible_crosspoints_of_each_ring(bench):
    errors = np.zeros((2, 5, 5))
    errors[:, bench.rings(5) == 0] = 1.0
    errors[:, 2, 2] = 3.0
    visible = np.ones((2, 5, 5), bool)
    visible[1] = False  # the second crop's crosspoints are hidden: never counted
    errors[1] = 99.0
    rows = bench.by_ring(errors, visible)
    assert [r["crosspoints"] for r in rows] == [16, 8, 1]
    assert [r["median"] for r in rows] == [1.0, 0.0, 3.0]


def test_by_ring_and_displacement_bins_each_visible_crosspoint_once(bench):
    errors = np.zeros((1, 25, 25))
    errors[0][bench.rings(25) == 0] = 2.0
    displacement = np.full((1, 25, 25), 0.7)
    displacement[0, 12, 12] = 9.0  # the centre: the last bin
    visible = np.ones((1, 25, 25), bool)
    visible[0, 0, 0] = False
    grid = bench.by_ring_and_displacement(errors, visible, displacement)
    assert [row["rings"] for row in grid] == [list(g) for g in bench.RING_GROUPS]
    counts = [[b["crosspoints"] for b in row["bins"]] for row in grid]
    assert sum(map(sum, counts)) == 624 and counts[0] == [0, 95, 0, 0, 0] and counts[3][-1] == 1
    assert grid[0]["bins"][1]["median"] == 2.0 and grid[1]["bins"][1]["median"] == 0.0
    assert grid[0]["bins"][0]["median"] is None


def test_an_untrained_network_on_a_shard_folder(bench, tmp_path, capsys):
    spec = PatternSpec(rows=2, cols=2, num_ids=64)
    write_shards(tmp_path / "xp", "crosspoints", spec, count=1, config=SynthConfig(image_size=(96, 96),
                 marker_px=(40.0, 48.0), seed=2), workers=1, images_per_part=1, progress=False)
    torch.manual_seed(0)
    path = save_checkpoint(tmp_path / "xp.pt", "crosspoints", build_model("crosspoints", spec.num_ids),
                           TrainConfig("crosspoints"), spec)
    errors, visible, displacement = bench.crop_errors(path, tmp_path / "xp", device="cpu")
    assert errors.shape[1:] == visible.shape[1:] == displacement.shape[1:] == (25, 25) and visible.any()
    # an untrained network answers near the canonical positions: its error is about the displacement
    assert np.median(np.abs(errors - displacement)[visible]) < 0.5
    assert bench.main(["--checkpoint", str(path), "--data", str(tmp_path / "xp"), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "| 12 |" in printed and "| 6-12 |" in printed
