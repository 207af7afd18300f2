"""Hostile and careless input to the networks: checkpoints and shard folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from assets.pattern import PatternSpec
from networks.checkpoint import load_checkpoint, save_checkpoint, slim_checkpoint
from networks.config import TrainConfig
from networks.data import ShardDataset
from networks.tasks import build_model

SPEC = PatternSpec(rows=2, cols=2, num_ids=16)


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """A localizer checkpoint as float32 and as compact int8, each as the dict torch.load returns."""
    folder = tmp_path_factory.mktemp("ckpt")
    torch.manual_seed(0)
    model = build_model("localizer", SPEC.num_ids, SPEC.crosspoints_per_side)
    save_checkpoint(folder / "float.pt", "localizer", model, TrainConfig("localizer", steps=1, batch_size=2), SPEC)
    slim_checkpoint(folder / "float.pt", folder / "int8.pt", torch.int8)
    return {kind: torch.load(folder / f"{kind}.pt", weights_only=True) for kind in ("float", "int8")}


def _first_float(state: dict) -> str:
    return next(key for key, value in state.items() if value.is_floating_point() and value.dim() >= 2)


def _nan(data):
    key = _first_float(data["model"])
    data["model"] = {**data["model"], key: data["model"][key].clone().fill_(float("nan"))}


def _drop_scale(data):
    data["int8_scales"] = dict(list(data["int8_scales"].items())[1:])


#: (kind, source checkpoint, change, words of the error)
CASES = {
    "nan weight": ("silent", "float", _nan, "holds non-finite values"),
    "int8 without scales": ("silent", "int8", lambda d: d.update(int8_scales={}), "is int8 without its scale"),
    "int8 scales left out": ("silent", "int8", lambda d: d.pop("int8_scales"), "is int8 without its scale"),
    "one int8 scale missing": ("silent", "int8", _drop_scale, "is int8 without its scale"),
    "nan int8 scales": ("silent", "int8",
                        lambda d: d.update(int8_scales={k: v * float("nan") for k, v in d["int8_scales"].items()}),
                        "int8_scales"),
    "int8 scales a string": ("traceback", "int8", lambda d: d.update(int8_scales="abc"), "int8_scales must map"),
    "pattern a string": ("traceback", "float", lambda d: d.update(pattern="abc"), "pattern must be"),
    "pattern spec a string": ("traceback", "float", lambda d: d.update(pattern={"spec": "x", "codebook_hash": "y"}),
                              "pattern must be"),
    "num_ids a string": ("traceback", "float", lambda d: d.update(num_ids="x"), "num_ids must be an integer"),
    "num_ids negative": ("silent", "float", lambda d: d.update(num_ids=-1), "num_ids must be an integer"),
    "step a string": ("silent", "float", lambda d: d.update(step="x"), "step must be an integer"),
    "model a list": ("traceback", "float", lambda d: d.update(model=[1, 2]), "model must map names to tensors"),
    "integer weights": ("silent", "float",
                        lambda d: d.update(model={**d["model"], _first_float(d["model"]):
                                                  d["model"][_first_float(d["model"])].to(torch.int32)}),
                        "the network expects floating point"),
}


@pytest.mark.parametrize("case", [pytest.param(name, marks=pytest.mark.hostile(kind))
                                  for name, (kind, *_) in CASES.items()])
def test_bad_checkpoints_are_refused_naming_the_file_and_key(checkpoints, tmp_path, case):
    _, source, change, words = CASES[case]
    data = dict(checkpoints[source])
    change(data)
    path = tmp_path / "bad.pt"
    torch.save(data, path)
    with pytest.raises(ValueError, match=f"bad.pt: .*{words}"):
        load_checkpoint(path, "localizer", spec=None if case.startswith("num_ids") else SPEC)


@pytest.mark.hostile("memory")
def test_a_checkpoint_claiming_a_billion_ids_allocates_nothing(checkpoints, tmp_path):
    data = {**checkpoints["float"], "task": "recognizer", "num_ids": 10**9,
            "config": {**checkpoints["float"]["config"], "task": "recognizer"}}
    torch.save(data, tmp_path / "huge.pt")
    with pytest.raises(ValueError, match="huge.pt: the weights do not fit the recognizer network"):
        load_checkpoint(tmp_path / "huge.pt")  # building it would take 8 TB


def _shards(root: Path) -> Path:
    """A localizer shard folder of one part of two items."""
    from networks.shards import write_shards
    from networks.synth import SynthConfig

    write_shards(root, "localizer", PatternSpec(rows=2, cols=2, num_ids=128), count=2, workers=1, images_per_part=2,
                 config=SynthConfig(image_size=(64, 64), marker_px=(20, 28), seed=3), progress=False)
    return root


@pytest.fixture(scope="module")
def shard_folder(tmp_path_factory):
    return _shards(tmp_path_factory.mktemp("shards") / "loc")


@pytest.mark.parametrize("case, words", [("zero-byte", "cells.npy: not a readable .npy array"),
                                         ("missing", "cells.npy: missing"),
                                         ("short", "cells.npy: 1 items, the part's image.npy has 2")])
@pytest.mark.hostile("traceback")
def test_a_damaged_shard_part_is_refused_when_the_folder_is_opened(shard_folder, tmp_path, case, words):
    import shutil

    root = tmp_path / "loc"
    shutil.copytree(shard_folder, root)
    cells = next(root.glob("part_*")) / "cells.npy"
    if case == "zero-byte":
        cells.write_bytes(b"")
    elif case == "missing":
        cells.unlink()
    else:
        np.save(cells, np.load(cells)[:1])
    with pytest.raises(ValueError, match=words):
        ShardDataset(root, "localizer")


@pytest.mark.hostile("outside")
@pytest.mark.parametrize("file", ["../../escaped.pt", "/tmp/escaped.pt", ".git"])
def test_a_weights_manifest_naming_a_file_outside_the_fetch_folder_is_refused(tmp_path, file):
    import json

    from networks.weights import FORMAT, MANIFEST, VERSION, read_manifest

    (tmp_path / MANIFEST).parent.mkdir(parents=True)
    entry = {"file": file, "commit": "0" * 40, "sha256": "0" * 64, "bytes": 1}
    (tmp_path / MANIFEST).write_text(json.dumps({"format": FORMAT, "version": VERSION,
                                                 "weights": {"localizer": entry}}))
    with pytest.raises(ValueError, match=r"weights.json: weights\['localizer'\].file: name .* cannot be a file name"):
        read_manifest(tmp_path)
