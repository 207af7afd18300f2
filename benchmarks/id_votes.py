"""The Detector's ID votes (`networks.neighbours.vote_ids`) on a factory dataset's ground truth, against
keeping the recognizer's IDs (the baseline), under the errors the chained networks make.

For every image of the dataset (Blender renders with exact ground truth), the markers that show are
taken with their true five points moved by Gaussian noise (`--point-noise` px per coordinate: the
localizer's error; 1.0 px gives a median point error of 1.18 px, the corners' 1.16 to 1.27 px of the
fourth GPU run, RESULTS.md) and a share of their IDs (`--error-rates`) replaced by IDs drawn from the
garment (the recognizer's mistakes: 0.26 is the chained Detector's measured rate on fully visible
markers, 0.35 on all).  Markers whose noisy points are fully observed (`networks.detector.fully_observed`
at the Detector's cut threshold) vote, as in the Detector.  Reports the ID accuracy without and with
votes, on all markers and on the fully observed ones, how many wrong IDs were put right and right
ones made wrong, and how many IDs are still wrong among the markers whose final ID has a neighbour's
vote (`Detections.id_support` >= 1) and among those with none, per error rate; 3 noise draws each.

    python benchmarks/id_votes.py --data .bench/rendered [--error-rates 0,0.1,0.26,0.35,0.5]

Prints a table and a `RESULT {json}` line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from assets.pattern import generate_codebook  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.data import dataset_spec  # noqa: E402
from networks.detector import DetectorConfig, fully_observed  # noqa: E402
from networks.evaluate import read_manifest, split_entries  # noqa: E402
from networks.evaluate_detector import garment_tables  # noqa: E402
from networks.neighbours import MarkerLayout, vote_ids  # noqa: E402

DRAWS = 3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="a factory dataset folder with gt/ and template.npz")
    parser.add_argument("--split", default="all", help="a split of the dataset, or all (default)")
    parser.add_argument("--error-rates", default="0,0.1,0.26,0.35,0.5")
    parser.add_argument("--point-noise", type=float, default=1.0, help="px, standard deviation per coordinate")
    args = parser.parse_args()
    spec = dataset_spec(args.data)
    codebook = generate_codebook(spec)
    tables = garment_tables(args.data, codebook)
    if tables is None:
        sys.exit(f"{args.data}: no template.npz, so no garment layout to vote on")
    layout = MarkerLayout.from_tables(tables, len(codebook))
    garment = np.flatnonzero(layout.table_of_id >= 0)
    config = DetectorConfig()
    entries = read_manifest(args.data) if args.split == "all" else split_entries(args.data, args.split)
    truth = []
    for entry in entries:
        gt = ImageGroundTruth.load(args.data / entry["gt"])
        shown = (gt.status > 0) & np.isfinite(gt.points_px).all(axis=(1, 2))
        truth.append((gt.points_px[shown].astype(np.float64), gt.marker_id[shown].astype(np.int64),
                      (gt.width, gt.height)))
    rows = []
    started = time.perf_counter()
    for rate in (float(r) for r in args.error_rates.split(",")):
        count = {k: 0 for k in ("markers", "full", "wrong", "wrong_full", "right_after", "right_after_full",
                                "fixed", "broken", "supported", "supported_wrong", "unsupported_wrong")}
        for draw in range(DRAWS):
            rng = np.random.default_rng([draw, int(rate * 1000)])
            for points, ids, size in truth:
                noisy = points + rng.normal(0.0, args.point_noise, points.shape)
                wrong = rng.random(len(ids)) < rate
                read = ids.copy()
                read[wrong] = rng.choice(garment, int(wrong.sum()))
                wrong = read != ids  # a draw may hit the true ID
                full = fully_observed(spec, noisy, size, config.max_layout_residual_cells)
                voted, support = vote_ids(layout, spec, read, noisy, full, config.vote_min, config.vote_min_partial,
                                    config.vote_tolerance)
                right = voted == ids
                count["markers"] += len(ids)
                count["full"] += int(full.sum())
                count["wrong"] += int(wrong.sum())
                count["wrong_full"] += int((wrong & full).sum())
                count["right_after"] += int(right.sum())
                count["right_after_full"] += int((right & full).sum())
                count["fixed"] += int((wrong & right).sum())
                count["broken"] += int((~wrong & ~right).sum())
                count["supported"] += int((support > 0).sum())
                count["supported_wrong"] += int(((support > 0) & ~right).sum())
                count["unsupported_wrong"] += int(((support == 0) & ~right).sum())
        rows.append({"error_rate": rate, **count,
                     "accuracy_before": 1 - count["wrong"] / count["markers"],
                     "accuracy_after": count["right_after"] / count["markers"],
                     "accuracy_before_full": 1 - count["wrong_full"] / count["full"],
                     "accuracy_after_full": count["right_after_full"] / count["full"]})
    result = {"date": time.strftime("%Y-%m-%d"), "data": str(args.data), "images": len(truth),
              "markers_per_draw": sum(len(t[1]) for t in truth), "draws": DRAWS, "point_noise_px": args.point_noise,
              "config": {"vote_min": config.vote_min, "vote_min_partial": config.vote_min_partial,
                         "vote_tolerance": config.vote_tolerance,
                         "max_layout_residual_cells": config.max_layout_residual_cells},
              "seconds": time.perf_counter() - started, "rows": rows}
    print(f"# ID votes, {result['date']}, {args.data}: {len(truth)} images, {result['markers_per_draw']} markers, "
          f"{DRAWS} draws, points moved by {args.point_noise} px, {result['seconds']:.1f} s")
    print("\n| IDs replaced | ID accuracy, recognizer's IDs (baseline): all / fully observed | with votes: all / "
          "fully observed | wrong IDs put right | right IDs made wrong | wrong after votes: with support >= 1 "
          "/ with support 0 |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['error_rate']:.0%} | {r['accuracy_before']:.3f} / {r['accuracy_before_full']:.3f} | "
              f"{r['accuracy_after']:.3f} / {r['accuracy_after_full']:.3f} | {r['fixed']} of {r['wrong']} | "
              f"{r['broken']} of {r['markers'] - r['wrong']} | {r['supported_wrong']} of {r['supported']} / "
              f"{r['unsupported_wrong']} of {r['markers'] - r['supported']} |")
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
