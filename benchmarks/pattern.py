"""Benchmark the pattern generator: codebook, marker table, and a 1.5 m x 1.5 m fabric at 300 DPI.

Each stage runs in a fresh subprocess so its peak memory (max RSS) is its own.  Targets (issue 2):
the 1.5 m render under 60 s and 4 GiB on a 2-core machine.  The baseline beside it in the same run is
the straightforward renderer: 4 x 4 supersampled point sampling of the same pattern, measured on a
strip and extrapolated, plus its accuracy against the exact box filter.

    python benchmarks/pattern.py [--size-m 1.5] [--dpi 300] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from common import add_results_flag, run_fresh, write_results

STAGES = {
    "codebook (4096 IDs)": """
        from assets.pattern import PatternSpec, generate_codebook
        generate_codebook(PatternSpec())
    """,
    "marker table (32 x 32)": """
        from assets.pattern import MarkerTable, PatternSpec
        t = MarkerTable.build(PatternSpec())
        t.crosspoint_markers; t.localization_xy
    """,
    "render {size} m @ {dpi} DPI": """
        from assets.pattern import MarkerTable, PatternSpec, render_region
        spec = PatternSpec.covering({size}, {size})
        table = MarkerTable.build(spec)
        t0 = time.perf_counter()
        image = render_region(table, (0, 0, {size}, {size}), {dpi})
        R["pixels"] = f"{{image.shape[1]}} x {{image.shape[0]}}"
        R["render_s"] = time.perf_counter() - t0
    """,
    "render + write PNG {size} m @ {dpi} DPI": """
        import tempfile, os
        from assets.pattern import MarkerTable, PatternSpec, render_region, write_png
        spec = PatternSpec.covering({size}, {size})
        table = MarkerTable.build(spec)
        image = render_region(table, (0, 0, {size}, {size}), {dpi})
        with tempfile.TemporaryDirectory() as d:
            write_png(os.path.join(d, "p.png"), image, {dpi})
            R["png_mb"] = os.path.getsize(os.path.join(d, "p.png")) / 1e6
    """,
    "baseline: 4x4 supersampled point sampling (extrapolated)": """
        import numpy as np
        from assets.pattern import MarkerTable, PatternSpec, render_region
        from assets.pattern.raster import fabric_cells, pixels_per_metre
        spec = PatternSpec.covering({size}, {size})
        table = MarkerTable.build(spec)
        cells = fabric_cells(table)
        ppm = pixels_per_metre({dpi}); width = int(np.ceil({size} * ppm)); rows = 256; ss = 4
        t0 = time.perf_counter()
        offs = (np.arange(ss) + 0.5) / ss
        x = ((np.arange(width)[:, None] + offs).ravel()) / ppm / spec.pitch
        y = ((np.arange(rows)[:, None] + offs).ravel()) / ppm / spec.pitch
        thin, thick = spec.line_width_mm / spec.pitch_mm / 2, spec.border_line_width_mm / spec.pitch_mm / 2
        def on_line(u):
            n = np.rint(u); d = np.abs(u - n)
            return d < np.where(n % spec.cells_per_side == 0, thick, thin)
        fill = cells[np.minimum(y.astype(int), cells.shape[0] - 1)][:, np.minimum(x.astype(int), cells.shape[1] - 1)]
        line = on_line(y)[:, None] | on_line(x)[None, :]
        bg, code, ink = (np.array(c, np.float32) for c in (spec.background_rgb, spec.code_rgb, spec.line_rgb))
        rgb = np.where(line[..., None], ink, np.where(fill[..., None] > 0, code, bg))
        strip = rgb.reshape(rows, ss, width, ss, 3).mean(axis=(1, 3))
        elapsed = time.perf_counter() - t0
        R["render_s"] = elapsed * np.ceil({size} * ppm) / rows
        exact = render_region(table, (0, spec.fabric_bounds[3] - rows / ppm, width / ppm, spec.fabric_bounds[3]), {dpi})
        R["mean_abs_err_8bit"] = float(np.abs(np.rint(strip) - exact[:rows]).mean())
        R["max_abs_err_8bit"] = float(np.abs(np.rint(strip) - exact[:rows]).max())
    """,
}

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size-m", type=float, default=1.5)
    parser.add_argument("--dpi", type=float, default=300.0)
    parser.add_argument("--json", help="also write the results as JSON here")
    add_results_flag(parser)
    args = parser.parse_args()
    rows = []
    for name, body in STAGES.items():
        fmt = {"size": args.size_m, "dpi": args.dpi}
        result = run_fresh(body.format(**fmt))
        rows.append((name.format(**fmt), result))
    print(f"machine: {platform.machine()}, {platform.processor() or 'cpu'}, python {platform.python_version()}, "
          f"{os.cpu_count()} cores; {time.strftime('%Y-%m-%d')}")
    table = ["| stage | wall s | render s | peak RSS GiB | notes |", "|---|---:|---:|---:|---|"]
    for name, r in rows:
        notes = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                          for k, v in r.items() if k not in ("wall_s", "render_s", "peak_rss_gib"))
        render = f"{r['render_s']:.1f}" if "render_s" in r else ""
        table.append(f"| {name} | {r['wall_s']:.1f} | {render} | {r['peak_rss_gib']:.2f} | {notes} |")
    print("\n".join(table))
    written = next(r for name, r in rows if name.startswith("render + write PNG"))
    met = written["wall_s"] < 60 and written["peak_rss_gib"] < 4
    stands = (f"{args.size_m} m x {args.size_m} m at {args.dpi:g} DPI written as PNG in {written['wall_s']:.1f} s, "
              f"{written['peak_rss_gib']:.2f} GiB peak (target < 60 s and < 4 GiB): {'met' if met else 'missed'}.")
    print(stands)
    print("JSON " + json.dumps({name: r for name, r in rows}))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({name: r for name, r in rows}, f, indent=2)
    if not args.no_results:
        write_results("pattern", "\n".join(table), stands)


if __name__ == "__main__":
    main()
