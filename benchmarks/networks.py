"""Benchmark the three networks (issue 7), on a GPU machine: train, evaluate on Blender renders, time
inference.

1. Train the Marker Localizer, Marker Recognizer and Crosspoint Localizer on the procedural
   synthesizer (`--data synth`), all three at once on one GPU (each with its own data workers), for a
   short schedule capped by `--minutes`.
   The localizer is also trained on the rendered dataset's train split mixed half and half with
   synthesized images, and on the rendered train split alone: which mix trains best.
2. Evaluate each on the rendered dataset's validation and test images (`--rendered`, a factory
   dataset folder of Blender renders; its `samples/` are rebuilt from the images and saved ground
   truth when missing, so only images, gt and template.npz need to travel).
3. Inference throughput of `networks.Detector` (all three chained) on synthesized 1024 x 1024 and
   2048 x 2048 images, on the GPU and on the CPU.

    python benchmarks/networks.py --rendered .bench/rendered --out out/bench_networks [--minutes 5]

Prints the tables of `benchmarks/RESULTS.md` and a `RESULT {json}` line; writes `results.json` and
the training logs to `--out`.  The rendered dataset must use the codebook this machine generates:
`--codebook-hash` (the hash printed on the machine that rendered it) stops the run early otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from assets.fileio import save_json, save_npz  # noqa: E402
from assets.pattern.observation import ImageGroundTruth, training_samples  # noqa: E402
from networks.checkpoint import codebook_hash  # noqa: E402
from networks.config import TrainConfig  # noqa: E402
from networks.data import dataset_spec  # noqa: E402
from networks.evaluate import evaluate  # noqa: E402
from networks.synth import PatternSynthesizer, SynthConfig  # noqa: E402

#: the short schedule: (steps, batch size, synthesized localizer image side); Adam at LR, warm-up
SCHEDULE = {"localizer": (3000, 16, 256), "recognizer": (2000, 64, 256), "crosspoints": (2000, 32, 256)}
LR, WARMUP = 3e-4, 100
#: the training runs: name -> (task, data, synth weight).  The localizer is trained three ways to see
#: which mix trains best: synthesized only, half rendered (the rendered train split) and rendered only.
RUNS = {"localizer": ("localizer", "synth", 1.0), "localizer_mix": ("localizer", "rendered", 0.5),
        "localizer_rendered": ("localizer", "rendered", 0.0), "recognizer": ("recognizer", "synth", 1.0),
        "crosspoints": ("crosspoints", "synth", 1.0)}


def rebuild_samples(root: Path) -> int:
    """Write `samples/<name>.npz` for every manifest entry that lacks it; returns how many."""
    spec = dataset_spec(root)
    made = 0
    for line in (root / "manifest.jsonl").read_text().splitlines():
        entry = json.loads(line)
        target = root / entry["samples"]
        if target.exists():
            continue
        image = cv2.imread(str(root / entry["image"]), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        save_npz(target, training_samples(image, ImageGroundTruth.load(root / entry["gt"]), spec))
        made += 1
    return made


def heldout(root: Path, limit: int | None = None) -> Path:
    """A view of the rendered dataset holding its validation and test images (the first `limit`) as
    the split 'heldout': the mixed runs train on its train split."""
    view = root.parent / f"{root.name}_heldout"
    view.mkdir(exist_ok=True)
    for name in ("images", "gt", "samples", "template.npz", "config.json", "meta"):
        link = view / name
        if not link.exists():
            link.symlink_to((root / name).resolve())
    entries = [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines() if line]
    entries = [dict(e, split="heldout") for e in entries if e["split"] != "train"][:limit]
    (view / "manifest.jsonl").write_text("".join(json.dumps(e) + "\n" for e in entries))
    return view


def train_all(out: Path, rendered: Path, minutes: float, workers: int, device: str,
              max_steps: int | None) -> dict[str, dict]:
    """Every run of RUNS at once (one process each); returns per run its wall time, steps and first and
    last logged loss."""
    processes = {}
    for name, (task, data, synth_weight) in RUNS.items():
        steps, batch, size = SCHEDULE[task]
        steps = min(steps, max_steps or steps)
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        config = TrainConfig(task=task, steps=steps, batch_size=batch, image_size=size, lr=LR, warmup_steps=WARMUP,
                             num_workers=workers, val_every=steps, val_samples=16 if max_steps else 512,
                             checkpoint_every=steps, log_every=50, synth_weight=synth_weight)
        config.save(folder / "config.in.json")
        command = [sys.executable, "-m", "networks.train", task, "--data", "synth" if data == "synth" else str(rendered),
                   "--out", str(folder / "run"), "--config", str(folder / "config.in.json"), "--device", device,
                   "--time-limit", str(minutes * 60), "--quiet"]
        log = open(folder / "train.log", "w")
        processes[name] = (subprocess.Popen(command, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT),
                           time.perf_counter(), log)
    results = {}
    for name, (process, started, log) in processes.items():
        status = process.wait()
        log.close()
        text = (out / name / "train.log").read_text()
        if status != 0:  # recorded, and the other runs still count
            results[name] = {"error": f"exit status {status}: {text[-2000:]}"}
            continue
        records = [json.loads(line) for line in (out / name / "run" / "log.jsonl").read_text().splitlines() if line]
        steps = [r for r in records if "loss" in r]
        results[name] = {"seconds": time.perf_counter() - started, "summary": text.strip().splitlines()[-1],
                         "step": steps[-1]["step"] if steps else 0,
                         "first_loss": steps[0]["loss"] if steps else None,
                         "last_loss": steps[-1]["loss"] if steps else None}
    return results


def throughput(out: Path, device: str, sizes: tuple[int, ...], repeats: int) -> list[dict]:
    """Detector images per second on synthesized images of each size (after one warm-up call)."""
    from networks import Detector

    runs = {task: out / task / "run" / "last.pt" for task in SCHEDULE}  # the synthesizer-trained runs
    detector = Detector.from_checkpoints(runs["localizer"], runs["recognizer"], runs["crosspoints"], device=device)
    rows = []
    for size in sizes:
        synth = PatternSynthesizer(detector.spec, SynthConfig(image_size=(size, size), seed=7))
        images = [synth.sample(i)[0] for i in range(repeats)]
        detector(images[:1])
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        start = time.perf_counter()
        found = [len(d) for d in detector(images)]
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        seconds = time.perf_counter() - start
        rows.append({"device": device, "size": size, "images": repeats, "seconds": seconds,
                     "images_per_s": repeats / seconds, "markers_per_image": float(np.mean(found))})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rendered", type=Path, required=True, help="a factory dataset folder (Blender renders)")
    parser.add_argument("--out", type=Path, default=Path("out/bench_networks"))
    parser.add_argument("--minutes", type=float, default=5.0, help="training time cap per network (all at once)")
    parser.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) // len(RUNS)),
                        help="data workers per training process")
    parser.add_argument("--device", default="cuda", help="cpu: a smoke run of this script (with --max-steps)")
    parser.add_argument("--max-steps", type=int, help="cap every network's steps (smoke runs)")
    parser.add_argument("--eval-images", type=int, help="evaluate on the first N rendered images only (smoke runs)")
    parser.add_argument("--sizes", default="1024,2048", help="image sides for the throughput")
    parser.add_argument("--codebook-hash", help="the rendering machine's codebook hash; stop if this one differs")
    args = parser.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        sys.exit("benchmarks/networks.py trains on a CUDA GPU; none is visible")
    args.out.mkdir(parents=True, exist_ok=True)
    spec = dataset_spec(args.rendered)
    here = codebook_hash(spec)
    if args.codebook_hash and here != args.codebook_hash:
        sys.exit(f"codebook differs from the rendering machine's ({here} vs {args.codebook_hash}): the rendered "
                 "IDs would not be this machine's IDs")
    rebuilt = rebuild_samples(args.rendered)
    test = heldout(args.rendered, args.eval_images)
    t0 = time.perf_counter()
    training = train_all(args.out, args.rendered, args.minutes, args.workers, args.device, args.max_steps)
    train_s = time.perf_counter() - t0
    metrics = {name: evaluate(args.out / name / "run" / "last.pt", test, split="heldout", device=args.device,
                              progress=False)
               for name in RUNS if "error" not in training[name]}
    save_json(args.out / "results.json", {"training": training, "metrics": metrics})
    sizes = tuple(int(v) for v in args.sizes.split(","))
    speed = (throughput(args.out, "cuda", sizes, 4) if args.device.startswith("cuda") else []) + \
        throughput(args.out, "cpu", sizes, 1)
    gpu = torch.cuda.get_device_name() if torch.cuda.is_available() else "no GPU"
    result = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()}, {gpu}, "
              f"{os.cpu_count()} CPUs, torch {torch.__version__}", "codebook_hash": here, "samples_rebuilt": rebuilt,
              "schedule": {t: {"steps": s, "batch": b, "image": i, "lr": LR, "warmup": WARMUP}
                           for t, (s, b, i) in SCHEDULE.items()},
              "runs": {name: {"task": t, "data": d, "synth_weight": w} for name, (t, d, w) in RUNS.items()},
              "heldout_images": len((test / "manifest.jsonl").read_text().splitlines()),
              "train_wall_s": train_s, "training": training, "metrics": metrics, "throughput": speed}
    save_json(args.out / "results.json", result)

    print(f"# networks benchmark, {result['date']}, {result['machine']}")
    print("| run | data (synth weight) | steps done | train s | loss first -> last |")
    print("|---|---|---|---|---|")
    for name, r in training.items():
        task, data, weight = RUNS[name]
        if "error" in r:
            print(f"| {name} | {data} ({weight}) | failed: {r['error'][-200:]!r} | | |")
            continue
        print(f"| {name} | {data} ({weight}) | {r['step']} of {SCHEDULE[task][0]} | {r['seconds']:.0f} | "
              f"{r['first_loss']:.4g} -> {r['last_loss']:.4g} |")
    print(f"\n| metric ({result['heldout_images']} held-out Blender renders) | value |\n|---|---|")
    for task, m in metrics.items():
        for key, value in _flatten(m):
            if isinstance(value, float) and not key.endswith("step"):
                print(f"| {task}.{key} | {value:.4g} |")
    print("\n| device | image | images/s | markers/image |\n|---|---|---|---|")
    for r in speed:
        print(f"| {r['device']} | {r['size']} x {r['size']} | {r['images_per_s']:.3g} | {r['markers_per_image']:.0f} |")
    print("RESULT " + json.dumps(result, default=float))


def _flatten(d: dict, prefix: str = "") -> list[tuple[str, object]]:
    items = []
    for key, value in d.items():
        name = f"{prefix}{key}"
        items += _flatten(value, name + ".") if isinstance(value, dict) else [(name, value)]
    return items


if __name__ == "__main__":
    main()
