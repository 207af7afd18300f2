"""Where the Detector loses fully visible markers: every ground-truth marker of status 2 (all five
points and every crosspoint visible) that no detection matches (`networks.metrics.match_detections`,
the same one-to-one match within the radius that `networks.evaluate_detector` counts), with the reason:

  below the presence threshold   the localizer's cell is there at a lower threshold (its probability)
  not localized                  not even at the lower threshold
  localized, points unusable     found at the threshold, dropped by `usable_points` (an unsane crop)
  moved by the completion        found, then its points replaced from its neighbours (the cut test) to
                                 more than the radius away
  taken by another match         a detection within the radius went to another marker

and what the growth from neighbours (`DetectorConfig.grow_missing`) had to work with: how many of its
pattern neighbours were detected with their right ID, and whether its ID was claimed by a detection
elsewhere (growth only places IDs not detected yet).

    python research/chain_misses.py --localizer loc.pt --recognizer rec.pt --crosspoints xp.pt --rendered .bench/rendered_m --split test

Prints a table per reason, one line per miss, and a `RESULT {json}` line.  CPU or GPU.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from assets.cli import add_device, add_networks, localizer_scale_arg, networks_of  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.detector import Detector, DetectorConfig, usable_points  # noqa: E402
from networks.metrics import MATCH_RADIUS_PX, match_markers  # noqa: E402

REASONS = ("below the presence threshold", "not localized", "localized, points unusable",
           "moved by the completion", "taken by another match")


def reason(centre: np.ndarray, located: np.ndarray, usable: np.ndarray, low_centres: np.ndarray,
           low_scores: np.ndarray, detected: np.ndarray, radius: float) -> tuple[str, float | None]:
    """(one of `REASONS`, the presence probability of the nearest low-threshold cell within `radius`
    or None) for a missed marker whose true centre is `centre` (2,): located (L, 5, 2) and usable (L,)
    bool, the localizer's points at the threshold; low_centres (Q, 2), low_scores (Q,) its centres at
    the lower threshold; detected (N, 2), the centres of the Detector's output for the image."""
    def nearest(centres: np.ndarray) -> tuple[int, float]:
        if len(centres) == 0:
            return -1, np.inf
        distance = np.linalg.norm(np.asarray(centres, np.float64).reshape(-1, 2) - centre, axis=1)
        return int(distance.argmin()), float(distance.min())

    j, distance = nearest(low_centres)
    score = float(low_scores[j]) if distance <= radius else None
    k, distance = nearest(located[:, 0])
    if distance > radius:
        return (REASONS[0] if score is not None else REASONS[1]), score
    if not usable[k]:
        return REASONS[2], score
    _, distance = nearest(detected)
    return (REASONS[3] if distance > radius else REASONS[4]), score


def image_misses(detector: Detector, image: np.ndarray, gt: ImageGroundTruth, radius: float,
                 low_threshold: float) -> tuple[list[dict], int]:
    """(one dict per missed fully visible marker: "id", "size_px", "reason", "presence", "right_neighbours"
    (its pattern neighbours detected with their right ID), "neighbours" (on the garment),
    "id_claimed_elsewhere"; the image's fully visible markers).  `detector` knows the garment (tables)."""
    from networks.recognizer_top1 import marker_shape

    found = detector.detect([image])
    (detections,), ((located, _),), scales = found.detections, found.located, found.localizer_scales
    truth = gt.select((gt.status > 0) & gt.point_visible[:, 0])
    full = np.flatnonzero(truth.status == 2)
    d, g = match_markers(detections.points_px[:, 0], truth.points_px[:, 0], radius)
    missed = np.setdiff1d(full, g)
    if len(missed) == 0:
        return [], len(full)
    low = copy.copy(detector)  # the same networks, the localizer decoded at the lower threshold and same scale
    low.config = dataclasses.replace(detector.config, presence_threshold=low_threshold)
    (low_points, low_scores), = low.localize([image], scales)[0]
    usable = usable_points(detector.spec, located.astype(np.float64)) if len(located) else np.zeros(0, bool)
    right = d[detections.marker_id[d] == truth.marker_id[g]]
    right_ids = set(detections.marker_id[right].tolist())
    misses = []
    for m in missed:
        marker_id = int(truth.marker_id[m])
        why, score = reason(truth.points_px[m, 0], located, usable, low_points[:, 0], low_scores,
                            detections.points_px[:, 0], radius)
        neighbours = [n for n in detector.layout.neighbours(np.array([marker_id]))[0].tolist() if n >= 0]
        misses.append({"id": marker_id, "size_px": float(marker_shape(truth.points_px[m:m + 1])[1][0]),
                       "reason": why, "presence": score, "neighbours": len(neighbours),
                       "right_neighbours": sum(n in right_ids for n in neighbours),
                       "id_claimed_elsewhere": bool((detections.marker_id == marker_id).any())})
    return misses, len(full)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_networks(parser, "(required) ")
    parser.add_argument("--rendered", type=Path, required=True, help="a factory dataset folder")
    parser.add_argument("--split", default="test", help="its split (default test)")
    parser.add_argument("--presence-threshold", type=float, default=DetectorConfig.presence_threshold)
    parser.add_argument("--low-threshold", type=float, default=0.05,
                        help="the lower threshold a missed marker's cell is looked for at (default 0.05)")
    parser.add_argument("--localizer-scale", type=localizer_scale_arg, default="auto",
                        help="a number, or 'auto' (chosen per image, the default)")
    parser.add_argument("--radius", type=float, default=MATCH_RADIUS_PX, help="match radius px")
    add_device(parser)
    args = parser.parse_args(argv)
    checkpoints = networks_of(args)
    if not checkpoints:
        parser.error("give the three networks: --localizer, --recognizer and --crosspoints")
    if not 0 < args.low_threshold < args.presence_threshold:
        parser.error(f"--low-threshold must lie in (0, --presence-threshold {args.presence_threshold}), "
                     f"got {args.low_threshold}")
    from networks.data import _read_png as read_png
    from networks.evaluate_detector import load_detector  # the garment's tables from the dataset folder
    from networks.recognizer_top1 import rendered_pairs

    pairs = rendered_pairs(args.rendered, (args.split,))
    if not pairs:
        parser.error(f"{args.rendered}: no images in split {args.split!r}")
    detector = load_detector(*checkpoints, args.rendered, args.device,
                             DetectorConfig(localizer_scale=args.localizer_scale,
                                            presence_threshold=args.presence_threshold))
    if detector.layout is None:
        parser.error(f"{args.rendered}: no template.npz, so no garment layout for the completion and growth")
    rows, total = [], 0
    for image_path, gt_path in tqdm(pairs, desc="chain misses", unit="image"):
        misses, full = image_misses(detector, read_png(image_path), ImageGroundTruth.load(gt_path), args.radius,
                                    args.low_threshold)
        total += full
        rows += [{"image": image_path.name, **miss} for miss in misses]
    counts = Counter(row["reason"] for row in rows)
    print(f"# fully visible markers the chain misses: {len(rows)} of {total} ({args.rendered.name}, "
          f"split {args.split}, presence threshold {args.presence_threshold})")
    print("| reason | misses |\n|---|---|")
    for name in REASONS:
        print(f"| {name} | {counts.get(name, 0)} |")
    print("\n| image | ID | size px | reason | presence | right neighbours / on the garment | ID claimed elsewhere |"
          "\n|---|---|---|---|---|---|---|")
    for row in rows:
        presence = "" if row["presence"] is None else f"{row['presence']:.2f}"
        print(f"| {row['image']} | {row['id']} | {row['size_px']:.1f} | {row['reason']} | {presence} | "
              f"{row['right_neighbours']} / {row['neighbours']} | {'yes' if row['id_claimed_elsewhere'] else ''} |")
    print("RESULT " + json.dumps({"rendered": str(args.rendered), "split": args.split, "full": total,
                                  "presence_threshold": args.presence_threshold, "misses": rows,
                                  "by_reason": {name: counts.get(name, 0) for name in REASONS}}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
