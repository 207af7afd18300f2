"""How well does the Marker Recognizer read partial markers?  Its top-1 given the true five points, for
markers with all five points visible against partial ones (the others of
`assets.pattern.observation.recognizer_markers(partial=True)`: centre visible, a point hidden, a sane
crop of five points in front of the camera, a point off the fabric completed from the marker's
crosspoints, `completed_points`), on a rendered dataset's held-out images and/or a capture's views
(`networks.recognizer_top1`, which the networks benchmark reports too).
The localizer and the votes take no part: this isolates the recognizer, whose training crops are whole
markers only unless it was trained with `TrainConfig.recognizer_partial`.

    python research/partial_ids.py --localizer loc.pt --recognizer recognizer_jitter.pt --crosspoints xp.pt \
        --rendered .bench/rendered2 [--capture .bench/cap8/capture --frames f000120]

Prints a table and a `RESULT {json}` line.  CPU or GPU.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from assets.cli import add_device, add_networks, localizer_scale_arg, networks_of  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.detector import Detector, DetectorConfig  # noqa: E402
from networks.recognizer_top1 import (GROUPS, by_residual, by_visible, groups, recognized,  # noqa: E402
                                      rendered_pairs, tally)


#: the chain's groups: the two above, and partial markers with a visible centre whose five points do
#: not give a sane crop (folded, seen edge-on, behind the camera, or cut with too little of it on the
#: fabric to complete: the recognizer never trains on them)
CHAIN_GROUPS = GROUPS + ("partial: centre visible, no sane crop",)


def chain(detector: Detector, pairs: list[tuple[Path, Path]], radius: float) -> dict[str, dict]:
    """Where the chain loses markers: per group (`CHAIN_GROUPS`), the share the localizer finds (a
    localized centre within `radius` px, `capture_detections.match_markers`), and the share identified
    on the localizer's own points by the recognizer alone, and after the neighbours' ID votes."""
    from capture_detections import match_markers  # research/, on the path from main
    from networks.detector import usable_points

    counts = {name: np.zeros(4, np.int64) for name in CHAIN_GROUPS}  # markers, found, right alone, right voted
    for image_path, gt_path in pairs:
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        gt = ImageGroundTruth.load(gt_path)
        (points, _), = detector.localize([image])[0]
        points = points.astype(np.float64)
        points = points[usable_points(detector.spec, points)]
        index = np.zeros(len(points), np.int64)
        ids, _ = detector.recognize([image], index, points) if len(points) else (np.zeros(0, np.int64), None)
        voted, _ = detector.vote([image], index, points, ids) if len(points) else (ids, None)
        hit, alone = match_markers(gt, points[:, 0], ids, radius)
        _, after = match_markers(gt, points[:, 0], voted, radius)
        masks = groups(gt, detector.spec)
        masks[CHAIN_GROUPS[2]] = (gt.status > 0) & gt.point_visible[:, 0] & ~gt.point_visible.all(axis=1) & \
            ~masks[GROUPS[1]]
        for name, mask in masks.items():
            counts[name] += [mask.sum(), (hit & mask).sum(), (alone & mask).sum(), (after & mask).sum()]
    return {name: {"markers": int(n), "found": f / max(n, 1), "right_alone": a / max(n, 1),
                   "right_voted": v / max(n, 1)} for name, (n, f, a, v) in counts.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_networks(parser, "(required; only the recognizer runs) ")
    parser.add_argument("--rendered", type=Path, help="a factory dataset folder (its validation and test images)")
    parser.add_argument("--capture", type=Path, help="a capture folder")
    parser.add_argument("--frames", default="", help="only these capture frames (comma-separated stems, e.g. f000120)")
    parser.add_argument("--chain", action="store_true", help="also where the chain loses them: found by the "
                        "localizer, identified on its points alone and after the ID votes")
    parser.add_argument("--localizer-scale", type=localizer_scale_arg, default="auto",
                        help="with --chain: a number, or 'auto' (chosen per image, the default)")
    parser.add_argument("--radius", type=float, help="with --chain: match radius px (default 4 on renders, 12 on a "
                        "capture)")
    parser.add_argument("--every-image", action="store_true", help="--rendered: every image of the folder (a "
                        "held-out set such as the networks benchmark's --extra-heldout), not only its val and test")
    parser.add_argument("--by-motion", action="store_true", help="--rendered: the top-1 per motion too")
    add_device(parser)
    args = parser.parse_args(argv)
    checkpoints = networks_of(args)
    if not checkpoints:
        parser.error("give the three networks: --localizer, --recognizer and --crosspoints")
    from assets.garments import load_template  # needs triangle: imported here only

    sys.path.insert(0, str(ROOT / "research"))
    from foreshortening import images_and_truth

    from networks.evaluate import read_manifest

    if not (args.rendered or args.capture):
        parser.error("give --rendered and/or --capture")
    sources, sizes, chains, motions, residuals, visibles = {}, {}, {}, {}, {}, {}
    for label, rendered, capture in (("renders, held out", args.rendered, None), ("capture", None, args.capture)):
        if rendered is None and capture is None:
            continue
        pairs, template = images_and_truth(rendered, capture)
        if rendered is not None and args.every_image:
            pairs = rendered_pairs(rendered)
        if capture is not None and args.frames:
            wanted = set(args.frames.split(","))
            pairs = [p for p in pairs if p[0].stem in wanted]
        detector = Detector.from_checkpoints(*checkpoints, device=args.device,
                                             tables=load_template(template).layout.tables(),
                                             config=DetectorConfig(localizer_scale=args.localizer_scale))
        source = f"{label} ({len(pairs)} images)"
        records = recognized(detector, pairs)  # once: the motions' tallies are taken from the same records
        sources[source], sizes[source] = tally(records)
        residuals[source] = by_residual(records)
        visibles[source] = by_visible(records)
        if args.chain:
            chains[source] = chain(detector, pairs, args.radius or (4.0 if rendered is not None else 12.0))
        if args.by_motion and rendered is not None:
            motion_of = {rendered / e["image"]: e["motion"] for e in read_manifest(rendered)}
            for motion in sorted({motion_of[image] for image, _ in pairs}):
                motions[motion] = tally([r for r in records if motion_of[r[0]] == motion])[0]
    print(f"# recognizer top-1 given the true points, {Path(checkpoints[1]).name}")
    print("| images | markers | count | top-1 |\n|---|---|---|---|")
    for source, rows in sources.items():
        for name, r in rows.items():
            print(f"| {source} | {name} | {r['markers']} | {r['top1']:.3f} |")
    print("\n# the same by marker size in the image (the square root of its area)")
    print("| images | markers | size | count | top-1 |\n|---|---|---|---|---|")
    for source, rows in sizes.items():
        for name, by_size in rows.items():
            for label, r in by_size.items():
                print(f"| {source} | {name} | {label} | {r['markers']} | {r['top1']:.3f} |")
    print("\n# whole markers by how far their five points are off a homography (curved cloth; layout residual)")
    print("| images | residual | count | top-1 |\n|---|---|---|---|")
    for source, rows in residuals.items():
        for label, r in rows.items():
            print(f"| {source} | {label} | {r['markers']} | {r['top1']:.3f} |")
    print("\n# whole markers by the share of their crosspoints visible (a fold hides the rest)")
    print("| images | crosspoints visible | count | top-1 |\n|---|---|---|---|")
    for source, rows in visibles.items():
        for label, r in rows.items():
            print(f"| {source} | {label} | {r['markers']} | {r['top1']:.3f} |")
    if chains:
        print(f"\n# the chain: {', '.join(Path(p).name for p in checkpoints)}")
        print("| images | markers | count | found | identified, recognizer alone | identified after the votes "
              "|\n|---|---|---|---|---|---|")
        for source, rows in chains.items():
            for name, r in rows.items():
                print(f"| {source} | {name} | {r['markers']} | {r['found']:.3f} | {r['right_alone']:.3f} | "
                      f"{r['right_voted']:.3f} |")
    if motions:
        print("\n# the same per motion (renders)")
        print("| motion | markers | count | top-1 |\n|---|---|---|---|")
        for motion, rows in motions.items():
            for name, r in rows.items():
                print(f"| {motion} | {name} | {r['markers']} | {r['top1']:.3f} |")
    print("RESULT " + json.dumps({"top1": sources, "by_size": sizes, "chain": chains, "by_motion": motions,
                                    "by_residual": residuals, "by_visible": visibles}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
