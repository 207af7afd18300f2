"""Benchmark the factory's cloth simulator against Newton's VBD solver on the same job.

The default shirt (12 mm training level) is dressed on the default body, then both solvers simulate it
through the built-in walk at 120 Hz (1 s transition from the dressing pose, then walking), from the same
dressed state with the same body frames:

- ours: `factory.simulate` (projective dynamics, `factory.cloth`), the reference's energies;
- peer: `newton.solvers.SolverVBD` with the body as a mesh collider (`benchmarks/newton_peer.py` maps
  the same energies onto Newton's), 5 substeps x 10 iterations per frame unless told otherwise.

Both are scored by the same measures: seconds per frame (Newton's first frame, which compiles its
kernels, is left out), the deepest garment vertex inside the body (exact signed distance to the
body's triangles, every 8th frame and the last) and the largest edge strain (length / rest length - 1)
over all frames.  Target (issue 5): ours
at least 2x faster than Newton's VBD, with penetration under 2 mm.  Each solver runs in its own process.

    python benchmarks/simulate.py [--frames 240] [--out out/bench_simulate] [--substeps 5] [--iterations 10]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from common import add_results_flag, run_fresh, write_results

OURS = """
    from factory.simulate import SimulationConfig, simulate
    import numpy as np, json
    t0 = time.perf_counter()
    path = simulate(SimulationConfig(garment="shirt", motion="walk", frames={frames}), "{out}", progress=False)
    R["total_s"] = time.perf_counter() - t0
    meta = json.loads(str(np.load(path)["meta"]))
    R["s_per_frame"] = meta["seconds_per_frame"]
    R["dressing_s"] = meta["dressing"]["seconds"]
"""

PEER = """
    import sys, json
    import numpy as np
    sys.path.insert(0, "benchmarks")
    from newton_peer import simulate_vbd
    from assets.body import load_body
    from factory.dressing import DressedGarment
    data = np.load("{out}/sequence.npz")
    meta = json.loads(str(data["meta"]))
    dressed = DressedGarment.load("{out}/dressed.npz")
    body = load_body(meta["body"])
    posed = body.pose(data["body_poses"], data["body_trans"], data["body_betas"])
    positions, per_frame, setup = simulate_vbd(
        dressed.faces, dressed.rest_corners, data["positions"][0].astype(np.float64), posed.vertices,
        body.faces, substeps={substeps}, iterations={iterations}, progress=False)
    np.save("{out}/newton_positions.npy", positions)
    R["s_per_frame"] = per_frame
    R["setup_s"] = setup
"""


def exact_depth(body_vertices, body_faces, points) -> float:
    """Deepest point inside the body (m, >= 0): exact closest points on the body's triangles (trimesh),
    signed by the closest triangle's normal; not the solver's own nearest-vertex approximation."""
    import numpy as np
    import trimesh

    mesh = trimesh.Trimesh(body_vertices, body_faces, process=False)
    closest, _, triangle = trimesh.proximity.closest_point(mesh, points)
    signed = np.einsum("nk,nk->n", points - closest, mesh.face_normals[triangle])
    return float(max(0.0, -signed.min()))


def score(out: str, every: int = 8) -> dict[str, dict[str, float]]:
    """Penetration (exact, every `every`-th frame) and strain (every frame) of both sequences, by
    the same measures."""
    import numpy as np

    from assets.body import load_body
    from factory.cloth import ClothModel
    from factory.dressing import DressedGarment

    data = np.load(f"{out}/sequence.npz")
    meta = json.loads(str(data["meta"]))
    dressed = DressedGarment.load(f"{out}/dressed.npz")
    body = load_body(meta["body"])
    posed = body.pose(data["body_poses"], data["body_trans"], data["body_betas"])
    model = ClothModel.build(dressed.faces, dressed.rest_corners)
    scores = {}
    for name, positions in (("ours", data["positions"]), ("newton_vbd", np.load(f"{out}/newton_positions.npy"))):
        depth, strain = [], []
        for t in range(1, len(positions)):
            x = positions[t].astype(np.float64)
            if not np.isfinite(x).all():
                depth.append(float("inf"))
                strain.append(float("inf"))
                continue
            if t % every == 0 or t == len(positions) - 1:
                depth.append(exact_depth(posed.vertices[t], body.faces, x))
            strain.append(float(np.abs(model.edge_length_strain(x)).max()))
        scores[name] = {"max_penetration_mm": 1e3 * max(depth), "max_strain": max(strain),
                        "median_frame_strain": float(np.median(strain))}
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--out", default="out/bench_simulate")
    parser.add_argument("--substeps", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--json", help="also write the results here")
    add_results_flag(parser)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    for stale in ("sequence.npz", "checkpoint.npz"):  # simulate afresh (the dressing is reused)
        if os.path.exists(os.path.join(args.out, stale)):
            os.remove(os.path.join(args.out, stale))
    ours = run_fresh(OURS.format(frames=args.frames, out=args.out))
    peer = run_fresh(PEER.format(out=args.out, substeps=args.substeps, iterations=args.iterations))
    scores = score(args.out)
    rows = [
        ("ours (projective dynamics)", ours["s_per_frame"], scores["ours"], ours["peak_rss_gib"]),
        (f"Newton SolverVBD ({args.substeps}x{args.iterations})", peer["s_per_frame"], scores["newton_vbd"],
         peer["peak_rss_gib"]),
    ]
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"{time.strftime('%Y-%m-%d')}; shirt 12 mm on the default body, walk, {args.frames} frames at 120 Hz")
    print(f"dressing (once, shared): {ours['dressing_s']:.1f} s")
    table = ["| solver | s / frame | max penetration (mm) | max edge strain | median frame strain | peak RSS (GiB) |",
             "|---|---|---|---|---|---|"]
    for name, spf, s, rss in rows:
        table.append(f"| {name} | {spf:.3f} | {s['max_penetration_mm']:.2f} | {s['max_strain']:.3f} | "
                     f"{s['median_frame_strain']:.3f} | {rss:.2f} |")
    print("\n".join(table))
    ratio = peer["s_per_frame"] / ours["s_per_frame"]
    depth = scores["ours"]["max_penetration_mm"]
    stands = (f"shirt 12 mm, walk, {args.frames} frames; speed-up of ours over Newton VBD {ratio:.2f}x (target >= 2x: "
              f"{'met' if ratio >= 2 else 'missed'}); our max penetration {depth:.2f} mm (target < 2 mm: "
              f"{'met' if depth < 2 else 'missed'}).")
    print(stands)
    result = {"ours": {**ours, **scores["ours"]}, "newton_vbd": {**peer, **scores["newton_vbd"]}, "speedup": ratio,
              "frames": args.frames}
    print(json.dumps(result))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    if not args.no_results:
        write_results("simulate", "\n".join(table), stands)


if __name__ == "__main__":
    main()
