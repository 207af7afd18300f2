"""Benchmark the scale-out (issue 10), in two halves.

``factory``: the factory's dataset build on 1 and 2 Ray workers beside the local backend, on this
machine.  Each build runs in a fresh process (`python -m factory.dataset build`) into its own folder,
from the same reused simulation, with the same images: `--frames` frames x `--variations` variations
of the default shirt walking, rendered with `--engine` at `--resolution` and `--samples`.  The table
gives wall seconds, images per hour and the ratio to one Ray worker.

    python benchmarks/scale.py factory --simulation out/bench_reconstruction/capture/sim --out out/bench_scale

The simulation folder is any finished `factory.simulate` output of the default shirt, body and walk
(``sequence.npz``, ``dressed.npz``) long enough for the frames asked for.

``training``: training throughput (samples per second) of each network with 1, 2, ... GPUs of this
machine, through ``torchrun -m networks.train`` (DistributedDataParallel over NCCL), with the ratio to
one GPU.  Weak scaling: each GPU takes the task's default batch (`networks.config.TASK_DEFAULTS`, the
reference's), so the global batch is that times the GPUs; each rank gets the same number of data
workers, reading pre-synthesized shards written first with every core.  The rate is taken from the
run's log (steps and elapsed seconds) after the first `--warmup` steps (cuDNN's autotuning, workers
starting).

    python benchmarks/scale.py training --rendered .bench/rendered --out /tmp/bs --gpus 1,2 --tasks recognizer,crosspoints
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
sys.path.insert(0, str(ROOT))

#: (name, extra CLI arguments) of each build, the local backend first as the baseline
BUILDS = (("local backend (one process)", ["--backend", "local"]),
          ("Ray, 1 worker", ["--backend", "ray", "--workers", "1"]),
          ("Ray, 2 workers", ["--backend", "ray", "--workers", "2"]))


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


def factory(args: argparse.Namespace) -> None:
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


#: synthetic images per task's shard folder for the training half (the crop tasks keep 32 crops of each)
SHARD_IMAGES = {"localizer": 4096, "recognizer": 1024, "crosspoints": 1024}


def rate(records: list[dict], batch: int, warmup: int) -> tuple[float, int, float]:
    """(samples per second, steps, seconds) between the first logged step at or after `warmup` and
    the last logged step, from a run's log.jsonl records (step, elapsed_s)."""
    timed = [r for r in records if "elapsed_s" in r and r["step"] >= warmup]
    if len(timed) < 2:
        raise SystemExit(f"too few logged steps after step {warmup} to time: {len(timed)} (raise --steps)")
    steps, seconds = timed[-1]["step"] - timed[0]["step"], timed[-1]["elapsed_s"] - timed[0]["elapsed_s"]
    return steps * batch / seconds, steps, seconds


def train_run(task: str, gpus: int, args: argparse.Namespace, workers: int) -> dict:
    """One short run of `task` on the first `gpus` GPUs (torchrun, one process per GPU); its rate."""
    from networks.config import TASK_DEFAULTS, TrainConfig  # the factory half needs no torch

    per_gpu = TASK_DEFAULTS[task]["batch_size"]
    folder = args.out / f"{task}_{gpus}gpu"
    if folder.exists():
        shutil.rmtree(folder)  # a fresh run each time: resuming would skip the warm-up
    folder.mkdir(parents=True)
    config = TrainConfig(task=task, steps=args.steps, batch_size=per_gpu * gpus, image_size=256, warmup_steps=50,
                         num_workers=workers, val_every=args.steps, val_samples=64, checkpoint_every=args.steps,
                         log_every=10, synth_weight=1.0)
    config.save(folder / "config.in.json")
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(gpus),
               "-m", "networks.train", task, "--data", "synth", "--garment", str(args.rendered),
               "--shards", str(args.out / "shards" / task),
               "--config", str(folder / "config.in.json"), "--out", str(folder / "run"), "--device", args.device, "--no-progress"]
    env = dict(os.environ, OMP_NUM_THREADS="2")
    if args.device == "cuda":
        env["CUDA_VISIBLE_DEVICES"] = ",".join(map(str, range(gpus)))
    start = time.perf_counter()
    with open(folder / "train.log", "w") as log:
        status = subprocess.run(command, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env).returncode
    wall = time.perf_counter() - start
    if status != 0:
        raise SystemExit(f"{' '.join(command)} failed ({status}):\n{(folder / 'train.log').read_text()[-3000:]}")
    records = [json.loads(line) for line in (folder / "run" / "log.jsonl").read_text().splitlines() if line]
    records = [r for r in records if "loss" in r]
    per_s, steps, seconds = rate(records, per_gpu * gpus, args.warmup)
    return {"task": task, "gpus": gpus, "global_batch": per_gpu * gpus, "workers_per_rank": workers,
            "samples_per_s": per_s, "timed_steps": steps, "timed_s": seconds, "wall_s": wall,
            "last_loss": records[-1]["loss"]}


def training(args: argparse.Namespace) -> None:
    import torch

    from networks.data import dataset_spec, garment_marker_ids
    from networks.shards import write_shards
    from networks.synth import SynthConfig

    gpus = sorted({int(v) for v in args.gpus.split(",") if v})
    tasks = [t for t in args.tasks.split(",") if t]
    unknown = sorted(set(tasks) - set(SHARD_IMAGES))
    if unknown:
        raise SystemExit(f"--tasks: unknown task(s) {', '.join(unknown)}; the tasks are {', '.join(SHARD_IMAGES)}")
    visible = torch.cuda.device_count()
    if args.device == "cuda" and (not gpus or gpus[0] < 1 or gpus[-1] > visible):
        raise SystemExit(f"--gpus {args.gpus}: this machine has {visible} CUDA GPU(s)")
    if args.warmup >= args.steps - 20:
        raise SystemExit(f"--warmup {args.warmup} leaves too few of --steps {args.steps} to time")
    cores = os.cpu_count() or 2
    workers = args.workers or max(1, (cores - gpus[-1]) // gpus[-1])  # per rank, the same for every run
    spec, ids = dataset_spec(args.rendered), garment_marker_ids(args.rendered)
    shards = {task: write_shards(args.out / "shards" / task, task, spec, args.shard_images or SHARD_IMAGES[task],
                                 SynthConfig(image_size=(256, 256)), ids, max(1, cores - 1), progress=False)
              for task in tasks}
    rows = [train_run(task, g, args, workers) for task in tasks for g in gpus]
    result = {"date": time.strftime("%Y-%m-%d"),
              "machine": (f"{visible} x {torch.cuda.get_device_name()}" if args.device == "cuda" else "CPU processes")
              + f", {cores} CPUs, torch {torch.__version__}",
              "steps": args.steps, "warmup": args.warmup, "shards": shards, "rows": rows}
    (args.out / "training.json").write_text(json.dumps(result, indent=2))
    print(f"# training scale-out, {result['date']}, {result['machine']}")
    print(f"weak scaling: the task's default batch per GPU; {workers} data workers per rank; rate over steps "
          f"{args.warmup}..{args.steps} of fresh runs on pre-synthesized shards")
    print("| network | GPUs | global batch | samples/s | vs 1 GPU | efficiency |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        one = next(o for o in rows if o["task"] == r["task"] and o["gpus"] == gpus[0])
        ratio = r["samples_per_s"] / one["samples_per_s"] * gpus[0]
        print(f"| {r['task']} | {r['gpus']} | {r['global_batch']} | {r['samples_per_s']:.0f} | {ratio:.2f}x | "
              f"{ratio / r['gpus']:.0%} |")
    print("RESULT " + json.dumps(result))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="half", required=True)
    f = sub.add_parser("factory", help="dataset build: local backend, 1 and 2 Ray workers")
    f.add_argument("--simulation", type=Path, required=True, help="a finished shirt/walk simulation folder")
    f.add_argument("--out", type=Path, default=Path("out/bench_scale"))
    f.add_argument("--frames", type=int, default=4)
    f.add_argument("--variations", type=int, default=2)
    f.add_argument("--resolution", type=int, default=256)
    f.add_argument("--engine", default="CYCLES", choices=("CYCLES", "EEVEE", "WORKBENCH"))
    f.add_argument("--samples", type=int, default=16)
    t = sub.add_parser("training", help="training samples/s with 1, 2, ... GPUs (torchrun, DDP)")
    t.add_argument("--rendered", type=Path, required=True, help="a factory dataset folder: its garment's marker IDs are synthesized")
    t.add_argument("--out", type=Path, default=Path("out/bench_scale_training"))
    t.add_argument("--gpus", default="1,2", help="GPU counts to compare, the first the baseline")
    t.add_argument("--tasks", default="recognizer,crosspoints,localizer", help="networks to train")
    t.add_argument("--steps", type=int, default=200, help="steps of each run")
    t.add_argument("--warmup", type=int, default=60, help="steps left out of the timing")
    t.add_argument("--device", default="cuda", choices=("cuda", "cpu"),
                   help="cpu: --gpus counts gloo processes (a check of this script, or CPU DDP throughput)")
    t.add_argument("--workers", type=int, help="data workers per rank (default: the cores shared by the most ranks)")
    t.add_argument("--shard-images", type=int, help="synthetic images per shard folder (default: per task)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    factory(args) if args.half == "factory" else training(args)


if __name__ == "__main__":
    main()
