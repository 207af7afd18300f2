"""How well does the Marker Recognizer read partial markers?  Its top-1 given the true five points, for
markers with all five points visible against partial ones (the others of
`assets.pattern.observation.recognizer_markers(partial=True)`: centre visible, a point hidden, a sane
crop of five points in front of the camera, a point off the fabric completed from the marker's
crosspoints, `completed_points`), on a rendered dataset's held-out images and/or a capture's views.
The localizer and the votes take no part: this isolates the recognizer, whose training crops are whole
markers only unless it was trained with `TrainConfig.recognizer_partial`.

    python benchmarks/partial_ids.py --checkpoints loc.pt recognizer_jitter.pt xp.pt --rendered .bench/rendered2 \
        [--capture .bench/cap8/capture --frames f000120]

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
import torch  # noqa: E402

from assets.cli import localizer_scale_arg  # noqa: E402
from assets.pattern.observation import ImageGroundTruth, completed_points, recognizer_markers  # noqa: E402
from networks.detector import Detector, DetectorConfig  # noqa: E402
from networks.homography import layout_residual  # noqa: E402


GROUPS = ("all five points visible", "partial: centre visible, a point hidden")


def groups(gt: ImageGroundTruth, spec, completed: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per group, (M,) bool over `gt`'s markers: whole markers, and the partial ones the recognizer
    trains on with `recognizer_partial` (`recognizer_markers`; completed: `completed_points(gt)`)."""
    taken = np.zeros(len(gt.marker_id), bool)
    taken[recognizer_markers(gt, spec, True, completed)] = True
    whole = gt.point_visible.all(axis=1)
    return dict(zip(GROUPS, (taken & whole, taken & ~whole)))


#: marker size bins, px (`foreshortening.marker_shape`: the square root of its area in the image)
SIZES = (0.0, 12.0, 16.0, 24.0, 32.0, np.inf)


def size_bin(low: float, high: float) -> str:
    return f"size {low:.0f}-{high:.0f} px" if np.isfinite(high) else f"size >= {low:.0f} px"


def recognized(detector: Detector, pairs: list[tuple[Path, Path]]) -> list[tuple]:
    """Per image and group (`GROUPS`) that has markers: (image path, group, right (K,) bool: the
    recognizer's ID given the true points is the marker's, size (K,) px: the marker's in the image,
    residual (K,) cells: its five points off a homography (`layout_residual`), visible (K,): the share
    of its crosspoints visible in the image)."""
    from foreshortening import marker_shape  # benchmarks/, on the path from main and networks.py

    records = []
    for image_path, gt_path in pairs:
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        gt = ImageGroundTruth.load(gt_path)
        completed = completed_points(gt)  # what the crops are cut from (a point off the fabric completed)
        for name, mask in groups(gt, detector.spec, completed).items():
            pick = np.flatnonzero(mask)
            if len(pick):
                points = completed[pick].astype(np.float64)
                ids, _ = detector.recognize([image], np.zeros(len(pick), np.int64), points)
                # crops' points are finite: every marker has a size
                records.append((image_path, name, ids == gt.marker_id[pick], marker_shape(points)[1],
                                layout_residual(detector.spec, points),
                                gt.crosspoint_visible[pick].reshape(len(pick), -1).mean(axis=1)))
    return records


def tally(records: list[tuple[Path, str, np.ndarray, np.ndarray]]) -> tuple[dict[str, dict], dict[str, dict]]:
    """Per group, markers and top-1 of `recognized`'s records; and the same per group and marker size
    (`SIZES`): the recognizer's misses by how large the marker is in the image."""
    counts = {name: [0, 0] for name in GROUPS}
    bins = {(name, size_bin(lo, hi)): [0, 0] for name in GROUPS for lo, hi in zip(SIZES[:-1], SIZES[1:])}
    for _, name, right, size, *_ in records:
        counts[name][0] += len(right)
        counts[name][1] += int(right.sum())
        which = np.digitize(size, SIZES[1:-1])
        for k, (lo, hi) in enumerate(zip(SIZES[:-1], SIZES[1:])):
            bins[name, size_bin(lo, hi)][0] += int((which == k).sum())
            bins[name, size_bin(lo, hi)][1] += int(right[which == k].sum())
    by_size: dict[str, dict] = {name: {} for name in GROUPS}
    for (name, label), (n, right) in bins.items():
        if n:
            by_size[name][label] = {"markers": n, "top1": right / n}
    return {name: {"markers": n, "top1": right / max(n, 1)} for name, (n, right) in counts.items()}, by_size


#: bins of how far a marker's five points are off a homography, cells (`networks.homography.layout_residual`)
RESIDUALS = (0.0, 1.0, 2.0, 4.0, np.inf)
#: bins of the share of a whole marker's crosspoints visible in the image (a fold, the body or the
#: garment's edge hides the rest although its five points show): under 80%, 80-95%, 95% and more but
#: not all, and `EVERY_CROSSPOINT`
VISIBLE_SHARES = (0.0, 0.8, 0.95, 1.0)
EVERY_CROSSPOINT = "every crosspoint visible"


def _whole(records: list[tuple], column: int) -> tuple[np.ndarray, np.ndarray]:
    """`recognized`'s whole markers (all five points visible): right (K,) and the record's `column` (K,)."""
    rows = [r for r in records if r[1] == GROUPS[0]]
    return (np.concatenate([r[2] for r in rows] or [np.zeros(0, bool)]),
            np.concatenate([r[column] for r in rows] or [np.zeros(0)]))


def _binned(right: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, dict]:
    return {label: {"markers": int(mask.sum()), "top1": float(right[mask].mean())}
            for label, mask in masks.items() if mask.any()}


def by_residual(records: list[tuple]) -> dict[str, dict]:
    """Markers and top-1 of `recognized`'s whole markers (all five points visible) by their layout
    residual (`RESIDUALS`): the crop homography's misfit, which curved cloth makes."""
    right, residual = _whole(records, 4)
    which = np.digitize(residual, RESIDUALS[1:-1])
    return _binned(right, {(f"residual {lo:g}-{hi:g} cells" if np.isfinite(hi) else f"residual >= {lo:g} cells"):
                           which == k for k, (lo, hi) in enumerate(zip(RESIDUALS[:-1], RESIDUALS[1:]))})


def by_visible(records: list[tuple]) -> dict[str, dict]:
    """Markers and top-1 of `recognized`'s whole markers by the share of their crosspoints visible
    (`VISIBLE_SHARES`, and `EVERY_CROSSPOINT`): a marker whose five points show can still lie partly
    under a fold, and its crop then shows a part of its code or none."""
    right, share = _whole(records, 5)
    masks = {f"{lo:.0%}-{hi:.0%} of its crosspoints visible" + (" (not all)" if hi == 1.0 else ""):
             (share >= lo) & (share < hi) for lo, hi in zip(VISIBLE_SHARES[:-1], VISIBLE_SHARES[1:])}
    return _binned(right, {**masks, EVERY_CROSSPOINT: share >= 1.0})


def top1(detector: Detector, pairs: list[tuple[Path, Path]]) -> dict[str, dict]:
    """The recognizer's top-1 given the true points: {"groups": per group, "by_size": per group and
    marker size (`tally`), "by_visible": whole markers by the share of their crosspoints visible,
    "by_residual": by their layout residual} of `recognized`'s records."""
    records = recognized(detector, pairs)
    groups, by_size = tally(records)
    return {"groups": groups, "by_size": by_size, "by_visible": by_visible(records), "by_residual": by_residual(records)}


#: the chain's groups: the two above, and partial markers with a visible centre whose five points do
#: not give a sane crop (folded, seen edge-on, behind the camera, or cut with too little of it on the
#: fabric to complete: the recognizer never trains on them)
CHAIN_GROUPS = GROUPS + ("partial: centre visible, no sane crop",)


def chain(detector: Detector, pairs: list[tuple[Path, Path]], radius: float) -> dict[str, dict]:
    """Where the chain loses markers: per group (`CHAIN_GROUPS`), the share the localizer finds (a
    localized centre within `radius` px, `capture_detections.match_markers`), and the share identified
    on the localizer's own points by the recognizer alone, and after the neighbours' ID votes."""
    from capture_detections import match_markers  # benchmarks/, on the path from main
    from networks.detector import usable_points

    counts = {name: np.zeros(4, np.int64) for name in CHAIN_GROUPS}  # markers, found, right alone, right voted
    for image_path, gt_path in pairs:
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        gt = ImageGroundTruth.load(gt_path)
        (points, _), = detector.localize([image])
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
    parser.add_argument("--checkpoints", nargs=3, type=Path, required=True, metavar=("LOC", "REC", "XP"),
                        help="the Detector's three checkpoints (only the recognizer runs)")
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
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args(argv)
    from assets.garments import load_template  # needs triangle: here only, so top1 runs on the GPU machine

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from foreshortening import rendered_pairs
    from vote_settings import images_and_truth

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
        detector = Detector.from_checkpoints(*args.checkpoints, device=args.device,
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
    print(f"# recognizer top-1 given the true points, {args.checkpoints[1].name}")
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
        print(f"\n# the chain: {', '.join(p.name for p in args.checkpoints)}")
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
