"""Benchmark the default body's shape range: does every default garment dress on every shape in it?

The default body's three shape values, gender (0 male .. 1 female), weight and height (0 .. 1,
about 1.3 .. 1.9 m), span the range `assets.body.default_body` accepts.  This dresses each default
garment (`factory.dress_garment`, the 12 mm training level, A pose) on a grid over that range and
prints a table: garment x shape, dressed or not, the widest seam gap when sewing stopped, sewing
steps and seconds; a failure's first words say why.  Each dressing runs in its own worker process
(one thread each), so a many-core machine runs the grid in parallel.

    python benchmarks/body_range.py [--grid corners|N] [--shapes 0.3,0.65,0.7 ...]
                                    [--garments shirt,skirt,pants,suit] [--workers N] [--json out.json]

`--grid corners`: the 8 corners of the range and its centre; `--grid N`: N values per shape axis
(N^3 shapes, 3: corners, edge middles and centre); `--grid none`: only `--shapes`, which adds shapes
(gender,weight,height).  Each row is also printed as it finishes (``ROW {json}``), so a run cut short
keeps what it dressed.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

GARMENTS = ("shirt", "skirt", "pants", "suit")


def grid_shapes(grid: str) -> list[tuple[float, float, float]]:
    """The shapes (gender, weight, height) of `--grid`: 'corners' or N values per axis over [0, 1]."""
    if grid == "corners":
        return [*itertools.product((0.0, 1.0), repeat=3), (0.5, 0.5, 0.5)]
    if grid == "none":
        return []
    n = int(grid)
    if n < 2:
        raise ValueError(f"--grid must be 'corners' or at least 2 values per axis, got {grid!r}")
    values = [round(k / (n - 1), 6) for k in range(n)]
    return list(itertools.product(values, repeat=3))


def dress_one(job: tuple[str, tuple[float, float, float], int]) -> dict:
    """Dress one garment on one shape; the row of the table as a dict (runs in a worker process)."""
    import numpy as np

    from assets.body import default_body
    from assets.garments.loading import load_template
    from factory.dressing import DressingError, DressingParams, dress

    garment, shape, level_mm = job
    body = default_body()
    template = load_template(garment)
    started = time.perf_counter()
    row = {"garment": garment, "shape": list(shape)}
    try:
        dressed = dress(template, body, np.array(shape), DressingParams(level_mm=level_mm), progress=False)
    except DressingError as exc:
        row.update(dressed=False, seconds=time.perf_counter() - started, why=str(exc))
        stuck, level = exc.stuck, template.level(level_mm)
        if stuck is not None and len(stuck.positions) == level.num_vertices:  # unsewn panels: measure the seams
            pairs = level.seam_pairs
            row["gap_mm"] = float(np.linalg.norm(stuck.positions[pairs[:, 0]] - stuck.positions[pairs[:, 1]],
                                                 axis=1).max() * 1e3)
        return row
    report = dressed.report
    row.update(dressed=True, seconds=report["seconds"], gap_mm=report["seam_gap_mm"], steps=report["sew_steps"],
               strain=report["max_strain"], penetration_mm=report["max_penetration_mm"])
    return row


def _single_threaded() -> None:
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--grid", default="corners", help="'corners' (8 corners and the centre), N per axis, or 'none'")
    parser.add_argument("--shapes", nargs="*", default=[], help="extra shapes, each 'gender,weight,height'")
    parser.add_argument("--garments", default=",".join(GARMENTS))
    parser.add_argument("--level", type=int, default=12, help="template level (mm)")
    parser.add_argument("--workers", type=int, default=os.cpu_count(), help="dressings at once")
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args()
    extra = [tuple(float(v) for v in s.split(",")) for s in args.shapes]
    # the corners and the centre first: on a machine lent for a while they are what must finish
    shapes = sorted(dict.fromkeys(grid_shapes(args.grid) + extra),
                    key=lambda s: (s not in grid_shapes("corners") and s not in extra))
    jobs = [(g, s, args.level) for s in shapes for g in args.garments.split(",")]
    _single_threaded()
    started = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=min(args.workers, len(jobs))) as pool:
        futures = {pool.submit(dress_one, job): job for job in jobs}
        for future in as_completed(futures):
            try:
                rows.append(future.result())
            except Exception as exc:  # a crash is a row too, not the end of the grid
                garment, shape, _ = futures[future]
                rows.append({"garment": garment, "shape": list(shape), "dressed": False, "seconds": float("nan"),
                             "why": f"crashed: {type(exc).__name__} {exc}"})
            print("ROW " + json.dumps(rows[-1]), flush=True)  # a run cut short keeps what finished
    rows.sort(key=lambda r: (GARMENTS.index(r["garment"]) if r["garment"] in GARMENTS else 9, r["shape"]))
    wall = time.perf_counter() - started
    print(f"machine: {platform.machine()}, python {platform.python_version()}, {os.cpu_count()} cores, "
          f"{args.workers} workers; {time.strftime('%Y-%m-%d')}; level {args.level} mm; wall {wall:.0f} s")
    print("| garment | gender | weight | height | dressed | widest seam gap (mm) | sewing steps | max strain | seconds "
          "| why not |")
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---|")
    for r in rows:
        g, w, h = r["shape"]
        gap = f"{r['gap_mm']:.2f}" if "gap_mm" in r else "-"
        why = "" if r["dressed"] else r["why"].split(";")[0].replace("|", "/")[:110]
        print(f"| {r['garment']} | {g:g} | {w:g} | {h:g} | {'yes' if r['dressed'] else 'NO'} | {gap} | "
              f"{r.get('steps', '-')} | {r.get('strain', float('nan')):.3f} | {r['seconds']:.0f} | {why} |")
    failed = [r for r in rows if not r["dressed"]]
    print(f"dressed {len(rows) - len(failed)} of {len(rows)}")
    print("JSON " + json.dumps({"benchmark": "body_range", "grid": args.grid, "level_mm": args.level,
                                "wall_s": wall, "rows": rows}))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
