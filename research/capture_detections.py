"""Which markers of a capture does networks-mode reconstruction detect and identify?  The Detector's
saved detections of a `reconstruction run --detections networks` against the capture's ground truth,
by marker status: fully visible, partial with the centre visible (the localizer's target), partial
with the centre hidden (never a localizer target).  Several runs side by side (e.g. two weight sets).

    python research/capture_detections.py --capture .bench/cap/capture \
        --runs seventh=.bench/cap/rec_nets eighth=.bench/cap/rec_nets8 [--radius 12]

A ground-truth marker is found when a detection's centre lies within --radius px of its centre (the
nearest), identified when that detection also has its ID; its visible crosspoints are counted as
recovered when it is identified.  A second table splits the markers whose centre is visible by
foreshortening (`networks.recognizer_top1.marker_shape`'s ratio, from the corners the ground truth
knows), and a third counts per frame the markers (IDs) visible in two or more views and those
identified in two or more, which is what triangulation needs.  Prints the tables and a `RESULT {json}` line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from assets.fileio import load_npz  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.recognizer_top1 import marker_shape  # noqa: E402

KINDS = ("fully visible", "partial, centre visible", "partial, centre hidden")
#: foreshortening bins (ratio of the corners' best-fit affine map's singular values)
BINS = (0.0, 0.3, 0.5, 0.7, 1.0001)


def ratios(points_px: np.ndarray) -> np.ndarray:
    """(M,) foreshortening ratio per marker, NaN where a corner is unknown (as `marker_shape`)."""
    corners = np.asarray(points_px, np.float64)[:, 1:]
    out = np.full(len(corners), np.nan)
    known = np.isfinite(corners).all(axis=(1, 2))
    if known.any():
        out[known] = marker_shape(points_px[known])[0]
    return out


def kinds(gt: ImageGroundTruth) -> dict[str, np.ndarray]:
    centre = gt.point_visible[:, 0]
    partial = gt.status == 1
    return dict(zip(KINDS, (gt.status == 2, partial & centre, partial & ~centre)))


def match_markers(gt: ImageGroundTruth, centres_px: np.ndarray, marker_id: np.ndarray, radius: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(found, identified) (M,) bool per ground-truth marker: a detected centre (N, 2) lies within
    `radius` px of its centre (the nearest detection), and that detection's ID is its own."""
    centres = gt.points_px[:, 0].astype(np.float64)
    known = np.isfinite(centres).all(axis=1)
    hit = np.zeros(gt.num_markers, bool)
    right = np.zeros(gt.num_markers, bool)
    if len(marker_id):
        distance, index = cKDTree(centres_px).query(np.where(known[:, None], centres, -1e9),
                                                    distance_upper_bound=radius)
        hit = np.isfinite(distance) & known
        right = hit & (np.asarray(marker_id)[np.minimum(index, len(marker_id) - 1)] == gt.marker_id)
    return hit, right


def compare(run: Path, capture: Path, radius: float) -> dict[str, dict]:
    files = sorted((run / "detections").glob("cam*/f*.npz"))
    if not files:
        raise FileNotFoundError(f"{run}: no detections/cam*/f*.npz (not a networks-mode reconstruction folder)")
    counts = {kind: np.zeros(5) for kind in KINDS}
    binned = np.zeros((len(BINS) - 1, 3))  # markers with a visible centre and known corners: count, found, identified
    views: dict[str, dict[int, list[int]]] = {}  # frame -> marker ID -> [views visible, views identified]
    for path in files:
        gt_path = capture / path.parent.name / f"{path.stem}_gt.npz"
        if not gt_path.is_file():
            raise FileNotFoundError(f"{gt_path}: the capture has no ground truth for {path}")
        detected = load_npz(path, required=("points_px", "marker_id"))
        gt = ImageGroundTruth.load(gt_path)
        hit, right = match_markers(gt, detected["points_px"][:, 0], detected["marker_id"], radius)
        visible = gt.crosspoint_visible.sum(axis=(1, 2))
        ratio = ratios(gt.points_px)
        centre = (gt.status > 0) & gt.point_visible[:, 0] & np.isfinite(ratio)
        which = np.digitize(ratio, BINS) - 1
        for b in range(len(BINS) - 1):
            mask = centre & (which == b)
            binned[b] += [mask.sum(), (hit & mask).sum(), (right & mask).sum()]
        frame = views.setdefault(path.stem, {})
        for marker, seen, known_id in zip(gt.marker_id.tolist(), (gt.status > 0).tolist(), right.tolist()):
            tally = frame.setdefault(marker, [0, 0])
            tally[0] += seen
            tally[1] += known_id
        for kind, mask in kinds(gt).items():
            counts[kind] += [mask.sum(), (hit & mask).sum(), (right & mask).sum(), visible[mask].sum(),
                             visible[mask & right].sum()]
    by_kind = {kind: {"markers": int(c[0]), "found": c[1] / max(c[0], 1), "identified": c[2] / max(c[0], 1),
                      "visible_crosspoints": int(c[3]), "recovered": c[4] / max(c[3], 1)} for kind, c in counts.items()}
    by_ratio = {f"{BINS[b]:.1f}-{min(BINS[b + 1], 1.0):.1f}": {"markers": int(c[0]), "found": c[1] / max(c[0], 1),
                                                              "identified": c[2] / max(c[0], 1)}
                for b, c in enumerate(binned)}
    tallies = [t for frame in views.values() for t in frame.values()]
    multi = {"markers_in_2_views": sum(t[0] >= 2 for t in tallies),
             "identified_in_2_views": sum(t[1] >= 2 for t in tallies)}
    return {"kinds": by_kind, "ratio": by_ratio, "views": multi}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capture", type=Path, required=True, help="the capture folder (factory.dataset capture)")
    parser.add_argument("--runs", nargs="+", required=True, help="NAME=FOLDER of networks-mode reconstructions")
    parser.add_argument("--radius", type=float, default=12.0, help="match radius, pixels of the views")
    args = parser.parse_args(argv)
    runs = {}
    for item in args.runs:
        name, _, folder = item.partition("=")
        if not folder:
            parser.error(f"--runs takes NAME=FOLDER, got {item!r}")
        runs[name] = compare(Path(folder), args.capture, args.radius)
    print("| run | markers | count | found | ID right | visible crosspoints | of identified markers |")
    print("|---|---|---|---|---|---|---|")
    for name, rows in runs.items():
        for kind, r in rows["kinds"].items():
            print(f"| {name} | {kind} | {r['markers']} | {r['found']:.2f} | {r['identified']:.2f} | "
                  f"{r['visible_crosspoints']} | {r['recovered']:.2f} |")
    print("\n| run | foreshortening ratio (centre visible, corners known) | count | found | ID right |")
    print("|---|---|---|---|---|")
    for name, rows in runs.items():
        for bin_name, r in rows["ratio"].items():
            print(f"| {name} | {bin_name} | {r['markers']} | {r['found']:.2f} | {r['identified']:.2f} |")
    print("\n| run | markers visible in >= 2 views (per frame, summed) | identified in >= 2 views | share |")
    print("|---|---|---|---|")
    for name, rows in runs.items():
        v = rows["views"]
        print(f"| {name} | {v['markers_in_2_views']} | {v['identified_in_2_views']} | "
              f"{v['identified_in_2_views'] / max(v['markers_in_2_views'], 1):.2f} |")
    print("RESULT " + json.dumps(runs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
