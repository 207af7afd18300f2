"""Evaluation: the metric functions on hand-made arrays, and `networks.evaluate` on a tiny dataset folder
laid out as `factory.dataset` writes it (images from the real synthesizer, targets from
`assets.pattern.observation`)."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from assets.fileio import save_json, save_npz
from assets.pattern import CROSSPOINT_CROP, PatternSpec, crop_crosspoints_px, crop_localization_px
from assets.pattern.observation import ImageGroundTruth, crosspoint_crops, localizer_targets, recognizer_crops
from networks.checkpoint import save_checkpoint
from networks.config import TrainConfig
from networks.decode import duplicate_border_targets
from networks.evaluate import _Results, evaluate, evaluate_at, folder_batches, format_table, main, split_entries
from networks.homography import crop_to_image, smooth_crosspoints
from networks.metrics import (
    cells_to_markers,
    crosspoint_metrics,
    detection_scores,
    localizer_metrics,
    marker_reach_px,
    match_markers,
    recognizer_metrics,
)
from networks.synth import PatternSynthesizer, SynthConfig
from networks.tasks import build_model

SPEC = PatternSpec(rows=2, cols=2, num_ids=64)


def write_factory_dataset(root: Path, spec: PatternSpec, splits: dict[str, int], size: int = 128, seed: int = 0,
                          keep=lambda recognizer_crops, crosspoint_crops: recognizer_crops >= 1,
                          motion: str = "synth") -> Path:
    """A dataset folder with the files `factory.build.build` writes that the networks read:
    manifest.jsonl, splits.json, config.json, images/<name>.png, gt/<name>.npz, samples/<name>.npz.
    Images come from the synthesizer; `splits` gives the image count per split; synthetic samples are
    taken in order when keep(number of recognizer crops, number of crosspoint crops) holds (default:
    the image shows a fully visible marker, so it has crops of both kinds); `motion` names the images
    and their frames."""
    synth = PatternSynthesizer(spec, SynthConfig(image_size=(size, size), marker_px=(56.0, 72.0), occluders=(0, 1),
                                                 seed=seed))
    lines, frames, index = [], {}, 0
    for split, count in splits.items():
        for _ in range(count):
            rec_ids = xp_ids = ()
            while not keep(len(rec_ids), len(xp_ids)):
                index += 1
                image, gt = synth.sample(index)
                rec, rec_ids = recognizer_crops(image, gt, spec)
                xp, xp_ids, xp_xy, xp_vis = crosspoint_crops(image, gt, spec)
            name = f"{motion}_f{index:06d}_v0"
            save_npz(root / "samples" / f"{name}.npz", {
                "cells": localizer_targets(gt), "recognizer_crops": rec, "recognizer_ids": rec_ids,
                "crosspoint_crops": xp, "crosspoint_ids": xp_ids, "crosspoint_xy": xp_xy,
                "crosspoint_visible": xp_vis})
            gt.save(root / "gt" / f"{name}.npz")
            (root / "images").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / "images" / f"{name}.png"), image[:, :, ::-1])
            meta = {"name": name, "split": split, "motion": motion, "frame": index, "variation": 0,
                    "image": f"images/{name}.png", "gt": f"gt/{name}.npz", "samples": f"samples/{name}.npz",
                    "markers_visible": int((gt.status > 0).sum()), "markers_full": int((gt.status == 2).sum())}
            save_json(root / "meta" / f"{name}.json", meta)
            lines.append(json.dumps(meta, sort_keys=True))
            frames.setdefault(split, []).append(f"{motion}/{index}")
    (root / "manifest.jsonl").write_text("".join(line + "\n" for line in lines))
    save_json(root / "splits.json", {s: frames.get(s, []) for s in ("train", "val", "test")})
    save_json(root / "config.json", {"garment": "none", "motions": [motion], "seed": seed})
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return write_factory_dataset(tmp_path_factory.mktemp("ds"), SPEC, {"train": 1, "val": 1, "test": 3})


# ---- metric functions on arrays -------------------------------------------------------------------

def _markers(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.uniform(20, 200, (count, 2)) + np.arange(count)[:, None] * 60  # far apart
    return (centres[:, None] + rng.uniform(-15, 15, (count, 5, 2))).astype(np.float32)


def test_localizer_metrics_perfect_and_imperfect():
    gt = [_markers(4, 0), _markers(3, 1)]
    gt[1][2, 3] = np.nan  # a corner off the fabric
    full = [np.array([True, False, True, True]), np.array([True, True, False])]
    perfect = localizer_metrics([g.copy() for g in gt], gt, full)
    for subset in ("all", "full"):
        assert perfect[subset]["precision"] == perfect[subset]["recall"] == perfect[subset]["f1"] == 1.0
        for stats in perfect[subset]["error_px"].values():
            assert stats["median"] == 0.0 and stats["p95"] == 0.0
    assert perfect["all"]["error_px"]["BL"]["count"] == 6  # the NaN corner is not counted
    assert perfect["full"]["true_positive"] == 5

    # image 0: marker 1 (not full) missed, one far-away false positive, marker 0 off by (3, 0) px
    pred0 = np.concatenate([gt[0][[0, 2, 3]], _markers(1, 5) + 1000])
    pred0[0] += np.array([3.0, 0.0], np.float32)
    # image 1: marker 0 predicted 5 px away (beyond the 4 px radius): a miss and a false positive
    pred1 = gt[1].copy()
    pred1[0] += np.array([0.0, 5.0], np.float32)
    result = localizer_metrics([pred0, pred1], gt, full, radius_px=4.0)
    a, f = result["all"], result["full"]
    assert (a["true_positive"], a["false_positive"], a["false_negative"]) == (5, 2, 2)
    assert a["precision"] == pytest.approx(5 / 7) and a["recall"] == pytest.approx(5 / 7)
    # full markers: 5 of them, marker 0 of image 1 missed; the prediction matched to a partial marker
    # (image 1, marker 2) is neither a true nor a false positive
    assert (f["true_positive"], f["false_positive"], f["false_negative"]) == (4, 2, 1)
    assert a["error_px"]["centre"]["count"] == 5
    assert a["error_px"]["TL"]["p95"] == pytest.approx(np.percentile([3, 0, 0, 0, 0], 95))
    assert localizer_metrics([pred0], [gt[0]])["all"]["recall"] == pytest.approx(3 / 4)
    assert "full" not in localizer_metrics([pred0], [gt[0]])


def test_a_prediction_on_a_marker_that_is_not_a_target_is_neither_true_nor_false():
    """A marker whose centre is hidden is shown but is no target; finding it is not a false positive.
    A prediction far from every marker still is, and a target takes its prediction first."""
    gt = [_markers(3, 0)]
    other = _markers(2, 7)[:, 0] + 200  # two shown markers that are not targets
    pred = np.concatenate([gt[0], _markers(1, 3) + 1000, other[:1, None].repeat(5, axis=1)])
    pred[-1, 0] += np.array([2.0, 0.0], np.float32)  # 2 px from the first non-target centre
    full = [np.array([True, True, False])]
    plain = localizer_metrics([pred], gt, full, radius_px=4.0)
    assert plain["all"]["false_positive"] == plain["full"]["false_positive"] == 2 and "ignored" not in plain
    result = localizer_metrics([pred], gt, full, radius_px=4.0, gt_ignore=[other])
    assert result["ignored"] == 1
    for subset, tp in (("all", 3), ("full", 2)):
        assert (result[subset]["true_positive"], result[subset]["false_positive"], result[subset]["false_negative"]) \
            == (tp, 1, 0)
    # a non-target centre on a target's centre does not take the target's prediction
    assert localizer_metrics([gt[0]], gt, full, gt_ignore=[gt[0][:1, 0]])["all"]["true_positive"] == 3
    with pytest.raises(ValueError, match="1 ignore sets"):
        localizer_metrics([pred, pred], gt * 2, full * 2, gt_ignore=[other])


def test_a_prediction_on_a_partial_marker_beyond_the_radius_is_no_false_positive_of_the_full_ones():
    """A partial marker placed 6 px off misses its match (4 px), so it is a false positive and a miss
    over all markers; over the fully visible ones it is neither (it lies on a partial marker, within
    the markers' reach).  Placed so far off a full marker, or away from every marker, it counts."""
    gt = [_markers(3, 0)]
    full = [np.array([True, True, False])]
    reach = marker_reach_px(gt[0][:2])
    assert reach > 6.0
    shift = np.array([6.0, 0.0], np.float32)
    on_partial = np.concatenate([gt[0][:2], gt[0][2:] + shift])
    result = localizer_metrics([on_partial], gt, full, radius_px=4.0)
    assert (result["all"]["true_positive"], result["all"]["false_positive"], result["all"]["false_negative"]) == (2, 1, 1)
    assert (result["full"]["true_positive"], result["full"]["false_positive"], result["full"]["false_negative"]) == (2, 0, 0)
    assert result["full"]["on_other_markers"] == 1 and result["full"]["precision"] == 1.0
    on_full = np.concatenate([gt[0][:1] + shift, gt[0][1:]])
    assert localizer_metrics([on_full], gt, full, radius_px=4.0)["full"]["false_positive"] == 1
    beyond = np.concatenate([gt[0][:2], gt[0][2:] + np.array([reach + 1.0, 0.0], np.float32)])
    assert localizer_metrics([beyond], gt, full, radius_px=4.0)["full"]["false_positive"] == 1
    # a marker shown but no target (gt_ignore) is not fully visible either
    other = np.concatenate([np.full((1, 2), np.nan, np.float32), gt[0][2:, 0]])  # NaN: its centre is off the fabric
    result = localizer_metrics([on_partial[:2].tolist() + [(gt[0][2] + shift).tolist()]], [gt[0][:2]], [full[0][:2]],
                               radius_px=4.0, gt_ignore=[other])
    assert result["full"]["false_positive"] == 0 and result["full"]["on_other_markers"] == 1


def test_match_markers_one_to_one_within_radius():
    pred = np.array([[0.0, 0.0], [3.0, 0.0], [50.0, 50.0]])
    gt = np.array([[1.0, 0.0], [4.0, 0.0]])
    p, g = match_markers(pred, gt, radius_px=4.0)
    assert sorted(zip(p.tolist(), g.tolist())) == [(0, 0), (1, 1)]  # not both to the nearer truth
    p, g = match_markers(pred, gt, radius_px=0.5)
    assert len(p) == len(g) == 0
    assert len(match_markers(np.zeros((0, 2)), gt)[0]) == 0
    assert detection_scores(0, 0, 0) == {"precision": 1.0, "recall": 1.0, "f1": 1.0, "true_positive": 0,
                                         "false_positive": 0, "false_negative": 0}


def test_cells_to_markers_undoes_targets_and_border_copies():
    cells = np.zeros((6, 6, 11), np.float32)
    cells[2, 3, 0] = 1
    cells[2, 3, 1:] = np.array([7.5, 0.4] + [1.0, -3.0] * 4, np.float32)  # centre near two borders
    cells[4, 1, 0] = 1
    cells[4, 1, 1:] = np.array([4.0, 4.0] + [np.nan] * 2 + [2.0] * 6, np.float32)
    markers = cells_to_markers(cells)
    assert markers.shape == (2, 5, 2)
    np.testing.assert_allclose(markers[0, 0], [3 * 8 + 7.5, 2 * 8 + 0.4], atol=1e-5)
    assert np.isnan(markers[1, 1]).all()
    duplicated = duplicate_border_targets(cells)
    assert (duplicated[..., 0] > 0.5).sum() == 5  # the first marker copied to three neighbours
    np.testing.assert_allclose(cells_to_markers(duplicated), markers, atol=1e-4)


def test_recognizer_and_crosspoint_metrics():
    ranked = np.array([[3, 1, 2], [0, 5, 6], [7, 8, 9]])
    result = recognizer_metrics(ranked, np.array([3, 5, 4]))
    assert result["top1"] == pytest.approx(1 / 3) and result["top5"] == pytest.approx(2 / 3)

    rng = np.random.default_rng(0)
    gt_xy = rng.uniform(0, 112, (3, 5, 5, 2))
    gt_visible = rng.random((3, 5, 5)) > 0.3
    gt_xy[~gt_visible] = np.nan
    perfect = crosspoint_metrics(gt_visible, gt_xy, gt_visible, gt_xy, gt_xy * 2, gt_xy * 2)
    assert perfect["visibility"]["precision"] == perfect["visibility"]["recall"] == 1.0
    assert perfect["crop_error_px"]["median"] == 0 and perfect["image_error_px"]["p95"] == 0
    assert perfect["crop_error_px"]["count"] == gt_visible.sum()
    pred_visible = gt_visible.copy()
    pred_visible[0] = True  # false positives where hidden
    pred_xy = np.where(np.isnan(gt_xy), 0.0, gt_xy) + [0.6, 0.8]  # 1 px off everywhere
    result = crosspoint_metrics(pred_visible, pred_xy, gt_visible, gt_xy)
    assert result["visibility"]["recall"] == 1.0
    assert result["visibility"]["false_positive"] == (~gt_visible[0]).sum()
    assert result["crop_error_px"]["median"] == pytest.approx(1.0) and result["image_error_px"] is None
    with pytest.raises(ValueError, match="shapes differ"):
        crosspoint_metrics(gt_visible, gt_xy[:2], gt_visible, gt_xy)


def test_crosspoint_errors_by_marker_size():
    """Each crop's errors go to its marker's size bin; the pooled numbers stay what they were."""
    gt_xy = np.zeros((3, 5, 5, 2))
    gt_visible = np.ones((3, 5, 5), bool)
    gt_visible[2, 0] = False  # a hidden row: not counted
    shift = np.array([2.0, 0.5, 0.3])[:, None, None, None] * [0.6, 0.8]  # crop errors 2, 0.5, 0.3 px
    pred_xy = gt_xy + shift
    result = crosspoint_metrics(gt_visible, pred_xy, gt_visible, gt_xy, pred_xy / 10, gt_xy / 10,
                                marker_side_px=np.array([10.0, 21.0, 23.0]))
    assert result["crop_error_px"] == crosspoint_metrics(gt_visible, pred_xy, gt_visible, gt_xy)["crop_error_px"]
    by_size = result["by_marker_size"]
    assert list(by_size) == ["0-12 px", "20-24 px"]  # bins without a crop are left out
    assert by_size["0-12 px"]["crops"] == 1 and by_size["0-12 px"]["crop_error_px"]["median"] == pytest.approx(2.0)
    assert by_size["0-12 px"]["image_error_px"]["median"] == pytest.approx(0.2)
    assert by_size["20-24 px"]["crops"] == 2 and by_size["20-24 px"]["crop_error_px"]["count"] == 25 + 20
    assert by_size["20-24 px"]["crop_error_px"]["median"] == pytest.approx(0.5)  # 25 at 0.5 against 20 at 0.3
    assert "by_marker_size" not in crosspoint_metrics(gt_visible, pred_xy, gt_visible, gt_xy)
    # the crops whose every crosspoint is visible: the first two (the third has a hidden row)
    whole = result["fully_visible"]
    assert whole["crops"] == 2 and whole["crop_error_px"]["count"] == 50
    assert whole["crop_error_px"]["median"] == pytest.approx(1.25) and whole["image_error_px"]["median"] == pytest.approx(0.125)
    with pytest.raises(ValueError, match="marker_side_px"):
        crosspoint_metrics(gt_visible, pred_xy, gt_visible, gt_xy, marker_side_px=np.ones(2))


# ---- the dataset folder and the model runs ---------------------------------------------------------

def test_folder_batches_carry_consistent_ground_truth(dataset):
    entries = split_entries(dataset, "test")
    assert len(entries) == 3
    everything = split_entries(dataset, "all")  # a held-out garment's folder: every image
    assert len(everything) > 3 and all(e in everything for e in entries)
    with pytest.raises(ValueError, match="no images in split 'nope'.*test, train, val"):
        split_entries(dataset, "nope")
    with pytest.raises(FileNotFoundError, match="no such dataset folder"):
        split_entries(dataset / "missing", "test")
    batches = list(folder_batches("crosspoints", dataset, "test", SPEC, batch_size=4))
    crops = sum(len(b["crop"]) for b in batches)
    assert crops > 0
    for b in batches:
        assert b["crop"].dtype == torch.uint8 and b["crop"].shape[1:] == (3, 112, 112)
        assert b["reference"].shape == b["crop"].shape
        # the crop homography refitted to the five points maps the crop truth back onto the image truth
        visible = b["visible"].numpy()
        image = crop_to_image(SPEC, CROSSPOINT_CROP, b["points_px"].numpy().astype(np.float64), b["xy"].numpy())
        np.testing.assert_allclose(image[visible], b["gt_xy_image"].numpy()[visible], atol=1e-3)
    # recognizer crops say which of their markers are fully visible (status 2), in the crops' order
    full = np.concatenate([b["full"].numpy() for b in folder_batches("recognizer", dataset, "test", SPEC)])
    truth = [ImageGroundTruth.load(dataset / e["gt"]) for e in entries]
    assert full.tolist() == [s == 2 for gt in truth for s in gt.status[gt.point_visible.all(axis=1)]]
    assert full.any()
    localizer = list(folder_batches("localizer", dataset, "test", SPEC))
    assert len(localizer) == 3
    for b in localizer:
        assert b["image"].shape == (1, 3, 128, 128) and b["cells"].shape == (1, 16, 16, 11)
        assert len(b["gt_full"][0]) == len(cells_to_markers(b["cells"][0].numpy()))
        ignore, targets = b["gt_ignore"][0], cells_to_markers(b["cells"][0].numpy())[:, 0]
        assert ignore.ndim == 2 and ignore.shape[1] == 2
        assert not (np.linalg.norm(ignore[:, None] - targets[None], axis=-1) < 1e-2).any()  # no target twice


@pytest.mark.parametrize("task", ["localizer", "recognizer", "crosspoints"])
def test_evaluate_untrained_checkpoint_in_range(task, dataset, tmp_path):
    torch.manual_seed(0)
    model = build_model(task, SPEC.num_ids, SPEC.crosspoints_per_side)
    path = save_checkpoint(tmp_path / "best.pt", task, model, TrainConfig(task), SPEC, step=3)
    metrics = evaluate(path, dataset, "test", task=task, device="cpu", batch_size=8, progress=False)
    assert metrics["task"] == task and metrics["step"] == 3 and metrics["samples"] > 0
    assert np.isfinite(metrics["loss"]["total"]) and metrics["loss"]["total"] > 0
    if task == "localizer":
        assert metrics["images"] == 3
        for subset in ("all", "full"):
            for key in ("precision", "recall", "f1"):
                assert 0 <= metrics[subset][key] <= 1
    elif task == "recognizer":
        assert 0 <= metrics["top1"] <= metrics["top5"] <= 1
        assert 0 < metrics["fully_visible"]["count"] <= metrics["count"]
    else:
        assert 0 <= metrics["visibility"]["precision"] <= 1 and 0 <= metrics["visibility"]["recall"] <= 1
        assert metrics["crop_error_px"]["median"] >= 0 and metrics["image_error_px"]["count"] > 0
        assert metrics["crop_error_px"]["count"] == metrics["image_error_px"]["count"]
        assert 0 < metrics["fully_visible"]["crop_error_px"]["count"] <= metrics["crop_error_px"]["count"]
    assert task in format_table(metrics)


@pytest.mark.parametrize("task", ["localizer", "crosspoints"])
def test_one_pass_at_several_thresholds_is_each_threshold_s_own_evaluation(task, dataset, tmp_path):
    torch.manual_seed(1)
    model = build_model(task, SPEC.num_ids, SPEC.crosspoints_per_side)
    path = save_checkpoint(tmp_path / "best.pt", task, model, TrainConfig(task), SPEC, step=3)
    thresholds = [0.2, 0.5, 0.8]
    together = evaluate_at(path, dataset, thresholds, "test", task=task, device="cpu", batch_size=8, progress=False)
    assert list(together) == thresholds
    for t in thresholds[1:]:  # a crosspoint pass takes 13 s here: two thresholds checked alone
        alone = evaluate(path, dataset, "test", task=task, device="cpu", batch_size=8, threshold=t, progress=False)
        assert json.dumps(together[t], sort_keys=True, default=str) == json.dumps(alone, sort_keys=True, default=str)
    key = ("all", "true_positive") if task == "localizer" else ("visibility", "true_positive")
    counts = [together[t][key[0]][key[1]] for t in thresholds]
    assert counts[0] >= counts[1] >= counts[2] and counts[0] > counts[2]  # the thresholds did apply
    with pytest.raises(ValueError, match="thresholds must be"):
        evaluate_at(path, dataset, [0.5, 1.0], "test", task=task, device="cpu", progress=False)


def test_a_folder_without_its_samples_is_evaluated_from_its_images_and_ground_truth(dataset, tmp_path):
    """A dataset folder that travelled without samples/ (they are derived data) evaluates the same: the
    samples are made in memory from the image and gt/; without gt/ either, the error names the file."""
    torch.manual_seed(2)
    model = build_model("recognizer", SPEC.num_ids, SPEC.crosspoints_per_side)
    path = save_checkpoint(tmp_path / "rec.pt", "recognizer", model, TrainConfig("recognizer"), SPEC, step=1)
    bare = tmp_path / "bare"
    shutil.copytree(dataset, bare)
    shutil.rmtree(bare / "samples")
    full = evaluate(path, dataset, "test", task="recognizer", device="cpu", progress=False)
    made = evaluate(path, bare, "test", task="recognizer", device="cpu", progress=False)
    assert made["samples"] == full["samples"] > 0 and made["top1"] == full["top1"]
    assert made["loss"]["total"] == pytest.approx(full["loss"]["total"], rel=1e-6)
    shutil.rmtree(bare / "gt")
    with pytest.raises(ValueError, match=r"samples/.*\.npz: no such file, and no ground truth"):
        evaluate(path, bare, "test", task="recognizer", device="cpu", progress=False)


def test_cli_writes_json(dataset, tmp_path, capsys):
    path = save_checkpoint(tmp_path / "rec.pt", "recognizer", build_model("recognizer", SPEC.num_ids),
                           TrainConfig("recognizer"), SPEC)
    assert main(["recognizer", "--checkpoint", str(path), "--data", str(dataset), "--device", "cpu"]) == 0
    written = json.loads((tmp_path / "eval_recognizer_test.json").read_text())
    assert written["task"] == "recognizer" and 0 <= written["top1"] <= 1
    assert "top1" in capsys.readouterr().out
    assert main(["localizer", "--checkpoint", str(path), "--data", str(dataset)]) == 2
    assert "a recognizer checkpoint, expected a localizer" in capsys.readouterr().err
    assert main(["recognizer", "--checkpoint", str(path), "--data", str(tmp_path / "none")]) == 2


@pytest.mark.parametrize("task", ["localizer", "crosspoints"])
def test_evaluate_on_a_shard_folder_of_synthesized_samples(task, tmp_path):
    from networks.data import ShardDataset
    from networks.shards import write_shards

    config = SynthConfig(image_size=(96, 96), marker_px=(40.0, 48.0), seed=5)
    write_shards(tmp_path / "shards", task, SPEC, count=2, config=config, workers=1, images_per_part=2,
                 progress=False)
    model = build_model(task, SPEC.num_ids, SPEC.crosspoints_per_side)
    path = save_checkpoint(tmp_path / "best.pt", task, model, TrainConfig(task), SPEC, step=2)
    metrics = evaluate(path, tmp_path / "shards", task=task, device="cpu", batch_size=4, progress=False)
    assert metrics["split"] == "shards" and metrics["samples"] == len(ShardDataset(tmp_path / "shards", task)) > 0
    if task == "crosspoints":  # the crop error of every visible crosspoint; no image to map it into
        assert metrics["crop_error_px"]["count"] > 0 and metrics["image_error_px"] is None
    else:
        assert 0 <= metrics["all"]["recall"] <= 1 and "full" not in metrics
    other = save_checkpoint(tmp_path / "other.pt", task, model, TrainConfig(task),
                            PatternSpec(rows=2, cols=2, num_ids=64, seed=1), step=2)
    with pytest.raises(ValueError, match="another codebook"):
        evaluate(other, tmp_path / "shards", task=task, device="cpu", progress=False)


def test_crosspoint_results_give_the_detectors_smoothed_crosspoints_beside_the_networks():
    """"smoothed": the errors of the network's crosspoints after the Detector's default smoothing,
    in the crop and (through each crop's five points) in the image."""
    rng = np.random.default_rng(3)
    n, k = 4, SPEC.crosspoints_per_side
    canonical = crop_crosspoints_px(SPEC, CROSSPOINT_CROP)
    u = (canonical - 56.0) / 48.0  # a smooth bend of each crop's grid, up to about 2 px
    truth = np.stack([canonical + rng.normal(0, 1.0, 2) * u ** 2 + rng.normal(0, 1.0, 2) * u[..., ::-1]
                      for _ in range(n)])
    pred = truth + rng.normal(0, 0.3, truth.shape)  # the network's noise
    visible = np.ones((n, k, k), dtype=bool)
    output = torch.cat([torch.full((n, 1, k, k), 20.0), torch.from_numpy(pred).permute(0, 3, 1, 2).float()], dim=1)
    points = np.broadcast_to(crop_localization_px(SPEC, CROSSPOINT_CROP), (n, 5, 2))  # image = crop
    batch = {"visible": torch.from_numpy(visible), "xy": torch.from_numpy(truth).float(),
             "points_px": torch.from_numpy(points.copy()), "gt_xy_image": torch.from_numpy(truth)}
    results = _Results("crosspoints", SPEC, 2.0, 0.5)
    results.update(output, torch.tensor(0.0), {}, batch)
    metrics = results.result()
    raw, smoothed = metrics["crop_error_px"], metrics["smoothed"]["crop_error_px"]
    expected = crosspoint_metrics(visible, smooth_crosspoints(output[:, 1:].permute(0, 2, 3, 1).numpy(), visible, 0.5),
                                  visible, truth.astype(np.float32))["crop_error_px"]
    assert smoothed == pytest.approx(expected)
    assert raw["median"] == pytest.approx(0.3 * 1.1774, rel=0.1)  # the noise's: a Rayleigh median
    assert smoothed["median"] < 0.5 * raw["median"]
    assert metrics["smoothed"]["image_error_px"]["median"] == pytest.approx(smoothed["median"], abs=1e-4)
    assert metrics["smoothed"]["fully_visible"]["crops"] == n


@pytest.mark.parametrize("classes", ["codebook", "modules"])
def test_a_recognizer_restricted_to_the_garment_s_ids_answers_among_them(classes, dataset, tmp_path):
    """--garment-ids: an ID classifier's and a module reader's answers come from the garment's IDs
    only (the Detector's restriction), so an untrained network is right among the few IDs printed."""
    from tests.networks.test_recipe import write_template

    torch.manual_seed(3)
    model = build_model("recognizer", SPEC.num_ids, SPEC.crosspoints_per_side, recognizer_classes=classes,
                        modules_per_side=SPEC.modules_per_side)
    path = save_checkpoint(tmp_path / "rec.pt", "recognizer", model,
                           TrainConfig("recognizer", recognizer_classes=classes), SPEC, step=1)
    seen = np.unique(np.concatenate([np.load(dataset / e["samples"])["recognizer_ids"]
                                     for e in split_entries(dataset, "test")]))
    assert 1 <= len(seen) <= 5
    garment = tmp_path / "garment"
    shutil.copytree(dataset, garment)
    write_template(garment, SPEC, [(int(i), 1, 1) for i in seen])
    anywhere = evaluate(path, garment, "test", task="recognizer", device="cpu", progress=False)
    among = evaluate(path, garment, "test", task="recognizer", device="cpu", progress=False, garment_ids=True)
    assert among["garment_ids"] and not anywhere["garment_ids"]
    assert among["top5"] == 1.0 and among["top1"] >= anywhere["top1"]  # the true ID is always a candidate
    with pytest.raises(ValueError, match="garment IDs restrict a recognizer on a factory dataset folder"):
        evaluate(path, dataset, "test", task="recognizer", device="cpu", progress=False, garment_ids=True)
