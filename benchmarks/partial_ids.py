"""How well does the Marker Recognizer read partial markers?  Its top-1 given the true five points, for
markers with all five points visible against partial ones (the others of
`assets.pattern.observation.recognizer_markers(partial=True)`: centre visible, a point hidden, a sane
crop of five points on the fabric), on a rendered dataset's held-out images and/or a capture's views.
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

from assets.pattern.observation import ImageGroundTruth, recognizer_markers  # noqa: E402
from networks.detector import Detector  # noqa: E402


GROUPS = ("all five points visible", "partial: centre visible, a point hidden")


def groups(gt: ImageGroundTruth, spec) -> dict[str, np.ndarray]:
    """Per group, (M,) bool over `gt`'s markers: whole markers, and the partial ones the recognizer
    trains on with `recognizer_partial` (`recognizer_markers`)."""
    taken = np.zeros(len(gt.marker_id), bool)
    taken[recognizer_markers(gt, spec, partial=True)] = True
    whole = gt.point_visible.all(axis=1)
    return dict(zip(GROUPS, (taken & whole, taken & ~whole)))


def top1(detector: Detector, pairs: list[tuple[Path, Path]]) -> dict[str, dict]:
    counts = {name: [0, 0] for name in GROUPS}
    for image_path, gt_path in pairs:
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        gt = ImageGroundTruth.load(gt_path)
        for name, mask in groups(gt, detector.spec).items():
            pick = np.flatnonzero(mask)
            if len(pick):
                points = gt.points_px[pick].astype(np.float64)
                ids, _ = detector.recognize([image], np.zeros(len(pick), np.int64), points)
                counts[name][0] += len(pick)
                counts[name][1] += int((ids == gt.marker_id[pick]).sum())
    return {name: {"markers": n, "top1": right / max(n, 1)} for name, (n, right) in counts.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoints", nargs=3, type=Path, required=True, metavar=("LOC", "REC", "XP"),
                        help="the Detector's three checkpoints (only the recognizer runs)")
    parser.add_argument("--rendered", type=Path, help="a factory dataset folder (its validation and test images)")
    parser.add_argument("--capture", type=Path, help="a capture folder")
    parser.add_argument("--frames", default="", help="only these capture frames (comma-separated stems, e.g. f000120)")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args(argv)
    from assets.garments import load_template  # needs triangle: here only, so top1 runs on the GPU machine

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from vote_settings import images_and_truth

    if not (args.rendered or args.capture):
        parser.error("give --rendered and/or --capture")
    sources = {}
    for label, rendered, capture in (("renders, held out", args.rendered, None), ("capture", None, args.capture)):
        if rendered is None and capture is None:
            continue
        pairs, template = images_and_truth(rendered, capture)
        if capture is not None and args.frames:
            wanted = set(args.frames.split(","))
            pairs = [p for p in pairs if p[0].stem in wanted]
        detector = Detector.from_checkpoints(*args.checkpoints, device=args.device,
                                             tables=load_template(template).layout.tables())
        sources[f"{label} ({len(pairs)} images)"] = top1(detector, pairs)
    print(f"# recognizer top-1 given the true points, {args.checkpoints[1].name}")
    print("| images | markers | count | top-1 |\n|---|---|---|---|")
    for source, rows in sources.items():
        for name, r in rows.items():
            print(f"| {source} | {name} | {r['markers']} | {r['top1']:.3f} |")
    print("RESULT " + json.dumps(sources))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
