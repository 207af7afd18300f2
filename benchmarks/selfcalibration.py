"""Benchmark self-calibration from the garment (issue 48 item 3): a rig that is a little off, refined by
bundle adjustment over the crosspoints of a few frames, against the exact rig.

1. Capture: the default shirt walking, `--frames` frames from `--first-frame` (a finished simulation
   can be reused with `--simulation`), a ring of `--cameras` cameras at `--resolution`, rendered with
   Workbench: only the ground truth is read (`factory.capture.capture`; resumed from `--out`).
2. Detections: each view's ground truth with `--noise-px` Gaussian noise (`reconstruction.groundtruth`).
3. Rigs: the exact cameras; the same perturbed (`perturb_cameras`: each turned `--degrees` about its
   centre, moved `--mm`, focal length scaled by 1 +- `--focal-pct` %, seeded by `--seed`); and the
   perturbed ones self-calibrated (`self_calibrate_detections`, focal lengths refined) from the first
   `--calibration-frames` frames.
4. Each rig triangulates every frame (`triangulate_frame`, default settings) and its points are
   compared with the ground-truth crosspoints: in the world frame, and after the one similarity
   transform (scale, rotation, shift) that best maps all of them onto the truth ("shape"): images alone
   cannot tell where the world is nor its scale, so a self-calibrated rig keeps the given rig's frame
   on average (``keep="rig"``) and the shape error is what it can restore.  Target: the self-calibrated
   rig's error within 10% of the exact rig's.

    .venv/bin/python benchmarks/selfcalibration.py --simulation out/sim/shirt_walk --out out/bench_selfcal

Prints the table and a ``RESULT {json}`` line; writes its section of RESULTS.md unless --no-results.
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

from benchmarks.common import add_results_flag, write_results  # noqa: E402
from factory.capture import capture  # noqa: E402
from factory.plan import RenderSettings  # noqa: E402
from reconstruction.groundtruth import GroundTruthCapture, GroundTruthConfig  # noqa: E402
from reconstruction.selfcalibration import (  # noqa: E402
    SelfCalibrationConfig, perturb_cameras, self_calibrate_detections, similarity_fit)
from reconstruction.triangulation import TriangulationConfig, triangulate_frame  # noqa: E402

TARGET = 1.10  # self-calibrated error / exact error


def rig_errors(capture_: GroundTruthCapture, cameras, detections: dict) -> dict:
    """Triangulate every frame with `cameras`: point count and error statistics (mm), world and shape."""
    found, truth = [], []
    for frame, views in detections.items():
        points = triangulate_frame(capture_.crosspoint_map, cameras, views, TriangulationConfig(), frame)
        true = capture_.crosspoints(frame, points.key)
        on = np.isfinite(true).all(axis=1)
        found.append(points.xyz[on])
        truth.append(true[on])
    found, truth = np.concatenate(found), np.concatenate(truth)
    world = np.linalg.norm(found - truth, axis=1) * 1000.0
    s, Q, d = similarity_fit(found, truth)
    shape = np.linalg.norm(s * found @ Q.T + d - truth, axis=1) * 1000.0
    return {"points": len(found), "world_mm_median": float(np.median(world)),
            "world_mm_p95": float(np.percentile(world, 95)), "shape_mm_median": float(np.median(shape)),
            "shape_mm_p95": float(np.percentile(shape, 95)), "scale": s}


def camera_errors(cameras, exact) -> dict:
    """How far `cameras` are from `exact` after the similarity transform of their centres (the gauge):
    largest rotation (degrees), centre (mm) and focal length (%) differences."""
    s, Q, d = similarity_fit(np.stack([c.center for c in cameras]), np.stack([c.center for c in exact]))
    angles = [np.degrees(np.arccos(np.clip((np.trace(c.R @ Q.T @ e.R.T) - 1) / 2, -1, 1)))
              for c, e in zip(cameras, exact)]
    centres = [np.linalg.norm(s * Q @ c.center + d - e.center) * 1000.0 for c, e in zip(cameras, exact)]
    focal = [abs(c.K[0, 0] / e.K[0, 0] - 1) * 100.0 for c, e in zip(cameras, exact)]
    return {"rotation_deg_max": float(max(angles)), "centre_mm_max": float(max(centres)),
            "focal_pct_max": float(max(focal))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench_selfcalibration")
    parser.add_argument("--simulation", type=Path, help="a finished shirt walk simulation folder to reuse")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--first-frame", type=int, default=2)
    parser.add_argument("--cameras", type=int, default=8)
    parser.add_argument("--resolution", default="1280x720", help="WIDTHxHEIGHT (default %(default)s)")
    parser.add_argument("--noise-px", type=float, default=0.3)
    parser.add_argument("--degrees", type=float, default=1.0)
    parser.add_argument("--mm", type=float, default=10.0)
    parser.add_argument("--focal-pct", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--calibration-frames", type=int, default=2, help="the first N frames self-calibrate")
    add_results_flag(parser)
    args = parser.parse_args()
    width, height = (int(v) for v in args.resolution.split("x"))

    render = RenderSettings(resolution=(width, height), engine="WORKBENCH", samples=1, denoise=False)
    folder = capture("shirt", "walk", args.out / "capture", frames=args.frames, first_frame=args.first_frame,
                     cameras=args.cameras, resolution=(width, height), render=render, simulation=args.simulation)
    gt = GroundTruthCapture(folder)
    exact = gt.cameras
    noise = GroundTruthConfig(noise_px=args.noise_px, seed=args.seed)
    detections = {f: gt.detections(f, noise) for f in gt.frames}
    perturbed = perturb_cameras(exact, np.random.default_rng(args.seed), args.degrees, args.mm, args.focal_pct / 100)
    calibration = {f: detections[f] for f in gt.frames[:args.calibration_frames]}
    started = time.perf_counter()
    refined, report = self_calibrate_detections(gt.crosspoint_map, perturbed, calibration,
                                                SelfCalibrationConfig(focal=True))
    seconds = time.perf_counter() - started
    print(report.table())

    rows = {"exact": exact, "perturbed": perturbed, "self-calibrated": refined}
    results = {name: {**rig_errors(gt, cams, detections), **camera_errors(cams, exact)} for name, cams in rows.items()}
    ratio = results["self-calibrated"]["shape_mm_median"] / results["exact"]["shape_mm_median"]
    header = ("| cameras | points | shape error mm median | p95 | world error mm median | p95 | scale | "
              "rotation deg max | centre mm max | focal % max |\n|---|---|---|---|---|---|---|---|---|---|")
    lines = [f"| {name} | {r['points']} | {r['shape_mm_median']:.3f} | {r['shape_mm_p95']:.3f} | "
             f"{r['world_mm_median']:.3f} | {r['world_mm_p95']:.3f} | {r['scale']:.4f} | {r['rotation_deg_max']:.3f} | "
             f"{r['centre_mm_max']:.2f} | {r['focal_pct_max']:.3f} |" for name, r in results.items()]
    table = "\n".join([header, *lines])
    stands = (f"self-calibrated shape error {ratio:.3f} x the exact rig's (target <= {TARGET:.2f}: "
              f"{'met' if ratio <= TARGET else 'missed'}); {len(exact)} cameras at {width} x {height}, "
              f"{len(gt.frames)} frames, {args.noise_px} px noise, perturbed {args.degrees} deg / {args.mm} mm / "
              f"{args.focal_pct}% focal, self-calibrated from {len(calibration)} frames ({report.points} points, "
              f"{report.observations} observations, RMS {report.rms_before_px:.2f} -> {report.rms_after_px:.3f} px) "
              f"in {seconds:.1f} s. Shape: after the one similarity transform that best maps a rig's points onto "
              "the truth; rotation, centre and focal: the worst camera, after the similarity transform of the "
              "camera centres onto the exact rig's.")
    print(table)
    print(f"Where it stands: {stands}")
    if not args.no_results:
        write_results("selfcalibration", table, stands)
    print("RESULT " + json.dumps({"rigs": results, "ratio": ratio, "seconds": seconds, "report": report.to_dict()}))


if __name__ == "__main__":
    main()
