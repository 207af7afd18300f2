"""`benchmarks/crosspoint_scale.py`: the crosspoint network's errors by marker size, from crops cut from
the true points of held-out images."""

import json

import numpy as np
import pytest
import torch

from networks.checkpoint import save_checkpoint
from networks.config import TrainConfig
from networks.evaluate import evaluate
from networks.tasks import build_model
from tests.networks.test_evaluate import SPEC, write_factory_dataset


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("crosspoint_scale")


def test_all_sizes_match_the_evaluation_of_the_same_crops_and_the_bins_split_them(bench, tmp_path, capsys):
    """Its crops are the ones the factory's samples hold (both from `crosspoint_crops` of the image and
    its ground truth), so on the held-out split its metrics over all sizes are `networks.evaluate`'s."""
    data = write_factory_dataset(tmp_path / "ds", SPEC, {"train": 1, "test": 2})
    torch.manual_seed(0)
    model = build_model("crosspoints", SPEC.num_ids, SPEC.crosspoints_per_side)
    path = save_checkpoint(tmp_path / "xp.pt", "crosspoints", model, TrainConfig("crosspoints"), SPEC, step=1)
    assert bench.main(["--checkpoint", str(path), "--rendered", str(data), "--device", "cpu", "--batch-size", "8"]) == 0
    out = capsys.readouterr().out
    result = json.loads(out.split("RESULT ", 1)[1])
    (rows,) = result.values()
    expected = evaluate(path, data, "test", device="cpu", batch_size=8, progress=False)
    every = rows.pop("all sizes")
    assert every["crops"] == expected["crops"] > 0
    for key in ("crop_error_px", "image_error_px"):
        assert every[key]["median"] == pytest.approx(expected[key]["median"], rel=1e-4)
        assert every[key]["count"] == expected[key]["count"]
    assert every["visibility"] == expected["visibility"]
    full = every["fully_visible"]  # the crops whose every crosspoint is visible, as evaluate counts them
    assert full["crops"] == expected["fully_visible"]["crops"]
    assert full["crop_error_px"]["median"] == pytest.approx(expected["fully_visible"]["crop_error_px"]["median"],
                                                            rel=1e-4)
    assert f"| {full['crops']}, " in out
    assert rows and sum(r["crops"] for r in rows.values()) == every["crops"]
    assert sum(r["crop_error_px"]["count"] for r in rows.values()) == every["crop_error_px"]["count"]
    assert all(label.startswith("size ") for label in rows) and "| all sizes |" in out
    assert np.isfinite(every["size_median"]) and every["size_median"] > 20  # the synthesizer's 56-72 px markers
