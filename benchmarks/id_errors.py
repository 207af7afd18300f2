"""What wrong marker IDs do to triangulation, and what the Detector's ID votes take back, on a factory
capture in the ground-truth mode.

For each ID error rate (`--id-errors`: the share of detected markers whose ID is replaced by a random
ID of the garment, `GroundTruthConfig.id_error`; 0.26 is the chained Detector's measured rate on
fully visible markers, RESULTS.md issue 7) the ground-truth detections of every camera and frame
(0.3 px noise, as `make demo`) are triangulated (`reconstruction.triangulate.triangulate_frame`, its
defaults: RANSAC over the views) five times: without the pattern-neighbour check
(`TriangulationConfig.neighbours` None) with the IDs as given (the baseline), after the Detector's ID
votes per view (`networks.detector.vote_markers`, `DetectorConfig` defaults), and after the votes
without the markers no neighbour supports (`Detections.id_support` 0); then with the neighbour check
(`reconstruction.consistency`, its defaults: on in triangulation by default) without and with the
votes.  The captured points are compared with the ground-truth garment at their crosspoints: median,
95th percentile and worst error, and how many are more than 5 mm off (a crosspoint placed on another
marker's part of the garment).

    python benchmarks/id_errors.py --capture out/demo/capture [--id-errors 0,0.05,0.26]

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

from networks.detections import Detections  # noqa: E402
from networks.detector import DetectorConfig, vote_markers  # noqa: E402
from networks.neighbours import MarkerLayout  # noqa: E402
from reconstruction.groundtruth import GroundTruthCapture, GroundTruthConfig  # noqa: E402
from reconstruction.triangulate import TriangulationConfig, triangulate_frame  # noqa: E402

NOISE_PX = 0.3
OFF_MM = 5.0
#: (ID votes, unsupported markers dropped, neighbour check) of each variant, in the table's order
VARIANTS = ((False, False, False), (True, False, False), (True, True, False), (False, False, True),
            (True, False, True))


def voted(detections: Detections, layout: MarkerLayout, spec, size: tuple[int, int], config: DetectorConfig
          ) -> Detections:
    """One view's detections with their IDs put to the neighbours' votes, as `networks.Detector.vote`."""
    ids, support = vote_markers(layout, spec, detections.marker_id, detections.points_px, size, config)
    return Detections(**{**detections.to_dict(), "marker_id": ids, "id_support": support})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--capture", type=Path, required=True, help="a factory capture folder (ground truth)")
    parser.add_argument("--id-errors", default="0,0.05,0.26")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    capture = GroundTruthCapture(args.capture)
    tables = capture.template.layout.tables()
    spec = capture.template.layout.spec
    layout = MarkerLayout.from_tables(tables, spec.num_ids)
    config = DetectorConfig()
    crosspoints = capture.crosspoint_map
    truths = {frame: capture.detections(frame, GroundTruthConfig(noise_px=NOISE_PX, seed=args.seed))
              for frame in capture.frames}
    rows = []
    started = time.perf_counter()
    for rate in (float(r) for r in args.id_errors.split(",")):
        degrade = GroundTruthConfig(noise_px=NOISE_PX, id_error=rate, seed=args.seed)
        for votes, supported, checked in VARIANTS:
            triangulation = TriangulationConfig() if checked else TriangulationConfig(neighbours=None)
            errors, right, seen = [], 0, 0
            for frame in capture.frames:
                views = capture.detections(frame, degrade)
                truth = truths[frame]
                if votes:
                    views = [voted(d, layout, spec, (cam.width, cam.height), config)
                             for d, cam in zip(views, capture.cameras)]
                if supported:
                    truth = [t.select(d.id_support != 0) for t, d in zip(truth, views)]
                    views = [d.select(d.id_support != 0) for d in views]
                for d, t in zip(views, truth):
                    right += int((d.marker_id == t.marker_id).sum())
                    seen += len(d)
                points = triangulate_frame(crosspoints, capture.cameras, views, triangulation, frame=frame,
                                           source=degrade.source)
                true = capture.crosspoints(frame, points.key)
                ok = np.isfinite(true).all(axis=1)
                errors.append(1e3 * np.linalg.norm(points.xyz[ok] - true[ok], axis=1))
            error = np.concatenate(errors)
            label = ("yes" if votes else "no" if checked else "no (baseline)") + (
                ", unsupported markers dropped" if supported else "")
            rows.append({"id_error": rate, "votes": label, "neighbour_check": checked,
                         "id_accuracy": right / max(seen, 1),
                         "points": int(len(error)), "median_mm": float(np.median(error)),
                         "p95_mm": float(np.percentile(error, 95)), "max_mm": float(error.max()),
                         "off": int((error > OFF_MM).sum())})
    result = {"date": time.strftime("%Y-%m-%d"), "capture": str(args.capture), "frames": capture.frames,
              "cameras": len(capture.cameras), "noise_px": NOISE_PX, "seconds": time.perf_counter() - started,
              "rows": rows}
    print(f"# ID errors and triangulation, {result['date']}, {args.capture}: {len(capture.cameras)} cameras, "
          f"frames {capture.frames}, {NOISE_PX} px noise, {result['seconds']:.0f} s")
    print(f"\n| IDs replaced | ID votes | neighbour check | ID accuracy of the detections | captured points | "
          f"error median / p95 / worst mm | points more than {OFF_MM:g} mm off |\n|---|---|---|---|---|---|---|")
    for r in rows:
        check = "yes" if r["neighbour_check"] else "no"
        print(f"| {r['id_error']:.0%} | {r['votes']} | {check} | {r['id_accuracy']:.3f} | "
              f"{r['points']} | {r['median_mm']:.2f} / {r['p95_mm']:.2f} / {r['max_mm']:.1f} | {r['off']} |")
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
