"""Evaluate a trained network on a split of a factory dataset; also the validation of `networks.train`.

    python -m networks.evaluate localizer --checkpoint runs/loc/best.pt --data out/ds --split test
    python -m networks.evaluate crosspoints --checkpoint runs/xp/best.pt --data out/ds --json xp.json
    python -m networks.evaluate crosspoints --checkpoint runs/xp/best.pt --data xp_shards  # synthesized

Reports (see `networks.metrics` for the definitions):
  localizer    marker precision / recall / F1 (a prediction matches a ground-truth marker whose centre
               is within --radius pixels), over all markers of the cell targets and over the fully
               visible ones, and the median and 95th-percentile error of each localization point;
  recognizer   top-1 and top-5 accuracy (a module reader's IDs decoded against the whole codebook,
               `networks.codes.CodeDecoder`);
  crosspoints  visibility precision / recall and the median and 95th-percentile error of the
               crosspoints visible in the ground truth, in crop pixels and in image pixels, also by
               the size of the crop's marker in the image (a crop magnifies a small marker more),
               and ("smoothed") the same errors of the crosspoints as the Detector returns them from
               these crops, after its default smoothing (`DetectorConfig.smooth_crosspoints_px`,
               `networks.homography.smooth_crosspoints`);
and the mean loss of each.  Prints a table and writes the metrics as JSON.  The three chained, as
`networks.Detector` runs them on whole images: `python -m networks.evaluate_detector`.

Ground truth comes from the dataset's own files, read directly (no augmentation): the cell targets,
crops and crosspoint positions of `samples/<name>.npz`, and from `gt/<name>.npz`
(`ImageGroundTruth`) which markers are fully visible and each crop's five localization points in the
image.  The samples do not store the crop homography, so the image error maps the predicted crop
positions back through the homography fitted to those five points (`crop_homography`, exactly as the
factory made the crop) and compares them with the ground-truth image crosspoints.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader
from tqdm import tqdm

from assets.fileio import load_npz, save_json
from assets.pattern import CROSSPOINT_CROP, CropSpec, PatternSpec, generate_codebook, reference_textures
from assets.pattern.observation import (ImageGroundTruth, completed_points, crosspoint_crops, crosspoint_markers,
                                       recognizer_markers, training_samples)
from networks.checkpoint import check_pattern, checkpoint_spec, load_checkpoint
from networks.codes import CodeDecoder, module_targets
from networks.config import SMOOTH_CROSSPOINTS_PX, TASKS
from networks.data import SHARD_META, ShardDataset
from networks.data import _manifest as read_manifest
from networks.data import _read_png as read_png
from networks.data import dataset_spec, garment_marker_ids
from networks.decode import decode_localizer
from networks.homography import crop_to_image, marker_side_px, smooth_crosspoints
from networks.metrics import (
    MATCH_RADIUS_PX,
    cells_to_markers,
    crosspoint_metrics,
    localizer_metrics,
    recognizer_metrics,
)
from networks.tasks import autocast, batch_length, forward, reads_modules

#: sample arrays each task reads from `samples/<name>.npz`
SAMPLE_KEYS = {
    "localizer": ("cells",),
    "recognizer": ("recognizer_crops", "recognizer_ids"),
    "crosspoints": ("crosspoint_crops", "crosspoint_ids", "crosspoint_xy", "crosspoint_visible"),
}


def resolve_device(device: str | torch.device | None) -> torch.device:
    """`device`, or the first CUDA GPU when there is one, else the CPU."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda was asked for, but torch finds no CUDA GPU")
    return device


# ---- a factory dataset folder, read directly -------------------------------------------------------

def split_entries(root: str | Path, split: str) -> list[dict]:
    """The manifest entries (one dict per finished image) of `split` in a factory dataset folder
    ("all": every image, as for a held-out garment's folder, which no network trained on)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such dataset folder")
    entries = read_manifest(root)
    chosen = [e for e in entries if split in ("all", e["split"])]
    if not chosen:
        splits = sorted({str(e["split"]) for e in entries})
        raise ValueError(f"{root / 'manifest.jsonl'}: no images in split {split!r} "
                         f"(splits present: {', '.join(splits) or 'none'})")
    return chosen


def crosspoint_crop_points(gt: ImageGroundTruth, spec: PatternSpec, marker_id: np.ndarray, source: Path,
                           crop: CropSpec = CROSSPOINT_CROP) -> tuple[np.ndarray, np.ndarray]:
    """Five image points and image crosspoints of each crosspoint crop, picked as
    `assets.pattern.observation.crosspoint_crops` picks them in `crop` (`crosspoint_markers`);
    `marker_id`: the crops' IDs, checked against that pick (`source` names the ground truth in the error)."""
    pick, _ = crosspoint_markers(gt, spec, crop=crop)
    if not np.array_equal(gt.marker_id[pick], marker_id):
        raise ValueError(f"{source}: its markers do not match the crosspoint crops of the sample "
                         f"({len(pick)} usable markers, {len(marker_id)} crops); build samples/ again with "
                         "assets.pattern.observation.training_samples")
    return completed_points(gt)[pick], gt.crosspoints_px[pick]


def crosspoint_arrays(spec: PatternSpec, codebook: np.ndarray, crops: np.ndarray, marker_id: np.ndarray,
                      xy: np.ndarray, visible: np.ndarray, crop: CropSpec = CROSSPOINT_CROP) -> dict[str, np.ndarray]:
    """A crosspoint crop set (`crosspoint_crops`' four arrays, cut in `crop`) as `crop_batches` takes
    it, with each ID's reference texture."""
    ids = np.asarray(marker_id, np.int64)
    return {"crop": crops, "reference": reference_textures(spec, codebook[ids], crop),
            "xy": np.asarray(xy, np.float32), "visible": np.asarray(visible, bool)}


def crop_batches(arrays: dict[str, np.ndarray], batch_size: int = 32) -> Iterator[dict]:
    """Batches of tensors of equal-length arrays (crops and references (N, H, W, C) become (B, C, H, W)),
    as the datasets' items collated."""
    for start in range(0, len(arrays["crop"]), batch_size):
        part = {k: v[start:start + batch_size] for k, v in arrays.items()}
        batch = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in part.items()}
        for key in ("crop", "reference"):
            if key in batch:
                batch[key] = batch[key].permute(0, 3, 1, 2).contiguous()
        yield batch


def folder_batches(task: str, root: str | Path, split: str, spec: PatternSpec, batch_size: int = 32,
                   crop: CropSpec = CROSSPOINT_CROP) -> Iterator[dict]:
    """Batches of the split's samples as the datasets' items collated (`networks.tasks`), with the
    ground truth the metrics need beside them: localizer batches carry "gt_full" (per image (M,)
    bool, matching `cells_to_markers`) and "gt_ignore" (per image (L, 2) centres of the markers the
    image shows that are not targets: `localizer_metrics` counts a prediction on one as neither
    true nor false), recognizer batches "full" (B,) bool (the crop's marker is fully visible, status
    2: no fold hides a part of it), crosspoint batches "points_px" (B, 5, 2) and "gt_xy_image"
    (B, K, K, 2) image pixels, all when `gt/<name>.npz` exists.  Localizer batches hold one image each.
    crop: the crosspoint crops' (a network's `crop`); other than the reference's, whose crops the
    samples store, they are cut from the images with their ground truth (`crosspoint_crops`)."""
    root = Path(root)
    codebook = generate_codebook(spec) if task == "crosspoints" else None
    for entry in split_entries(root, split):
        samples_path = root / entry.get("samples", f"samples/{entry.get('name')}.npz")
        gt_path = root / entry["gt"] if "gt" in entry else None
        gt = ImageGroundTruth.load(gt_path) if gt_path is not None and gt_path.is_file() else None
        image = None  # read once, where needed
        if samples_path.is_file():
            samples = load_npz(samples_path, required=SAMPLE_KEYS[task])
        elif gt is not None:  # a folder that travelled without samples/: made in memory from image and truth
            image = read_png(root / entry["image"])
            samples = training_samples(image, gt, spec)
        else:
            raise ValueError(f"{samples_path}: no such file, and no ground truth (gt/) to make the samples from")
        if task == "localizer":
            image = read_png(root / entry["image"]) if image is None else image
            cells = samples["cells"].astype(np.float32)
            batch = {"image": torch.from_numpy(image).permute(2, 0, 1)[None].contiguous(),
                     "cells": torch.from_numpy(cells)[None]}
            if gt is not None:
                centres = cells_to_markers(cells)[:, 0].astype(np.float64)
                full_centres = gt.points_px[gt.status == 2, 0].astype(np.float64)
                shown = gt.points_px[gt.status > 0, 0].astype(np.float64)  # every marker the image shows
                # (distances to an empty set are an empty axis: any() is False there)
                batch["gt_full"] = [(np.linalg.norm(centres[:, None] - full_centres[None], axis=-1) < 1e-2).any(axis=1)]
                target = (np.linalg.norm(shown[:, None] - centres[None], axis=-1) < 1e-2).any(axis=1)
                batch["gt_ignore"] = [shown[~target]]
            yield batch
            continue
        if task == "recognizer":
            arrays = {"crop": samples["recognizer_crops"], "marker_id": samples["recognizer_ids"].astype(np.int64)}
            if gt is not None:  # which crops show a fully visible marker (status 2)
                pick = recognizer_markers(gt, spec)  # the markers the crops are cut for, in their order
                if len(pick) == len(arrays["marker_id"]) and np.array_equal(gt.marker_id[pick], arrays["marker_id"]):
                    arrays["full"] = gt.status[pick] == 2
        else:
            if crop == CROSSPOINT_CROP:
                made = tuple(samples[key] for key in SAMPLE_KEYS["crosspoints"])
            elif gt is None:
                raise ValueError(f"{root}: {entry.get('name')} has no gt/<name>.npz, which a {crop.size_px} x "
                                 f"{crop.size_px} crosspoint crop is cut with (the samples store 112 x 112 crops)")
            else:
                made = crosspoint_crops(read_png(root / entry["image"]) if image is None else image, gt, spec, crop)
            arrays = crosspoint_arrays(spec, codebook, *made, crop=crop)
            if gt is not None:
                arrays["points_px"], arrays["gt_xy_image"] = crosspoint_crop_points(gt, spec, made[1], gt_path, crop)
        yield from crop_batches(arrays, batch_size)


def data_batches(task: str, data: str | Path, split: str, spec: PatternSpec, batch_size: int = 32,
                 crop: CropSpec = CROSSPOINT_CROP) -> Iterable[dict]:
    """Batches of every item of a shard folder of synthesized samples (`networks.shards write`; `split`
    is not used), or of a factory dataset's split (`folder_batches`, whose crosspoint crops are cut in
    `crop`)."""
    if (Path(data) / SHARD_META).is_file():
        return DataLoader(ShardDataset(data, task, spec=spec), batch_size=batch_size)
    return folder_batches(task, data, split, spec, batch_size, crop)


def model_crop(model: nn.Module) -> CropSpec:
    """The crosspoint crop a network takes: a `CrosspointLocalizer`'s `crop`, the reference's for the
    others (which cut none)."""
    return getattr(model, "crop", CROSSPOINT_CROP)


# ---- running a model -------------------------------------------------------------------------------

def crosspoint_predictions(output: torch.Tensor, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A `CrosspointLocalizer` output (B, 3, K, K) as (visible (B, K, K) bool: sigmoid above
    `threshold`; xy (B, K, K, 2) float32 crop pixels)."""
    out = output.detach().float().cpu().numpy()
    return out[:, 0] > np.log(threshold / (1 - threshold)), out[:, 1:].transpose(0, 2, 3, 1)


class _Results:
    """Accumulates one task's predictions, ground truth and loss over batches."""

    def __init__(self, task: str, spec: PatternSpec | None, radius_px: float, threshold: float,
                 crop: CropSpec = CROSSPOINT_CROP, decoder: CodeDecoder | None = None,
                 candidates: torch.Tensor | None = None) -> None:
        self.task, self.spec, self.radius_px, self.threshold, self.crop = task, spec, radius_px, threshold, crop
        self.decoder = decoder  # a module reader's: its logits ranked as codebook IDs
        self.candidates = candidates  # an ID classifier's: the IDs (K,) int64 it may answer
        self.samples = 0
        self.loss: dict[str, float] = {}
        self.store: dict[str, list] = {}

    def _add(self, **arrays: object) -> None:
        for key, value in arrays.items():
            self.store.setdefault(key, []).append(value)

    def update(self, output: torch.Tensor, loss: torch.Tensor, parts: dict[str, torch.Tensor], batch: dict) -> None:
        n = batch_length(batch)
        self.samples += n
        for key, value in {"total": loss, **parts}.items():
            self.loss[key] = self.loss.get(key, 0.0) + float(value) * n
        output = output.detach().float()
        if self.task == "localizer":
            decoded = decode_localizer(output, threshold=self.threshold)
            self._add(pred=[points for points, _ in decoded],
                      gt=[cells_to_markers(c) for c in batch["cells"].numpy()], full=batch.get("gt_full"),
                      ignore=batch.get("gt_ignore"))
        elif self.task == "recognizer":
            if self.decoder is None and self.candidates is not None:
                allowed = torch.zeros(output.shape[1], dtype=torch.bool, device=output.device)
                allowed[self.candidates.to(output.device)] = True
                output = output.masked_fill(~allowed, -math.inf)
            ranked = self.decoder.ranked(output, 5) if self.decoder is not None \
                else torch.topk(output, min(5, output.shape[1]), dim=1).indices
            self._add(ranked=ranked.cpu().numpy(), marker_id=batch["marker_id"].numpy(),
                      full=batch["full"].numpy() if "full" in batch else None)
        else:
            pred_visible, pred_xy = crosspoint_predictions(output, self.threshold)
            smoothed = smooth_crosspoints(pred_xy, pred_visible, SMOOTH_CROSSPOINTS_PX)  # as the Detector returns them
            self._add(pred_visible=pred_visible, pred_xy=pred_xy, smoothed_xy=smoothed,
                      gt_visible=batch["visible"].numpy(), gt_xy=batch["xy"].numpy())
            if "points_px" in batch and self.spec is not None:
                points = np.asarray(batch["points_px"], dtype=np.float64)
                self._add(pred_image=crop_to_image(self.spec, self.crop, points, pred_xy),
                          smoothed_image=crop_to_image(self.spec, self.crop, points, smoothed),
                          gt_image=np.asarray(batch["gt_xy_image"]), side=marker_side_px(points))

    def result(self) -> dict:
        if self.samples == 0:
            raise ValueError(f"no {self.task} samples to evaluate")
        loss = {key: value / self.samples for key, value in self.loss.items()}
        s = self.store
        if self.task == "localizer":
            pred = [p for chunk in s["pred"] for p in chunk]
            gt = [g for chunk in s["gt"] for g in chunk]
            full = None if any(f is None for f in s["full"]) else [f for chunk in s["full"] for f in chunk]
            ignore = None if any(f is None for f in s["ignore"]) else [f for chunk in s["ignore"] for f in chunk]
            metrics = localizer_metrics(pred, gt, full, self.radius_px, ignore)
        elif self.task == "recognizer":
            ranked, marker_id = np.concatenate(s["ranked"]), np.concatenate(s["marker_id"])
            metrics = recognizer_metrics(ranked, marker_id)
            if all(f is not None for f in s["full"]):  # every batch knew its fully visible markers
                full = np.concatenate(s["full"])
                metrics["fully_visible"] = recognizer_metrics(ranked[full], marker_id[full])
        else:
            image, smoothed_image = {}, {}
            if len(s.get("pred_image", [])) == len(s["pred_xy"]):  # every batch had image points
                image = {"pred_xy_image": np.concatenate(s["pred_image"]),
                         "gt_xy_image": np.concatenate(s["gt_image"]), "marker_side_px": np.concatenate(s["side"])}
                # no marker sizes: the smoothed block keeps no per-size bins
                smoothed_image = {"pred_xy_image": np.concatenate(s["smoothed_image"]),
                                  "gt_xy_image": image["gt_xy_image"]}
            visible, gt_visible, gt_xy = (np.concatenate(s[k]) for k in ("pred_visible", "gt_visible", "gt_xy"))
            metrics = crosspoint_metrics(visible, np.concatenate(s["pred_xy"]), gt_visible, gt_xy, **image)
            smoothed = crosspoint_metrics(visible, np.concatenate(s["smoothed_xy"]), gt_visible, gt_xy,
                                          **smoothed_image)
            metrics["smoothed"] = {key: smoothed[key] for key in ("crop_error_px", "image_error_px", "fully_visible")}
        return {"loss": loss, "samples": self.samples, **metrics}


def evaluate_model(task: str, model: nn.Module, batches: Iterable[dict], device: str | torch.device = "cpu",
                   spec: PatternSpec | None = None, mixed_precision: bool = True, radius_px: float = MATCH_RADIUS_PX,
                   threshold: float = 0.5, progress: bool = False) -> dict:
    """Metrics of `model` (any mode; evaluated in eval mode, then restored) over `batches` (collated
    dataset items, optionally with the extra ground truth of `folder_batches`).  `spec` is needed for
    the crosspoints' image error.  Returns {"loss": {"total", parts}, "samples", task metrics}."""
    return evaluate_model_at(task, model, batches, [threshold], device, spec, mixed_precision, radius_px,
                             progress)[threshold]


@torch.no_grad()
def evaluate_model_at(task: str, model: nn.Module, batches: Iterable[dict], thresholds: Sequence[float],
                      device: str | torch.device = "cpu", spec: PatternSpec | None = None,
                      mixed_precision: bool = True, radius_px: float = MATCH_RADIUS_PX, progress: bool = False,
                      marker_ids: np.ndarray | None = None) -> dict[float, dict]:
    """`evaluate_model` at each of `thresholds` (presence or visibility probability) from one pass of the
    network over `batches`: {threshold: metrics}.  A module reader (`networks.tasks.reads_modules`) needs
    `spec`: its targets and decoded IDs come from the pattern's codebook.  marker_ids: a recognizer
    answers among these IDs only (a garment's, as the Detector restricts it), else among all it knows."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}: expected one of {', '.join(TASKS)}")
    if not thresholds or not all(0 < t < 1 for t in thresholds):
        raise ValueError(f"thresholds must be a non-empty list of values in (0, 1), got {list(thresholds)}")
    device = torch.device(device)
    codes, decoder = None, None
    if task == "recognizer" and reads_modules(model):
        if spec is None:
            raise ValueError("evaluate_model: a module-reading recognizer needs the pattern (spec) to decode IDs")
        codebook = generate_codebook(spec)
        codes, decoder = module_targets(codebook).to(device), CodeDecoder(codebook, marker_ids, device=device)
    candidates = None if decoder is not None or marker_ids is None else \
        torch.as_tensor(np.asarray(marker_ids, dtype=np.int64))
    was_training = model.training
    model.eval()
    results = {t: _Results(task, spec, radius_px, t, model_crop(model), decoder, candidates) for t in thresholds}
    try:
        for batch in tqdm(batches, desc=f"evaluate {task}", unit="batch", disable=not progress, leave=False):
            with autocast(device, mixed_precision):
                output, loss, parts = forward(task, model, batch, device, codes=codes)
            for result in results.values():
                result.update(output, loss, parts, batch)
    finally:
        model.train(was_training)
    return {t: result.result() for t, result in results.items()}


def evaluate(checkpoint: str | Path, data: str | Path, split: str = "test", task: str | None = None,
             device: str | torch.device | None = None, batch_size: int = 32, radius_px: float = MATCH_RADIUS_PX,
             threshold: float = 0.5, progress: bool = True, garment_ids: bool = False) -> dict:
    """Evaluate the checkpoint on `split` of the factory dataset folder `data`, or on every item of a
    shard folder of synthesized samples (`networks.shards write`; `split` is then "shards"); a dict of
    metrics with the checkpoint's task, step and the data it was measured on.  garment_ids: a
    recognizer answers among the IDs printed on the dataset's garment (its template.npz), as the
    Detector restricts it to the garment it is given."""
    return evaluate_at(checkpoint, data, [threshold], split, task, device, batch_size, radius_px, progress,
                       garment_ids)[threshold]


def evaluate_at(checkpoint: str | Path, data: str | Path, thresholds: Sequence[float], split: str = "test",
                task: str | None = None, device: str | torch.device | None = None, batch_size: int = 32,
                radius_px: float = MATCH_RADIUS_PX, progress: bool = True, garment_ids: bool = False
                ) -> dict[float, dict]:
    """`evaluate` at each of `thresholds`, the network run once: {threshold: metrics}."""
    device = resolve_device(device)
    model, config, saved = load_checkpoint(checkpoint, expected_task=task, device=device)
    spec = checkpoint_spec(saved)
    if (Path(data) / "template.npz").is_file():
        check_pattern(saved, dataset_spec(data), source=f"{checkpoint} against the dataset {data}")
    batches = data_batches(config.task, data, split, spec, batch_size, model_crop(model))
    if (Path(data) / SHARD_META).is_file():
        split = "shards"
    marker_ids = None
    if garment_ids:
        if config.task != "recognizer" or not (Path(data) / "template.npz").is_file():
            raise ValueError(f"{data}: garment IDs restrict a recognizer on a factory dataset folder with a "
                             f"template.npz (here a {config.task} checkpoint)")
        marker_ids = garment_marker_ids(data)
    metrics = evaluate_model_at(config.task, model, batches, thresholds, device, spec, config.mixed_precision,
                                radius_px, progress, marker_ids)
    return {t: {"task": config.task, "checkpoint": str(checkpoint), "step": int(saved["step"]), "data": str(data),
                "split": split, "garment_ids": marker_ids is not None, **m} for t, m in metrics.items()}


def format_table(metrics: dict) -> str:
    """The metrics as a two-column text table (nested keys joined by dots)."""
    rows: list[tuple[str, str]] = []

    def walk(prefix: str, value: object) -> None:
        if isinstance(value, dict):
            for key, item in value.items():
                walk(f"{prefix}.{key}" if prefix else str(key), item)
        elif isinstance(value, float):
            rows.append((prefix, f"{value:.4g}"))
        else:
            rows.append((prefix, "-" if value is None else str(value)))

    walk("", metrics)
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def main(argv: list[str] | None = None) -> int:
    from assets.cli import add_device, add_progress, progress, run_cli

    parser = argparse.ArgumentParser(prog="python -m networks.evaluate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task", choices=TASKS, help="which network the checkpoint holds")
    parser.add_argument("--checkpoint", type=Path, required=True, help="a checkpoint of networks.train (best.pt)")
    parser.add_argument("--data", type=Path, required=True, help="a factory dataset folder (manifest.jsonl), or "
                        "a shard folder of synthesized samples (shards.json; every item, no --split)")
    parser.add_argument("--split", default="test", help="train, val, test or all (default test)")
    add_device(parser)
    parser.add_argument("--batch-size", type=int, default=32, help="crops per batch (localizer: one image)")
    parser.add_argument("--radius", type=float, default=MATCH_RADIUS_PX,
                        help="localizer: match radius between predicted and true centres, pixels")
    parser.add_argument("--threshold", type=float, default=0.5, help="presence / visibility probability threshold")
    parser.add_argument("--garment-ids", action="store_true", help="recognizer: answer among the IDs printed on the "
                        "dataset's garment (its template.npz), as the Detector does for the garment it is given")
    parser.add_argument("--json", type=Path, help="where to write the metrics (default: beside the checkpoint, "
                                                  "eval_<task>_<split>.json)")
    add_progress(parser)
    args = parser.parse_args(argv)

    def action() -> None:
        if args.batch_size < 1 or not 0 < args.threshold < 1 or not args.radius > 0:
            raise ValueError("--batch-size must be >= 1, --threshold in (0, 1), --radius > 0")
        metrics = evaluate(args.checkpoint, args.data, args.split, args.task, args.device, args.batch_size,
                           args.radius, args.threshold, progress(args), garment_ids=args.garment_ids)
        out = args.json or args.checkpoint.with_name(f"eval_{args.task}_{args.split}.json")
        save_json(out, metrics)
        print(format_table(metrics))
        print(f"metrics written to {out}")

    return run_cli(action)


if __name__ == "__main__":
    sys.exit(main())
