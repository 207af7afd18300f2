"""The Detector's ID votes on its own outputs: IDs identified with each `vote_min_partial` (the votes a
marker that is not fully observed needs before its neighbours' ID replaces the recognizer's),
side by side on the same localized and recognized markers.  `benchmarks/id_votes.py` measures the
votes on the ground truth with simulated errors; this measures them where the errors are the
networks' own.

    python benchmarks/vote_settings.py --checkpoints loc.pt rec.pt xp.pt --capture .bench/cap8/capture \
        --localizer-scale 0.3 [--values 4,3,2]
    python benchmarks/vote_settings.py --checkpoints loc.pt rec.pt xp.pt --rendered .bench/rendered2

A ground-truth marker is found when a localized centre lies within --radius px of its centre (12 px
for 1080p captures, 4 px on 512 px renders), identified when that marker's ID after the votes is its
own.  Held-out images of a rendered dataset (validation and test), every view of a capture.  CPU or
GPU; the crosspoint network is not run.  Prints a table and a `RESULT {json}` line.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from assets.cli import localizer_scale_arg  # noqa: E402
from assets.garments import load_template  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.detector import Detector, DetectorConfig, usable_points  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
from capture_detections import match_markers  # noqa: E402
from foreshortening import HELDOUT, capture_pairs, rendered_pairs  # noqa: E402


def images_and_truth(rendered: Path | None, capture: Path | None) -> tuple[list[tuple[Path, Path]], Path]:
    """(image, ground truth) pairs and the template of a rendered dataset's held-out split or a capture."""
    if rendered is not None:
        return rendered_pairs(rendered, HELDOUT), rendered / "template.npz"
    return capture_pairs(capture), capture / "template.npz"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoints", nargs=3, type=Path, required=True, metavar=("LOC", "REC", "XP"))
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--rendered", type=Path, help="a factory dataset folder (its validation and test images)")
    source.add_argument("--capture", type=Path, help="a capture folder (every view)")
    parser.add_argument("--localizer-scale", type=localizer_scale_arg, default="auto",
                        help="a number, or 'auto' (chosen per image, the default)")
    parser.add_argument("--values", default="4,3,2", help="vote_min_partial values, the first the baseline")
    parser.add_argument("--radius", type=float, help="match radius px (default 4 on renders, 12 on a capture)")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    pairs, template = images_and_truth(args.rendered, args.capture)
    if not pairs:
        parser.error("no images with ground truth found")
    radius = args.radius or (4.0 if args.rendered else 12.0)
    detector = Detector.from_checkpoints(*args.checkpoints, device=args.device,
                                         tables=load_template(template).layout.tables(),
                                         config=DetectorConfig(localizer_scale=args.localizer_scale))
    located = []
    for image_path, gt_path in pairs:
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        (points, _), = detector.localize([image])
        points = points.astype(np.float64)
        points = points[usable_points(detector.spec, points)]
        index = np.zeros(len(points), np.int64)
        ids, _ = detector.recognize([image], index, points)
        located.append((image, ImageGroundTruth.load(gt_path), points, index, ids))
    rows = []
    for value in (int(v) for v in args.values.split(",")):
        detector.config = replace(detector.config, vote_min_partial=value)
        counts = np.zeros((2, 2))
        found = right_total = 0
        for image, gt, points, index, ids in located:
            voted, _ = detector.vote([image], index, points, ids) if len(points) else (ids, None)
            hit, right = match_markers(gt, points[:, 0], voted, radius)
            for k, mask in enumerate((gt.status == 2, (gt.status == 1) & gt.point_visible[:, 0])):
                counts[k] += [mask.sum(), (right & mask).sum()]
            found += int(hit.sum())
            right_total += int(right.sum())
        rows.append({"vote_min_partial": value, "fully_visible_identified": counts[0, 1] / max(counts[0, 0], 1),
                     "partial_identified": counts[1, 1] / max(counts[1, 0], 1),
                     "right_share_of_found": right_total / max(found, 1), "found": found})
    print(f"# ID votes on the Detector's outputs, {len(pairs)} images of {args.rendered or args.capture}")
    print("| vote_min_partial | fully visible markers identified | partial (centre visible) identified "
          "| right IDs among found markers |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['vote_min_partial']} | {r['fully_visible_identified']:.3f} | {r['partial_identified']:.3f} | "
              f"{r['right_share_of_found']:.3f} of {r['found']} |")
    print("RESULT " + json.dumps({"images": len(pairs), "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
