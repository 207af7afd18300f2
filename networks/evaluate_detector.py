"""Evaluate the whole `networks.Detector` (the three networks chained) on a split of a factory dataset.

    python -m networks.evaluate_detector --localizer runs/loc/best.pt --recognizer runs/rec/best.pt \\
        --crosspoints runs/xp/best.pt --data out/ds --split test --json detector_test.json

Where `networks.evaluate` scores each network alone on ground-truth crops, this runs the Detector on
every image of the split, as reconstruction does, and compares its `Detections` with the image's
`ImageGroundTruth` (`gt/<name>.npz`); see `networks.metrics.detector_metrics` for the definitions:
  markers        precision / recall / F1 over the markers present in the image (status > 0, centre
                 visible; a detection matches one whose centre is within --radius pixels), recall
                 over the fully visible ones; a detection of a shown marker whose centre is hidden
                 is neither a true nor a false positive (on_hidden), nor is one with the ID of a
                 shown marker whose crosspoints it lies on (by_id: a marker cut by the garment's
                 edge has no centre on the fabric to match);
  id_accuracy    matched detections with the true ID, over all and over fully visible markers;
  partial        matched fully / partly visible markers that the Detector flagged partial (cut);
  point_error_px median and 95th percentile error of each of the five points of the matched fully
                 visible markers, over all of them and over those not flagged partial;
  crosspoints    for matches with the true ID: visibility precision / recall per crosspoint and the
                 image error of the crosspoints visible in the truth and in the detections;
  layout_residual_cells  how far five points of a fully visible marker miss a homography of its
                 layout (`networks.homography.layout_residual`), for the Marker Localizer's own
                 points (before cut markers are re-estimated from neighbours) and for the ground
                 truth's, against the Detector's `max_layout_residual_cells` (above it: "cut").
When the dataset has template.npz, the Detector gets the garment's marker tables (IDs restricted to
the garment, cut markers completed from their neighbours), as reconstruction's networks mode does.
"seconds" is the time spent in the Detector.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np
import torch
from tqdm import tqdm

from assets.cli import (add_completion_options, add_crosspoint_options, completion_options, crosspoint_options,
                        localizer_scale_arg)
from assets.fileio import save_json
from assets.pattern import MarkerTable, PatternSpec
from assets.pattern.observation import ImageGroundTruth
from networks.data import _layout as read_layout
from networks.data import _read_png as read_png
from networks.detector import Detector, DetectorConfig
from networks.evaluate import format_table, resolve_device, split_entries
from networks.metrics import MATCH_RADIUS_PX, detector_metrics, match_detections


def garment_tables(data: str | Path, codebook: np.ndarray) -> list[MarkerTable] | None:
    """The garment's marker tables (one per panel) from a factory dataset folder's template.npz, built
    with `codebook` as `assets.garments.SheetLayout.tables` builds them, but from layout_json alone
    (without assets.garments and its mesh dependencies); None when the folder has no template.npz."""
    path = Path(data) / "template.npz"
    if not path.is_file():
        return None
    layout = read_layout(data)
    try:
        panels = [(PatternSpec.from_dict(p["spec"], source=f"{path}:layout_json.panels[{i}].spec"), int(p["first_id"]))
                  for i, p in enumerate(layout["panels"])]
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: layout_json.panels lacks spec or first_id ({exc!r})") from exc
    if not panels:
        raise ValueError(f"{path}: layout_json has no panels")
    return [MarkerTable.build(spec, codebook, first_id) for spec, first_id in panels]


def load_detector(localizer: str | Path, recognizer: str | Path, crosspoints: str | Path, data: str | Path,
                  device: str | torch.device | None = None, config: DetectorConfig = DetectorConfig(),
                  batch_size: int = 64) -> Detector:
    """The Detector of three checkpoints, with the tables of the dataset's garment when it has one."""
    detector = Detector.from_checkpoints(localizer, recognizer, crosspoints, device=resolve_device(device),
                                         batch_size=batch_size, config=config)
    tables = garment_tables(data, detector.codebook)
    if tables is None:
        return detector
    return Detector(detector.localizer, detector.recognizer, detector.crosspoints, detector.spec,
                    device=detector.device, batch_size=batch_size, tables=tables, config=config,
                    codebook=detector.codebook)


def evaluate_images(detector: Detector, pairs: Iterable[tuple[np.ndarray, ImageGroundTruth]],
                    radius_px: float = MATCH_RADIUS_PX) -> dict:
    """Run `detector` on each (image (H, W, 3) uint8, its ground truth) of `pairs`, one image at a
    time, and pool `networks.metrics.match_detections` over them.

    Returns the dict of `networks.metrics.detector_metrics` with "radius_px", "tables" (whether the
    Detector knows the garment), "presence_threshold" (the localizer's), "seconds" (in the Detector),
    "seconds_per_image", "localizer_scale" (the configured one and the median, min and max chosen, with
    "per_image" the scale of each image) and "stage_seconds" (per stage of the Detector, summed over the
    images, `networks.detector.DetectorResult.stage_seconds`) added."""
    records, seconds, scales, stages = [], 0.0, [], {}
    for image, gt in pairs:
        start = time.perf_counter()
        found = detector.detect([image])
        seconds += time.perf_counter() - start
        scales += found.localizer_scales
        stages = {stage: stages.get(stage, 0.0) + s for stage, s in found.stage_seconds.items()}
        # the localizer's own points: those the cut test saw
        records.append(match_detections(found.detections[0], gt, detector.spec, radius_px, found.located[0][0]))
    metrics = detector_metrics(records, detector.config.max_layout_residual_cells)
    return {"radius_px": float(radius_px), "tables": detector.layout is not None,
            "presence_threshold": detector.config.presence_threshold, **metrics, "seconds": seconds,
            "seconds_per_image": seconds / len(records),
            "localizer_scale": {"config": detector.config.localizer_scale, "median": float(np.median(scales)),
                                "min": min(scales), "max": max(scales), "per_image": scales},
            "stage_seconds": stages}


def evaluate_detector(detector: Detector, data: str | Path, split: str = "test", progress: bool = True,
                      limit: int | None = None, radius_px: float = MATCH_RADIUS_PX) -> dict:
    """`evaluate_images` on the images of `split` of the factory dataset folder `data` (the first
    `limit` only, when given), with "data" and "split" added."""
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be >= 1 or None, got {limit}")
    root = Path(data)
    entries = split_entries(root, split)[:limit]

    def pairs() -> Iterator[tuple[np.ndarray, ImageGroundTruth]]:
        for entry in tqdm(entries, desc="evaluate detector", unit="image", disable=not progress):
            if "gt" not in entry:
                raise ValueError(f"{root / 'manifest.jsonl'}: image {entry['name']} has no 'gt' (ground truth) entry")
            gt = ImageGroundTruth.load(root / entry["gt"])
            image = read_png(root / entry["image"])
            if image.shape[:2] != (gt.height, gt.width):
                raise ValueError(f"{root / entry['image']}: {image.shape[1]} x {image.shape[0]} pixels, its ground "
                                 f"truth {root / entry['gt']} is {gt.width} x {gt.height}")
            yield image, gt

    return {"data": str(root), "split": split, **evaluate_images(detector, pairs(), radius_px)}


def main(argv: list[str] | None = None) -> int:
    from assets.cli import NETWORKS, add_device, add_networks, add_progress, networks_of, progress, run_cli

    parser = argparse.ArgumentParser(prog="python -m networks.evaluate_detector", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_networks(parser, "(required) ")
    parser.add_argument("--data", type=Path, required=True, metavar="DIR", help="a factory dataset folder (manifest.jsonl, gt/)")
    parser.add_argument("--split", default="test", help="train, val or test (default test)")
    parser.add_argument("--limit", type=int, metavar="N", help="evaluate the first N images of the split only")
    add_device(parser)
    parser.add_argument("--localizer-scale", type=localizer_scale_arg, default="auto", metavar="S",
                        help="the localizer sees the image resized by this factor, so markers fall in the "
                             "size range it was trained on (0.5 for markers 32 to 64 px across), or 'auto' "
                             "(the default): chosen per image from a first pass's marker sizes")
    defaults = DetectorConfig()
    parser.add_argument("--max-layout-residual", type=float, default=defaults.max_layout_residual_cells, metavar="CELLS",
                        help="cells (24 per marker side) by which five points may miss a homography of the "
                             "marker's layout before it counts as cut (default %(default)s)")
    add_completion_options(parser, defaults.keep_own_cells, (defaults.neighbour_sigma_sides, defaults.neighbour_degree))
    parser.add_argument("--no-id-votes", action="store_true",
                        help="keep the recognizer's IDs (default: correct them by the neighbours' votes)")
    parser.add_argument("--no-grow", action="store_true",
                        help="do not add the markers the localizer missed next to fully observed ones "
                             "(default: grow them, DetectorConfig.grow_missing)")
    add_crosspoint_options(parser, defaults.smooth_crosspoints_px)
    parser.add_argument("--presence-threshold", type=float, default=defaults.presence_threshold, metavar="P",
                        help="localizer presence probability above which a cell holds a marker centre "
                             "(default %(default)s, the reference's)")
    parser.add_argument("--nms-radius", type=float, metavar="PX",
                        help="localizer pixels within which detected centres are merged (default: the decoder's)")
    parser.add_argument("--batch-size", type=int, default=64, metavar="N", help="marker crops per recognizer / crosspoint batch")
    parser.add_argument("--radius", type=float, default=MATCH_RADIUS_PX, metavar="PX",
                        help="match radius between detected and true marker centres, pixels (default %(default)s)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the metrics to this JSON file")
    add_progress(parser)
    args = parser.parse_args(argv)

    def action() -> None:
        if not args.radius > 0:
            raise ValueError(f"--radius must be > 0, got {args.radius}")
        checkpoints = networks_of(args)
        if not checkpoints:
            raise ValueError("give the three networks: --localizer, --recognizer and --crosspoints")
        split_entries(args.data, args.split)  # a bad folder or split fails before the checkpoints load
        detector = load_detector(*checkpoints, args.data, args.device,
                                 DetectorConfig(localizer_scale=args.localizer_scale, nms_radius_px=args.nms_radius,
                                                presence_threshold=args.presence_threshold,
                                                max_layout_residual_cells=args.max_layout_residual,
                                                **completion_options(args),
                                                vote_ids=not args.no_id_votes, grow_missing=not args.no_grow,
                                                **crosspoint_options(args)),
                                 args.batch_size)
        metrics = evaluate_detector(detector, args.data, args.split, progress(args), args.limit, args.radius)
        metrics = {"checkpoints": dict(zip(NETWORKS, map(str, checkpoints))), **metrics}
        print(format_table(metrics))
        if args.json is not None:
            save_json(args.json, metrics)
            print(f"metrics written to {args.json}")

    return run_cli(action)


if __name__ == "__main__":
    sys.exit(main())
