"""Benchmark the rendering factory: seconds per training image, split into scene set-up, render and
ground truth (issue 6).

The default shirt (12 mm level) walks (`factory.simulate`, reused from `--out` when already there);
`--images` training images at 512 x 512 are rendered from a few frames with the dataset's random
variations, with Cycles at the default samples and, for comparison in the same run, EEVEE and
Workbench.  Ground truth (markers, visibility, localizer cells, both crop sets) is computed for every
Cycles image.  Target: ground truth under 10 % of the render time.  Each engine runs in its own
process.

    python benchmarks/render.py [--images 4] [--samples 64] [--out out/bench_render]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from common import add_results_flag, run_fresh, write_results

ENGINE = """
    import json, time
    from pathlib import Path
    from factory.build import build
    from factory.plan import DatasetConfig, RenderSettings
    config = DatasetConfig(garment="shirt", motions=("walk",), frames={frames}, variations={variations},
                           render=RenderSettings(engine="{engine}", samples={samples}))
    out = Path("{out}") / "{engine}"
    # one simulation for all engines: the first engine's run makes it, the others copy it
    done = sorted(p for p in Path("{out}").glob("*/sim/walk") if (p / "sequence.npz").exists())
    t0 = time.perf_counter()
    build(config, out, progress=False, simulations={{"walk": done[0]}} if done and not (out / "sim").exists() else None)
    R["total_s"] = time.perf_counter() - t0
    timing = json.loads((out / "timing.json").read_text())
    R.update(timing)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--variations", type=int, default=2)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--engines", default="CYCLES,EEVEE,WORKBENCH")
    parser.add_argument("--out", default="out/bench_render")
    add_results_flag(parser)
    args = parser.parse_args()
    rows = {}
    for engine in args.engines.split(","):
        rows[engine] = run_fresh(ENGINE.format(frames=args.frames, variations=args.variations, engine=engine,
                                               samples=args.samples, out=os.path.abspath(args.out)))
    print(f"# render benchmark, {time.strftime('%Y-%m-%d')}, {platform.node()} ({os.cpu_count()} CPUs), "
          f"512 x 512, {args.frames * args.variations} images per engine")
    table = ["| engine | samples | set-up s/image | render s/image | ground truth s/image | GT / render | images per hour |",
             "|---|---|---|---|---|---|---|"]
    share = {}
    for engine, r in rows.items():
        n = r["images"]
        setup, render, gt = r["setup_s"] / n, r["render_s"] / n, r["groundtruth_s"] / n
        per_hour = 3600.0 / (setup + render + gt)
        samples = args.samples if engine == "CYCLES" else "-"
        share[engine] = 100 * gt / render
        table.append(f"| {engine} | {samples} | {setup:.2f} | {render:.2f} | {gt:.3f} | {share[engine]:.1f} % | "
                     f"{per_hour:.0f} |")
    print("\n".join(table))
    stands = (f"ground truth costs {share['CYCLES']:.1f} % of a Cycles render (target < 10 %: "
              f"{'met' if share['CYCLES'] < 10 else 'missed'})." if "CYCLES" in share
              else "no Cycles row in this run, so no comparison with the target (ground truth < 10 % of a Cycles render).")
    print(stands)
    print("RESULT " + json.dumps(rows))
    if not args.no_results:
        write_results("render", "\n".join(table), f"{args.frames * args.variations} images per engine at 512 x 512; "
                      + stands)


if __name__ == "__main__":
    main()
