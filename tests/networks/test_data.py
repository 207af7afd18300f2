"""Training datasets: a factory dataset folder (written here in the factory's layout from synthetic
images), the synthesizer, and their mixture."""

import json
import pickle
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from assets.fileio import save_json, save_npz
from assets.pattern import CROSSPOINT_CROP, PatternSpec, generate_codebook, reference_textures
from assets.geometry import apply_homography
from assets.pattern.observation import (ImageGroundTruth, crosspoint_crops, localizer_targets, recognizer_crops,
                                        recognizer_markers)
from networks.augment import Augment, ViewWarp, warp_image
from networks.data import (_VIEW, MixedDataset, RenderedDataset, SynthDataset, dataset_spec, garment_marker_ids,
                           synth_crops)
from networks.synth import PatternSynthesizer, SynthConfig

SPEC = PatternSpec(rows=8, cols=8, num_ids=512)
#: (motion, frame) -> split, three variations each, as `factory.build.build` names and splits them
FRAMES = {("walk", 2): "train", ("walk", 4): "train", ("walk", 5): "val", ("walk", 7): "test"}
VARIATIONS = 2


@pytest.fixture(scope="module")
def codebook():
    return generate_codebook(SPEC)


@pytest.fixture(scope="module")
def folder(tmp_path_factory, codebook) -> Path:
    """A dataset folder in the layout `factory.build.build` writes, with synthetic images."""
    garments = pytest.importorskip("assets.garments")  # the real template file (needs triangle)
    from assets.garments.defaults import default_pattern

    out = tmp_path_factory.mktemp("dataset")
    garments.Template.build(default_pattern("skirt"), SPEC, dpi=20).save(out / "template.npz", levels=())
    save_json(out / "config.json", {"garment": "skirt", "motions": ["walk"], "variations": VARIATIONS, "seed": 0})
    save_json(out / "splits.json", {s: [f"{m}/{f}" for (m, f), name in FRAMES.items() if name == s]
                                    for s in ("train", "val", "test")})
    # square markers and few cut lines: every split of these small images shows whole markers
    synth = PatternSynthesizer(SPEC, SynthConfig(image_size=(192, 128), marker_px=(36, 56), foreshortening=1.0,
                                                 boundary_probability=0.3), codebook)
    (out / "images").mkdir()
    for k, ((motion, frame), split) in enumerate(sorted(FRAMES.items())):
        for v in range(VARIATIONS):
            name = f"{motion}_f{frame:06d}_v{v}"
            image, gt = synth.sample(k * VARIATIONS + v)
            cv2.imwrite(str(out / "images" / f"{name}.png"), image[:, :, ::-1])
            rec, rec_ids = recognizer_crops(image, gt, SPEC)
            xp, xp_ids, xp_xy, xp_vis = crosspoint_crops(image, gt, SPEC)
            gt.save(out / "gt" / f"{name}.npz")
            save_npz(out / "samples" / f"{name}.npz", {
                "cells": localizer_targets(gt), "recognizer_crops": rec, "recognizer_ids": rec_ids,
                "crosspoint_crops": xp, "crosspoint_ids": xp_ids, "crosspoint_xy": xp_xy,
                "crosspoint_visible": xp_vis})
            save_json(out / "meta" / f"{name}.json", {
                "name": name, "split": split, "motion": motion, "frame": frame, "variation": v,
                "image": f"images/{name}.png", "depth": f"images/{name}_depth.exr",
                "camera": f"images/{name}_camera.json", "gt": f"gt/{name}.npz", "samples": f"samples/{name}.npz",
                "markers_visible": int((gt.status > 0).sum()), "markers_full": int((gt.status == 2).sum())})
    lines = [json.dumps(json.loads(p.read_text()), sort_keys=True) for p in sorted((out / "meta").glob("*.json"))]
    (out / "manifest.jsonl").write_text("".join(line + "\n" for line in lines))
    return out


def _entries(folder: Path, split: str) -> list[dict]:
    entries = [json.loads(line) for line in (folder / "manifest.jsonl").read_text().splitlines()]
    return [e for e in entries if e["split"] == split]


def test_the_folder_spec_comes_from_the_template(folder):
    assert dataset_spec(folder) == SPEC


def test_localizer_items_are_the_images_and_their_cells(folder):
    for split, count in (("train", 4), ("val", 2), ("test", 2)):
        data = RenderedDataset(folder, split, "localizer")
        assert len(data) == count
        entries = _entries(folder, split)
        for i in range(len(data)):
            item = data[i]
            assert item["image"].dtype == torch.uint8 and item["image"].shape == (3, 128, 192)
            assert item["cells"].dtype == torch.float32 and item["cells"].shape == (16, 24, 11)
            png = cv2.imread(str(folder / entries[i]["image"]))[:, :, ::-1]
            assert np.array_equal(item["image"].permute(1, 2, 0).numpy(), png)
            cells = np.load(folder / entries[i]["samples"])["cells"]
            assert np.array_equal(item["cells"].numpy(), cells, equal_nan=True)


def test_garment_marker_ids_are_the_ids_printed_on_its_panels(folder):
    from assets.garments import Template

    ids = garment_marker_ids(folder)
    assert np.array_equal(ids, garment_marker_ids(folder / "template.npz"))
    tables = Template.load(folder / "template.npz").layout.tables()
    printed = np.concatenate([t.marker_ids for t in tables])
    assert np.array_equal(ids, np.unique(printed)) and len(ids) == len(printed)
    assert ids.dtype == np.int64 and ids.max() < SPEC.num_ids


def test_localizer_crops_are_cut_on_the_cell_grid(folder):
    whole = RenderedDataset(folder, "train", "localizer")
    cropped = RenderedDataset(folder, "train", "localizer", crop_px=70, seed=4)
    assert cropped.crop_size((192, 128)) == (64, 64) and cropped.crop_size((40, 128)) == (40, 64)
    offsets = set()
    for i in range(len(whole)):
        image, cells = whole[i]["image"].numpy(), whole[i]["cells"].numpy()
        item = cropped[i]
        assert item["image"].shape == (3, 64, 64) and item["cells"].shape == (8, 8, 11)
        # the crop's cells are the whole image's cells at the crop's place: the targets stay exact
        rows, cols = np.nonzero((image[:, ::8, ::8] == item["image"].numpy()[:, :1, :1]).all(axis=0)[:9, :17])
        found = [(r, c) for r, c in zip(rows, cols)
                 if np.array_equal(image[:, 8 * r:8 * r + 64, 8 * c:8 * c + 64], item["image"].numpy())]
        assert len(found) >= 1
        r, c = found[0]
        assert np.array_equal(cells[r:r + 8, c:c + 8], item["cells"].numpy(), equal_nan=True)
        assert torch.equal(item["image"], cropped[i]["image"])  # seeded per (seed, epoch, index)
        offsets.add((r, c))
    assert len(offsets) > 1
    with pytest.raises(ValueError, match="crop_px"):
        RenderedDataset(folder, "train", "localizer", crop_px=4)


def test_a_view_warp_moves_the_image_and_its_targets_together(folder):
    warp = ViewWarp(probability=1.0, scale=(0.8, 1.25), rotation_deg=20.0, squeeze=0.6)
    data = RenderedDataset(folder, "train", "localizer", crop_px=96, seed=5, view_warp=warp)
    plain = RenderedDataset(folder, "train", "localizer", crop_px=96, seed=5)
    never = RenderedDataset(folder, "train", "localizer", crop_px=96, seed=5, view_warp=replace(warp, probability=0.0))
    grid = np.stack(np.meshgrid(np.arange(12), np.arange(12)), axis=-1) * 8.0  # (row, col) -> cell corner (x, y)
    found = 0
    for i, entry in enumerate(_entries(folder, "train")):
        item = data[i]
        assert item["image"].shape == (3, 96, 96) and item["cells"].shape == (12, 12, 11)
        assert torch.equal(item["image"], data[i]["image"])  # seeded per (seed, epoch, index)
        assert torch.equal(never[i]["image"], plain[i]["image"])  # probability 0: the plain crop
        # the item's view, drawn as the dataset draws it
        view = warp.homography(np.random.default_rng([5, 0, i, _VIEW]), (192, 128), (96, 96))
        png = cv2.imread(str(folder / entry["image"]))[:, :, ::-1]
        assert np.array_equal(item["image"].permute(1, 2, 0).numpy(), warp_image(png, view, (96, 96)))
        gt = ImageGroundTruth.load(folder / entry["gt"])
        centres = apply_homography(view, gt.points_px[:, 0])
        inside = ((centres >= 0) & (centres < 96)).all(axis=1) & gt.point_visible[:, 0]
        cells = item["cells"].numpy()
        present = cells[..., 0] > 0
        # each present cell holds a visible marker's five points, moved by the view, and each
        # visible marker whose centre lands inside the item has its cell
        points = cells[present][:, 1:].reshape(-1, 5, 2) + grid[present][:, None, :]
        moved = apply_homography(view, gt.points_px[inside])
        assert present.sum() == inside.sum()
        for p in points:
            match = np.nanmax(np.abs(moved - p), axis=(1, 2)) < 1e-3
            assert match.sum() == 1
        found += int(present.sum())
    assert found > 4
    with pytest.raises(ValueError, match="view_warp"):
        RenderedDataset(folder, "train", "recognizer", view_warp=warp)


def test_crop_tasks_index_every_crop_of_the_split(folder, codebook):
    for split in ("train", "val"):
        arrays = [np.load(folder / e["samples"]) for e in _entries(folder, split)]
        recognizer = RenderedDataset(folder, split, "recognizer")
        crops = np.concatenate([a["recognizer_crops"] for a in arrays])
        ids = np.concatenate([a["recognizer_ids"] for a in arrays])
        assert len(recognizer) == len(ids) > 0
        for i in (0, len(ids) // 2, len(ids) - 1):
            item = recognizer[i]
            assert item["crop"].shape == (3, 96, 96) and item["crop"].dtype == torch.uint8
            assert item["marker_id"].dtype == torch.int64 and item["marker_id"].shape == ()
            assert np.array_equal(item["crop"].permute(1, 2, 0).numpy(), crops[i]) and item["marker_id"] == ids[i]
        crosspoints = RenderedDataset(folder, split, "crosspoints")
        xy = np.concatenate([a["crosspoint_xy"] for a in arrays])
        xp_ids = np.concatenate([a["crosspoint_ids"] for a in arrays])
        assert len(crosspoints) == len(xp_ids) > 0
        for i in (0, len(xp_ids) - 1):
            item = crosspoints[i]
            assert item["crop"].shape == item["reference"].shape == (3, 112, 112)
            assert item["xy"].dtype == torch.float32 and item["xy"].shape == (25, 25, 2)
            assert item["visible"].dtype == torch.bool and item["visible"].shape == (25, 25)
            assert np.array_equal(item["xy"].numpy(), xy[i], equal_nan=True)
            reference = reference_textures(SPEC, codebook[xp_ids[i]][None], CROSSPOINT_CROP)[0]
            assert np.array_equal(item["reference"].permute(1, 2, 0).numpy(), reference)


def test_jittered_recognizer_crops_are_cut_anew_from_moved_points(folder):
    exact = RenderedDataset(folder, "train", "recognizer")
    tiny = RenderedDataset(folder, "train", "recognizer", crop_jitter_px=1e-9)
    jittered = RenderedDataset(folder, "train", "recognizer", crop_jitter_px=1.5)
    assert len(exact) == len(tiny) == len(jittered) > 2
    moved = []
    for i in range(len(exact)):
        stored = exact[i]["crop"].numpy().astype(int)
        # cut again from the PNG at the true points: the stored crop (the same unwarp of the same image)
        assert np.array_equal(tiny[i]["crop"].numpy().astype(int), stored)
        item = jittered[i]
        assert item["marker_id"] == exact[i]["marker_id"]
        moved.append(np.abs(item["crop"].numpy().astype(int) - stored).mean())
        assert torch.equal(item["crop"], jittered[i]["crop"])  # reproducible per (seed, epoch, index)
    assert np.mean(moved) > 3
    jittered.set_epoch(1)
    assert not torch.equal(jittered[0]["crop"], RenderedDataset(folder, "train", "recognizer", crop_jitter_px=1.5)[0]["crop"])
    with pytest.raises(ValueError, match="only for the crop tasks"):
        RenderedDataset(folder, "train", "localizer", crop_jitter_px=1.0)



def test_partial_marker_items_add_the_partial_markers_crops_cut_from_the_image(folder):
    whole = RenderedDataset(folder, "train", "recognizer")
    partial = RenderedDataset(folder, "train", "recognizer", partial_markers=True)
    expected, stored = [], {}
    for e in _entries(folder, "train"):
        gt = ImageGroundTruth.load(folder / e["gt"])
        expected.extend(gt.marker_id[recognizer_markers(gt, SPEC, partial=True)])
        crops = np.load(folder / e["samples"])
        stored.update({(e["name"], int(m)): c for m, c in zip(crops["recognizer_ids"], crops["recognizer_crops"])})
    assert len(whole) < len(partial) == len(expected)  # the image borders cut some markers
    assert [int(partial[i]["marker_id"]) for i in range(len(partial))] == [int(m) for m in expected]
    # whole markers' crops are the stored ones (the same unwarp of the same points and PNG)
    names = [partial.entries[i]["name"] for i in partial._index[:, 0]]
    same = [np.array_equal(partial[i]["crop"].permute(1, 2, 0).numpy(), stored[(n, int(partial[i]["marker_id"]))])
            for i, n in enumerate(names) if (n, int(partial[i]["marker_id"])) in stored]
    assert len(same) == len(whole) and all(same)
    with pytest.raises(ValueError, match="partial_markers is for the recognizer"):
        RenderedDataset(folder, "train", "crosspoints", partial_markers=True)


def test_per_image_marker_work_is_done_once_when_the_dataset_is_made_and_stale_samples_are_refused_then(
        folder, tmp_path, monkeypatch):
    import networks.data as data

    made = {task: RenderedDataset(folder, "train", task, crop_jitter_px=1.0) for task in ("recognizer", "crosspoints")}
    made["partial"] = RenderedDataset(folder, "train", "recognizer", partial_markers=True)
    made["warp"] = RenderedDataset(folder, "train", "localizer", view_warp=ViewWarp(probability=1.0), crop_px=64)
    expected = {name: [d[i] for i in range(0, len(d), max(1, len(d) // 5))] for name, d in made.items()}

    def refused(*_, **__):
        raise AssertionError("per-image marker work in an item")

    for name in ("completed_points", "crosspoint_markers", "recognizer_markers"):
        monkeypatch.setattr(data, name, refused)  # the items (what a worker does) no longer need them
    for name, dataset in made.items():
        dataset._cache.clear()
        got = [dataset[i] for i in range(0, len(dataset), max(1, len(dataset) // 5))]
        for a, b in zip(got, expected[name]):
            assert all(np.array_equal(a[k].numpy(), b[k].numpy(), equal_nan=a[k].is_floating_point()) for k in a), name
    monkeypatch.undo()
    stale = shutil.copytree(folder, tmp_path / "stale")
    entry = _entries(stale, "train")[0]
    arrays = dict(np.load(stale / entry["samples"]))
    arrays["crosspoint_ids"] = arrays["crosspoint_ids"][1:]  # samples built before the markers changed
    np.savez(stale / entry["samples"], **arrays)
    with pytest.raises(ValueError, match="do not match the crosspoints crops"):
        RenderedDataset(stale, "train", "crosspoints", crop_jitter_px=1.0)  # at once, not in a worker


def test_synthesized_recognizer_crops_take_partial_markers_when_configured(codebook):
    config = SynthConfig(image_size=(128, 128), marker_px=(40, 56), boundary_probability=1.0)
    synth = PatternSynthesizer(SPEC, config, codebook)
    counts = np.zeros(2, int)
    for index in range(4):
        image, gt = synth.sample(index)
        for k, partial in enumerate((False, True)):
            crops, ids = synth_crops("recognizer", image, gt, SPEC, config.replace(recognizer_partial=partial), index)
            np.testing.assert_array_equal(ids, gt.marker_id[recognizer_markers(gt, SPEC, partial)])
            counts[k] += len(ids)
    assert 0 < counts[0] < counts[1]


def _at(crop: torch.Tensor, xy: np.ndarray) -> np.ndarray:
    """The crop's colours (float) at the crop pixel positions xy (M, 2), bilinear."""
    image = crop.permute(1, 2, 0).numpy().astype(np.float32)
    # pixel centres at +0.5: the crop's xy are continuous coordinates
    map_x = (xy[:, 0] - 0.5).astype(np.float32)[None]
    map_y = (xy[:, 1] - 0.5).astype(np.float32)[None]
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR)[0]


def test_jittered_crosspoint_crops_move_their_targets_with_the_crop(folder):
    exact = RenderedDataset(folder, "train", "crosspoints")
    tiny = RenderedDataset(folder, "train", "crosspoints", crop_jitter_px=1e-9)
    jittered = RenderedDataset(folder, "train", "crosspoints", crop_jitter_px=1.5)
    assert len(exact) == len(tiny) == len(jittered) > 2
    same, shuffled, shift = [], [], []
    for i in range(len(exact)):
        want, near, item = exact[i], tiny[i], jittered[i]
        # cut again at the true points: the stored crop and targets
        assert np.abs(near["crop"].numpy().astype(int) - want["crop"].numpy().astype(int)).max() <= 1
        assert np.allclose(near["xy"].numpy(), want["xy"].numpy(), atol=1e-3, equal_nan=True)
        assert torch.equal(near["visible"], want["visible"])
        assert torch.equal(item["reference"], want["reference"])  # the same marker
        assert torch.equal(item["crop"], jittered[i]["crop"])  # reproducible per (seed, epoch, index)
        both = (item["visible"] & want["visible"]).numpy()
        inner = both & (np.stack([item["xy"].numpy(), want["xy"].numpy()]) > 4).all(axis=(0, -1)) \
            & (np.stack([item["xy"].numpy(), want["xy"].numpy()]) < 108).all(axis=(0, -1))
        if inner.sum() < 20:
            continue
        moved, true = item["xy"].numpy()[inner], want["xy"].numpy()[inner]
        shift.append(np.linalg.norm(moved - true, axis=-1).mean())
        # the moved targets point at what the true targets point at in the exact crop
        same.append(np.abs(_at(item["crop"], moved) - _at(want["crop"], true)).mean())
        shuffled.append(np.abs(_at(item["crop"], true) - _at(want["crop"], true)).mean())
    assert len(same) > 2
    assert 0.3 < np.mean(shift) < 10  # 1.5 px of jitter moves the targets by a few crop pixels
    assert np.mean(same) < 0.5 * np.mean(shuffled)


def test_default_collate_batches_the_items(folder):
    for task, keys in (("localizer", {"image", "cells"}), ("recognizer", {"crop", "marker_id"}),
                       ("crosspoints", {"crop", "reference", "xy", "visible"})):
        loader = DataLoader(RenderedDataset(folder, "train", task), batch_size=3)
        batch = next(iter(loader))
        assert set(batch) == keys and all(len(v) == 3 for v in batch.values())
    assert batch["visible"].dtype == torch.bool and batch["reference"].shape == (3, 3, 112, 112)
    data = RenderedDataset(folder, "train", "recognizer", augment=Augment(), seed=2)
    parallel = DataLoader(data, batch_size=4, num_workers=2, timeout=60)
    serial = DataLoader(data, batch_size=4)
    for a, b in zip(parallel, serial):  # workers need no seeding: items depend on (seed, epoch, index) only
        assert torch.equal(a["crop"], b["crop"]) and torch.equal(a["marker_id"], b["marker_id"])


def test_augmentation_is_reproducible_per_index_and_epoch(folder):
    plain = RenderedDataset(folder, "train", "recognizer")
    data = RenderedDataset(folder, "train", "recognizer", augment=Augment(colour_probability=1), seed=3)
    first = data[1]["crop"]
    assert not torch.equal(first, plain[1]["crop"]) and first.shape == plain[1]["crop"].shape
    assert torch.equal(first, data[1]["crop"]) and data[1]["marker_id"] == plain[1]["marker_id"]
    data.set_epoch(1)
    assert not torch.equal(first, data[1]["crop"])
    crosspoints = RenderedDataset(folder, "train", "crosspoints", augment=Augment(colour_probability=1))
    clean = RenderedDataset(folder, "train", "crosspoints")
    assert torch.equal(crosspoints[0]["reference"], clean[0]["reference"])  # the reference is never augmented


def test_bad_folders_are_named(folder, tmp_path):
    with pytest.raises(ValueError, match="manifest.jsonl"):
        RenderedDataset(tmp_path, "train", "localizer")
    with pytest.raises(ValueError, match="split"):
        RenderedDataset(folder, "training", "localizer")
    with pytest.raises(ValueError, match="task"):
        RenderedDataset(folder, "train", "segmenter")
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("manifest.jsonl", "splits.json"):
        (broken / name).write_text((folder / name).read_text())
    with pytest.raises(ValueError, match="missing"):
        RenderedDataset(broken, "train", "recognizer")
    (broken / "samples").symlink_to(folder / "samples")
    (broken / "images").symlink_to(folder / "images")
    with pytest.raises(ValueError, match="template.npz"):
        RenderedDataset(broken, "train", "crosspoints")
    assert len(RenderedDataset(broken, "train", "crosspoints", spec=SPEC)) > 0
    (broken / "manifest.jsonl").write_text('{"name": "x", "split": "train"}\n')
    with pytest.raises(ValueError, match="manifest.jsonl:1: missing field"):
        RenderedDataset(broken, "train", "localizer")


def test_synth_items_follow_the_contract_and_are_reproducible(codebook):
    config = SynthConfig(image_size=(160, 160), marker_px=(40, 64), centred=True)
    localizer = SynthDataset("localizer", SPEC, length=3, seed=1, config=config, codebook=codebook)
    item = localizer[0]
    assert item["image"].shape == (3, 160, 160) and item["cells"].shape == (20, 20, 11)
    assert torch.equal(item["image"], localizer[0]["image"])
    assert not torch.equal(item["image"], SynthDataset("localizer", SPEC, 3, seed=2, config=config,
                                                       codebook=codebook)[0]["image"])
    recognizer = SynthDataset("recognizer", SPEC, length=8, seed=1, config=config, codebook=codebook)
    crops = [recognizer[i] for i in range(4)]  # one synthetic sample serves four items
    assert all(c["crop"].shape == (3, 96, 96) and c["marker_id"].dtype == torch.int64 for c in crops)
    assert len({int(c["marker_id"]) for c in crops}) > 1
    assert torch.equal(recognizer[2]["crop"], crops[2]["crop"])
    plain = config.replace(deformation=0.0, shading=False, occluders=(0, 0), boundary_probability=0.0)
    crosspoints = SynthDataset("crosspoints", SPEC, length=8, seed=1, config=plain, codebook=codebook)
    items = [crosspoints[i] for i in range(8)]
    assert all(i["crop"].shape == i["reference"].shape == (3, 112, 112) for i in items)
    assert all(i["xy"].shape == (25, 25, 2) and i["visible"].dtype == torch.bool for i in items)
    full = [i for i in items if i["visible"].all()]
    assert full
    # the reference is the canonical crop of the marker in the crop: of all IDs, it matches best
    references = _modules(reference_textures(SPEC, codebook, CROSSPOINT_CROP))
    for item in full:
        seen = _modules(item["crop"].permute(1, 2, 0).numpy()[None])[0]
        best = int(np.abs(references - seen).mean(axis=(1, 2, 3)).argmin())
        assert np.array_equal(_modules(item["reference"].permute(1, 2, 0).numpy()[None])[0], references[best])
    augmented = SynthDataset("crosspoints", SPEC, length=8, seed=1, config=plain, codebook=codebook, augment=Augment())
    assert torch.equal(augmented[0]["reference"], items[0]["reference"])
    assert np.array_equal(augmented[0]["xy"].numpy(), items[0]["xy"].numpy(), equal_nan=True)
    crosspoints.set_epoch(1)
    assert not torch.equal(items[3]["crop"], crosspoints[3]["crop"])


def _modules(crops: np.ndarray) -> np.ndarray:
    """The marker part of 112 px crops (N, 112, 112, 3) averaged per 8 x 8 px code module."""
    return crops[:, 8:104, 8:104].astype(np.float64).reshape(len(crops), 12, 8, 12, 8, 3).mean(axis=(2, 4))


def test_mixed_dataset_draws_in_proportion_to_the_weights(codebook):
    config = SynthConfig(image_size=(64, 64), marker_px=(30, 50))
    a = SynthDataset("localizer", SPEC, length=10, seed=0, config=config, codebook=codebook)
    b = SynthDataset("localizer", SPEC, length=20, seed=1, config=config, codebook=codebook)
    mixed = MixedDataset([a, b], weights=[3, 1], length=4000, seed=5)
    sources = np.array([mixed.source(i) for i in range(len(mixed))])
    assert abs((sources[:, 0] == 0).mean() - 0.75) < 0.03
    assert sources[sources[:, 0] == 0, 1].max() < 10 and sources[sources[:, 0] == 1, 1].max() >= 10
    assert len(np.unique(sources[sources[:, 0] == 1, 1])) == 20  # every item of b is reachable
    # synthesized items are i.i.d.: taken in order, so consecutive items share a synthesized sample
    assert all(j == i % len([a, b][k]) for i, (k, j) in enumerate(sources))
    k, j = mixed.source(7)
    assert torch.equal(mixed[7]["image"], [a, b][k][j]["image"])
    assert [mixed.source(i) for i in range(50)] == [tuple(s) for s in sources[:50]]
    mixed.set_epoch(1)
    assert [mixed.source(i) for i in range(50)] != [tuple(s) for s in sources[:50]] and a.epoch == 1
    with pytest.raises(ValueError, match="weight"):
        MixedDataset([a, b], weights=[1], length=10, seed=0)
    with pytest.raises(ValueError, match="tasks"):
        MixedDataset([a, SynthDataset("recognizer", SPEC, 2, 0, config=config, codebook=codebook)], [1, 1], 10, 0)


def test_localizer_images_decoded_ahead_give_the_items_read_per_image(folder, tmp_path):
    """decode_ahead changes where the images come from, not the items: plain, cropped with a view
    warp and augmentation; also in a copy pickled as a worker gets it, and
    with the PNGs gone once the dataset is made."""
    moved = shutil.copytree(folder, tmp_path / "dataset")
    gone = RenderedDataset(moved, "train", "localizer", seed=3, decode_ahead=True)
    shutil.rmtree(moved / "images")
    for i in range(len(gone)):
        assert torch.equal(gone[i]["image"], RenderedDataset(folder, "train", "localizer", seed=3)[i]["image"])
    warp = ViewWarp(probability=0.5)
    for settings in ({}, {"crop_px": 96, "view_warp": warp, "augment": Augment()}):
        read = RenderedDataset(folder, "train", "localizer", seed=3, **settings)
        ahead = RenderedDataset(folder, "train", "localizer", seed=3, decode_ahead=True, **settings)
        worker = pickle.loads(pickle.dumps(ahead))
        assert ahead._decoded.path.is_file() and len(ahead._decoded) == len(read)
        assert ahead.decoded_bytes == ahead._decoded.path.stat().st_size > 0 and read.decoded_bytes == 0
        _assert_same_items(read, ahead, worker)


def _assert_same_items(read: RenderedDataset, *others: RenderedDataset) -> None:
    """Every item of `others` equals `read`'s (NaN where it has NaN), in epochs 0 and 1."""
    for epoch in (0, 1):
        for data in (read, *others):
            data.set_epoch(epoch)
        for i in range(len(read)):
            expected = read[i]
            for data in others:
                item = data[i]
                assert item.keys() == expected.keys()
                for key, value in expected.items():
                    assert np.array_equal(item[key].numpy(), value.numpy(), equal_nan=True), (data.task, i, epoch, key)


@pytest.mark.parametrize("task, settings", [
    ("recognizer", {}), ("recognizer", {"crop_jitter_px": 1.0, "partial_markers": True}),
    ("crosspoints", {}), ("crosspoints", {"crop_jitter_px": 1.0})])
def test_crop_items_decoded_ahead_give_the_items_read_per_image(folder, tmp_path, task, settings):
    """The crop tasks decode ahead what they read per image (stored crops; or the image and the
    markers' ground truth that crops cut anew are cut from): the same items, augmented and over two
    epochs, also in a pickled worker's copy and with the images, ground truth and samples deleted
    once the dataset is made."""
    moved = shutil.copytree(folder, tmp_path / "dataset")
    read = RenderedDataset(folder, "train", task, seed=3, augment=Augment(), **settings)
    ahead = RenderedDataset(moved, "train", task, seed=3, augment=Augment(), decode_ahead=True, **settings)
    for name in ("images", "gt", "samples"):
        shutil.rmtree(moved / name)
    worker = pickle.loads(pickle.dumps(ahead))
    assert len(ahead) == len(read) > 0 and ahead.decoded_bytes > 0 and read.decoded_bytes == 0
    _assert_same_items(read, ahead, worker)
