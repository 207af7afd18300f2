"""Pre-synthesized shards: written by a process pool, read back as exactly the synthesizer's samples."""

import json
import pickle

import numpy as np
import pytest
import torch

from assets.pattern import CropGeometry, PatternSpec
from assets.pattern.observation import localizer_targets
from networks.data import ShardDataset, read_shard_meta, synth_crops
from networks.shards import main, write_shards
from networks.synth import SYNTH_REMOVED_FIELDS, PatternSynthesizer, SynthConfig

SPEC = PatternSpec(rows=2, cols=2, num_ids=128)
CONFIG = SynthConfig(image_size=(64, 64), marker_px=(20, 28), seed=3)


def test_localizer_shards_hold_the_synthesizer_samples_and_grow(tmp_path):
    out = tmp_path / "loc"
    result = write_shards(out, "localizer", SPEC, count=5, config=CONFIG, workers=1, images_per_part=2,
                          progress=False)
    assert (result["parts"], result["items"], result["written_parts"], result["complete"]) == (3, 6, 3, True)
    data = ShardDataset(out, "localizer", spec=SPEC)
    synth = PatternSynthesizer(SPEC, CONFIG)
    assert len(data) == 6
    for index in (0, 3, 5):
        image, gt = synth.sample(index)
        item = data[index]
        assert item["image"].dtype == torch.uint8 and item["cells"].shape == (8, 8, 11)
        assert np.array_equal(item["image"].permute(1, 2, 0).numpy(), image)
        assert np.array_equal(item["cells"].numpy(), localizer_targets(gt), equal_nan=True)
    again = pickle.loads(pickle.dumps(data))  # as a spawned DataLoader worker gets it: maps reopened there
    assert torch.equal(again[4]["image"], data[4]["image"])
    (out / "part_00009.tmp").mkdir()  # an interrupted part is not read
    grown = write_shards(out, "localizer", SPEC, count=8, config=CONFIG, workers=1, images_per_part=2, progress=False)
    assert (grown["parts"], grown["written_parts"]) == (4, 1)
    assert len(ShardDataset(out, "localizer")) == 8
    with pytest.raises(ValueError, match="other settings.*synth"):
        write_shards(out, "localizer", SPEC, count=8, config=CONFIG.replace(seed=4), images_per_part=2,
                     progress=False)
    with pytest.raises(ValueError, match="recognizer"):
        ShardDataset(out, "recognizer")
    with pytest.raises(ValueError, match="codebook"):
        ShardDataset(out, "localizer", spec=PatternSpec(rows=2, cols=2, num_ids=128, seed=1))


def test_crop_shards_keep_a_subset_of_each_image_with_the_given_ids(tmp_path):
    ids = np.arange(40, 80)
    config = CONFIG.replace(image_size=(128, 128), foreshortening=1.0)
    write_shards(tmp_path / "rec", "recognizer", SPEC, count=2, config=config, marker_ids=ids, workers=1,
                 images_per_part=2, crops_per_image=3, progress=False)
    data = ShardDataset(tmp_path / "rec", "recognizer", spec=SPEC)
    assert 0 < len(data) <= 6 and np.array_equal(data.marker_ids, ids)
    first = synth_crops("recognizer", *PatternSynthesizer(SPEC, config, marker_ids=ids).sample(0), SPEC)
    crop = data[0]["crop"].permute(1, 2, 0).numpy()
    match = [k for k in range(len(first[0])) if np.array_equal(first[0][k], crop)]
    assert match and first[1][match[0]] == data[0]["marker_id"]
    assert all(40 <= int(data[i]["marker_id"]) < 80 for i in range(len(data)))
    write_shards(tmp_path / "xp", "crosspoints", SPEC, count=1, config=config, workers=1, images_per_part=1,
                 progress=False)
    item = ShardDataset(tmp_path / "xp", "crosspoints")[0]
    assert item["crop"].shape == item["reference"].shape == (3, 112, 112)
    assert item["xy"].shape == (25, 25, 2) and item["visible"].dtype == torch.bool


def test_cli_writes_a_shard_folder(tmp_path, capsys):
    pattern = tmp_path / "pattern.json"
    SPEC.save(pattern)
    out = tmp_path / "shards"
    assert main(["write", "--out", str(out), "--task", "localizer", "--count", "2", "--pattern", str(pattern),
                 "--image-size", "64", "--images-per-part", "2", "--no-progress"]) == 0
    assert "1 parts, 2 localizer items (complete)" in capsys.readouterr().out
    assert ShardDataset(out, "localizer")[1]["image"].shape == (3, 64, 64)
    assert main(["write", "--out", str(out), "--task", "localizer", "--count", "2", "--pattern", str(pattern),
                 "--image-size", "32", "--images-per-part", "2", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "shards.json: " in err and "other settings" in err and "synth.image_size: [64, 64] -> [32, 32]" in err


def test_cli_writes_jittered_crops(tmp_path, capsys):
    """--crop-jitter: the shard folder records it, and its crops are those synth_crops cuts with it."""
    pattern = tmp_path / "pattern.json"
    SPEC.save(pattern)
    out = tmp_path / "jittered"
    assert main(["write", "--out", str(out), "--task", "recognizer", "--count", "2", "--pattern", str(pattern),
                 "--image-size", "128", "--images-per-part", "2", "--crop-jitter", "1.5", "--no-progress"]) == 0
    meta = read_shard_meta(out)
    assert meta["synth"]["crop_jitter_px"] == 1.5
    assert CropGeometry.from_dict(meta["crop_geometry"]) == CropGeometry(jitter_px=1.5)
    # a folder written before the record reads as its synth config cut it; one contradicting it is refused
    raw = json.loads((out / "shards.json").read_text())
    (out / "shards.json").write_text(json.dumps({k: v for k, v in raw.items() if k != "crop_geometry"}))
    assert read_shard_meta(out)["crop_geometry"] == raw["crop_geometry"]
    (out / "shards.json").write_text(json.dumps({**raw, "crop_geometry": CropGeometry().to_dict()}))
    with pytest.raises(ValueError, match="crop_geometry.jitter_px is 0.0, synth.crop_jitter_px 1.5"):
        read_shard_meta(out)
    (out / "shards.json").write_text(json.dumps(raw))
    config = SynthConfig.from_dict(meta["synth"])
    image, gt = PatternSynthesizer(SPEC, config).sample(0)
    jittered, _ = synth_crops("recognizer", image, gt, SPEC, config, 0)
    exact, _ = synth_crops("recognizer", image, gt, SPEC)
    stored = ShardDataset(out, "recognizer")
    got = np.stack([stored[i]["crop"].permute(1, 2, 0).numpy() for i in range(min(len(jittered), 32))])

    def among(a, b):
        return (a.reshape(len(a), 1, -1) == b.reshape(1, len(b), -1)).all(axis=-1).any(axis=1)

    assert len(got) > 0 and among(got, jittered).all() and not among(got, exact).any()


def test_time_limit_stops_submitting_parts_that_would_end_after_it(tmp_path):
    # an empty folder gets one part whatever the limit, and no more (two workers idle beside it)
    out = tmp_path / "loc"
    first = write_shards(out, "localizer", SPEC, count=8, config=CONFIG, workers=2, images_per_part=2,
                         time_limit_s=0.0, progress=False)
    assert (first["written_parts"], first["complete"]) == (1, False)
    assert 0 < first["worker_seconds_per_image"] < first["seconds"] / 2  # per image, the worker's start excluded
    # the first part comes after the workers' start and its own two images; one of two workers worked
    assert 2 * first["worker_seconds_per_image"] < first["first_part_s"] <= first["seconds"]
    assert 0 < first["busy"] <= 0.5
    # a folder with parts gets none when the limit is spent, and all of them without a limit
    none = write_shards(out, "localizer", SPEC, count=8, config=CONFIG, workers=2, images_per_part=2,
                        time_limit_s=0.0, progress=False)
    assert (none["written_parts"], none["worker_seconds_per_image"], none["first_part_s"], none["busy"]) == (0, None,
                                                                                                   None, 0.0)
    rest = write_shards(out, "localizer", SPEC, count=8, config=CONFIG, workers=2, images_per_part=2, progress=False)
    assert (rest["written_parts"], rest["complete"]) == (3, True)


#: per removed SynthConfig field: a value other than the product's
SYNTH_REMOVED_OTHER_VALUES = {"crosspoint_margin_cells": 4, "crosspoint_bend": True, "recognizer_bend": True}


@pytest.mark.parametrize("name", sorted(SYNTH_REMOVED_FIELDS))
def test_shards_written_with_a_removed_option_are_read_only_at_the_value_the_product_uses(tmp_path, name):
    out = tmp_path / "shards"
    write_shards(out, "crosspoints", SPEC, count=1, config=CONFIG.replace(image_size=(128, 128), centred=True),
                 workers=1, images_per_part=1, progress=False)
    meta_path = out / "shards.json"
    meta = json.loads(meta_path.read_text())
    meta_path.write_text(json.dumps({**meta, "synth": {**meta["synth"], name: SYNTH_REMOVED_FIELDS[name]}}))
    assert len(ShardDataset(out, "crosspoints")) > 0
    meta_path.write_text(json.dumps({**meta, "synth": {**meta["synth"], name: SYNTH_REMOVED_OTHER_VALUES[name]}}))
    with pytest.raises(ValueError, match=f"shards.json:synth: {name} is"):
        ShardDataset(out, "crosspoints")


def test_crosspoint_shards_cut_only_the_crops_they_keep_and_those_are_the_synthesizer_s(tmp_path):
    """Crosspoint shards keep a seeded subset of an image's crops, cut alone: the same rows as all of
    `synth_crops`' crops with that subset taken."""
    config = CONFIG.replace(image_size=(160, 160), marker_px=(16, 24), crop_jitter_px=1.0)
    image, gt = PatternSynthesizer(SPEC, config).sample(0)
    every = synth_crops("crosspoints", image, gt, SPEC, config, 0)
    assert len(every[0]) > 3
    keep = np.array([0, 2, len(every[0]) - 1])
    kept = synth_crops("crosspoints", image, gt, SPEC, config, 0, lambda count: keep)
    assert all(np.array_equal(a[keep], b, equal_nan=True) for a, b in zip(every, kept))
    write_shards(tmp_path / "xp", "crosspoints", SPEC, count=1, config=config, workers=1, images_per_part=1,
                 crops_per_image=3, progress=False)
    data = ShardDataset(tmp_path / "xp", "crosspoints", spec=SPEC)
    assert len(data) == 3
    for k in range(3):  # each stored crop is one of the image's, with its targets
        crop = data[k]["crop"].permute(1, 2, 0).numpy()
        match = [j for j in range(len(every[0])) if np.array_equal(every[0][j], crop)]
        assert match and np.array_equal(every[2][match[0]], data[k]["xy"].numpy(), equal_nan=True)
