"""Benchmark garment template building: every default garment at every level.

Each (garment, level) builds in a fresh process so its time and peak memory (max RSS) are its own.
Targets (issue 3): the 12/4/2 mm levels of all four garments in under 60 s together; the 1 mm shirt
in under 60 s and 8 GiB.  Baseline in the same run: the whole panel meshed by Triangle alone
(quality 20 degrees, the same target triangle area), which is what the hybrid grid replaces.

    python benchmarks/garments.py [--garments shirt,skirt,pants,suit] [--levels 12,4,2,1] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from common import add_results_flag, run_fresh, write_results

HYBRID = """
    from assets.garments.defaults import default_pattern
    from assets.garments.template import Template
    template = Template.build(default_pattern("{garment}"))
    t0 = time.perf_counter()
    level = template.level({mm})
    R["build_s"] = time.perf_counter() - t0
    R["vertices"] = level.num_vertices
    R["triangles"] = len(level.faces)
    R["crosspoint_vertices"] = int((level.crosspoint >= 0).sum())
"""

TRIANGLE_ONLY = """
    import numpy as np, triangle
    from assets.garments.defaults import default_pattern
    from assets.garments.mesh import seam_segment_counts
    pattern = default_pattern("{garment}")
    h = {mm} * 1e-3
    counts = seam_segment_counts(pattern, h)
    t0 = time.perf_counter()
    vertices = triangles = 0
    for panel, n in zip(pattern.panels, counts):
        outline = np.concatenate([panel.edge_points(k, c)[:-1] for k, c in enumerate(n)])
        seg = np.stack([np.arange(len(outline)), (np.arange(len(outline)) + 1) % len(outline)], 1)
        out = triangle.triangulate({{"vertices": outline, "segments": seg}}, f"pq20Ya{{h * h / 2:.15f}}Q")
        vertices += len(out["vertices"]); triangles += len(out["triangles"])
    R["build_s"] = time.perf_counter() - t0
    R["vertices"] = vertices
    R["triangles"] = triangles
    R["crosspoint_vertices"] = 0
"""

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--garments", default="shirt,skirt,pants,suit")
    parser.add_argument("--levels", default="12,4,2,1")
    parser.add_argument("--json", help="also write the results here")
    add_results_flag(parser)
    args = parser.parse_args()
    rows = []
    for garment in args.garments.split(","):
        for mm in (int(v) for v in args.levels.split(",")):
            if mm == 1 and garment != "shirt":
                continue  # the target names the 1 mm shirt; the others follow the same scaling
            rows.append((garment, mm, "hybrid grid + CDT band", run_fresh(HYBRID.format(garment=garment, mm=mm))))
            if mm in (4, 2) and garment == "shirt":
                rows.append((garment, mm, "baseline: Triangle only", run_fresh(TRIANGLE_ONLY.format(garment=garment, mm=mm))))
    print(f"machine: {platform.machine()}, python {platform.python_version()}, {os.cpu_count()} cores; "
          f"{time.strftime('%Y-%m-%d')}")
    table = ["| garment | level | method | vertices | triangles | crosspoint vertices | build s | peak RSS GiB |",
             "|---|---:|---|---:|---:|---:|---:|---:|"]
    for garment, mm, method, r in rows:
        table.append(f"| {garment} | {mm} mm | {method} | {r['vertices']} | {r['triangles']} | "
                     f"{r['crosspoint_vertices']} | {r['build_s']:.2f} | {r['peak_rss_gib']:.2f} |")
    print("\n".join(table))
    coarse = sum(r["build_s"] for g, mm, m, r in rows if mm in (12, 4, 2) and m.startswith("hybrid"))
    stands = [f"12/4/2 mm levels of all garments together: {coarse:.1f} s (target < 60 s: "
              f"{'met' if coarse < 60 else 'missed'})"]
    for g, mm, m, r in rows:
        if g == "shirt" and mm == 1 and m.startswith("hybrid"):
            met = r["build_s"] < 60 and r["peak_rss_gib"] < 8
            stands.append(f"1 mm shirt: {r['build_s']:.1f} s, {r['peak_rss_gib']:.2f} GiB (target < 60 s, < 8 GiB: "
                          f"{'met' if met else 'missed'})")
    print("\n".join(stands))
    print("JSON " + json.dumps([{"garment": g, "mm": mm, "method": m, **r} for g, mm, m, r in rows]))
    if args.json:
        with open(args.json, "w") as f:
            json.dump([{"garment": g, "mm": mm, "method": m, **r} for g, mm, m, r in rows], f, indent=2)
    if not args.no_results:
        write_results("garments", "\n".join(table), "; ".join(stands) + ".")


if __name__ == "__main__":
    main()
