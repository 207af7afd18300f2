"""Benchmark the scale-out (issue 10): the factory's dataset build on 1 and 2 Ray workers beside the
local backend, on this machine.

Each build runs in a fresh process (`python -m factory.dataset build`) into its own folder, from the
same reused simulation, with the same images: `--frames` frames x `--variations` variations of the
default shirt walking, rendered with `--engine` at `--resolution` and `--samples`.  The table gives
wall seconds, images per hour and the ratio to one Ray worker.

    python benchmarks/scale.py --simulation out/bench_reconstruction/capture/sim --out out/bench_scale

The simulation folder is any finished `factory.simulate` output of the default shirt, body and walk
(``sequence.npz``, ``dressed.npz``) long enough for the frames asked for.  Training throughput with
1 and 2 GPUs (the other half of the issue's benchmark) needs a 2-GPU machine and `torchrun`; it is
not part of this script yet.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (name, extra CLI arguments) of each build, the local backend first as the baseline
BUILDS = (("local backend (one process)", ["--backend", "local"]),
          ("Ray, 1 worker", ["--backend", "ray", "--num-cpus", "1"]),
          ("Ray, 2 workers", ["--backend", "ray", "--num-cpus", "2"]))


def build(folder: Path, simulation: Path, args: argparse.Namespace, extra: list[str]) -> dict:
    """One dataset build in a fresh process; returns its wall time and `timing.json`."""
    if folder.exists():
        shutil.rmtree(folder)  # every build starts empty: the time is the whole build's
    command = [sys.executable, "-m", "factory.dataset", "build", "--garment", "shirt", "--motions", "walk",
               "--frames", str(args.frames), "--variations", str(args.variations), "--resolution",
               str(args.resolution), "--engine", args.engine, "--samples", str(args.samples),
               "--reuse-simulation", f"walk={simulation}", "--out", str(folder), *extra]
    start = time.perf_counter()
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-3000:]}")
    timing = json.loads((folder / "timing.json").read_text())
    return {"wall_s": wall, "timing": timing}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--simulation", type=Path, required=True, help="a finished shirt/walk simulation folder")
    parser.add_argument("--out", type=Path, default=Path("out/bench_scale"))
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--variations", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--engine", default="CYCLES", choices=("CYCLES", "EEVEE", "WORKBENCH"))
    parser.add_argument("--samples", type=int, default=16)
    args = parser.parse_args()
    if not (args.simulation / "sequence.npz").is_file():
        raise SystemExit(f"{args.simulation}: not a finished simulation (no sequence.npz)")
    rows = []
    for i, (name, extra) in enumerate(BUILDS):
        measured = build(args.out / f"build{i}", args.simulation.resolve(), args, extra)
        images = measured["timing"].get("images", 0)
        rows.append({"build": name, "images": images, "wall_s": measured["wall_s"],
                     "images_per_hour": 3600.0 * images / measured["wall_s"], "timing": measured["timing"]})
    one = next(r for r in rows if r["build"] == "Ray, 1 worker")
    result = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
              "job": {k: getattr(args, k) for k in ("frames", "variations", "resolution", "engine", "samples")},
              "rows": rows}
    (args.out / "results.json").write_text(json.dumps(result, indent=2))
    print(f"# factory scale-out, {result['date']}, {result['machine']}")
    print(f"job: default shirt, walk, {args.frames} frames x {args.variations} variations, {args.engine} "
          f"{args.samples} samples at {args.resolution} px, simulation reused")
    print("| build | images | wall s | images/hour | vs Ray 1 worker |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['build']} | {r['images']} | {r['wall_s']:.1f} | {r['images_per_hour']:.0f} | "
              f"{r['images_per_hour'] / one['images_per_hour']:.2f}x |")
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
