"""Does the localizer's view warp (`networks.augment.ViewWarp`) help it generalise?  Same call, side by
side: the Marker Localizer trained for the same steps from the same start with and without the warp
(the baseline), both evaluated on the held-out renders (the validation and test images), which
neither sees.

The localizer learns its rendered training images by heart (RESULTS.md, seventh and eighth GPU runs:
validation loss flat after 3,000 steps at about five times the training loss), so the arms train on
the rendered train split alone by default (`--synth-weight 0`), where the warp is the only
difference; `--init` starts both from a trained localizer (a fine-tune), else from scratch.

    python benchmarks/view_warp.py --rendered .bench/rendered2 --out /tmp/vw --init localizer_mix.pt \
        --steps 1200 [--device cuda] [--workers 7] [--time-limit-s 200]

The rendered folder needs images, gt, meta, template.npz, config.json, splits.json and
manifest.jsonl; the localizer's samples (cells only) are made in --out from the ground truth, so no
crop needs building.  Both arms run at once (on one GPU, or one after another on the CPU).  Prints
a table and a `RESULT {json}` line; writes results.json to --out.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from assets.fileio import save_json, save_npz  # noqa: E402
from assets.pattern.observation import ImageGroundTruth, localizer_targets  # noqa: E402
from networks.config import TrainConfig  # noqa: E402
from networks.evaluate import evaluate, read_manifest  # noqa: E402

# benchmarks/networks.py, whose held-out view of a rendered folder this benchmark shares (by path:
# its module name is the networks package's)
_spec = importlib.util.spec_from_file_location("bench_networks", ROOT / "benchmarks" / "networks.py")
bench_networks = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_networks)

ARMS = {"no warp (baseline)": False, "view warp": True}
FILES = ("images", "gt", "meta", "template.npz", "config.json", "splits.json", "manifest.jsonl")


def localizer_folder(rendered: Path, out: Path) -> Path:
    """A dataset folder `out/rendered` for the localizer: the rendered folder's files linked and
    samples holding only the cells (`localizer_targets` of each image's ground truth)."""
    view = out / "rendered"
    (view / "samples").mkdir(parents=True, exist_ok=True)
    for item in FILES:
        if not (view / item).exists():
            (view / item).symlink_to((rendered / item).resolve())
    for e in read_manifest(rendered):
        target = view / e["samples"]
        if not target.exists():
            save_npz(target, {"cells": localizer_targets(ImageGroundTruth.load(rendered / e["gt"]))})
    return view


def arm_config(warp: bool, args: argparse.Namespace) -> TrainConfig:
    return TrainConfig(task="localizer", steps=args.steps, batch_size=args.batch, image_size=256, lr=args.lr,
                       warmup_steps=min(300, args.steps // 10), synth_weight=args.synth_weight, view_warp=warp,
                       init=str(args.init.resolve()) if args.init else None, num_workers=args.workers,
                       val_every=args.steps, val_samples=64, checkpoint_every=args.steps, log_every=50)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rendered", type=Path, required=True, help="a factory dataset folder (Blender renders)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--init", type=Path, help="a localizer checkpoint both arms start from (default: scratch)")
    parser.add_argument("--steps", type=int, default=1200)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--synth-weight", type=float, default=0.0, help="share of synthesized images (on the fly)")
    parser.add_argument("--workers", type=int, default=4, help="data workers per arm")
    parser.add_argument("--time-limit-s", type=float, help="stop each arm after this long (the table says the steps)")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    train_view = localizer_folder(args.rendered, args.out)
    heldout = bench_networks.heldout(train_view, args.out)  # its validation and test images
    processes = {}
    for arm, warp in ARMS.items():
        folder = args.out / ("warp" if warp else "plain")
        if folder.exists():
            shutil.rmtree(folder)  # a fresh arm: the comparison is of whole runs
        folder.mkdir(parents=True)
        arm_config(warp, args).save(folder / "config.in.json")
        command = [sys.executable, "-m", "networks.train", "localizer", "--data", str(train_view),
                   "--out", str(folder / "run"), "--config", str(folder / "config.in.json"), "--device", args.device,
                   "--quiet"] + (["--time-limit", str(args.time_limit_s)] if args.time_limit_s else [])
        log = open(folder / "train.log", "w")
        processes[arm] = (subprocess.Popen(command, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT), log, folder)
        if args.device == "cpu":
            processes[arm][0].wait()
    rows = {}
    for arm, (process, log, folder) in processes.items():
        status = process.wait()
        log.close()
        if status != 0:
            raise RuntimeError(f"{arm}: training failed; see {folder / 'train.log'}:\n"
                               + (folder / "train.log").read_text()[-2000:])
        records = [json.loads(line) for line in (folder / "run" / "log.jsonl").read_text().splitlines()]
        losses = [r for r in records if "loss" in r]
        metrics = evaluate(folder / "run" / "last.pt", heldout, split="heldout", device=args.device, progress=False)
        rows[arm] = {"step": losses[-1]["step"], "seconds": losses[-1]["elapsed_s"],
                     "train_loss_last_100": sum(r["loss"] for r in losses[-2:]) / len(losses[-2:]), **metrics}
    result = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()}, "
              f"{torch.cuda.get_device_name() if args.device.startswith('cuda') else 'CPU'}",
              "init": str(args.init) if args.init else None, "steps": args.steps, "batch": args.batch,
              "synth_weight": args.synth_weight, "heldout_images": len((heldout / "manifest.jsonl").read_text().splitlines()),
              "arms": rows, "wall_s": time.perf_counter() - started}
    save_json(args.out / "results.json", result)
    print(f"# view warp A/B, {result['date']}, {result['machine']}, {args.steps} steps of {args.batch}, synth weight "
          f"{args.synth_weight}, from {'init ' + args.init.name if args.init else 'scratch'}")
    print("| arm | steps, s | train loss (last 100 steps) | held-out loss | fully visible P / R / F1 | all F1 "
          "| centre / corner median px (fully visible) |")
    print("|---|---|---|---|---|---|---|")
    for arm, r in rows.items():
        full, every = r["full"], r["all"]
        corners = [full["error_px"][k]["median"] for k in ("TL", "TR", "BL", "BR")]
        print(f"| {arm} | {r['step']}, {r['seconds']:.0f} | {r['train_loss_last_100']:.3f} | {r['loss']['total']:.3f} | "
              f"{full['precision']:.3f} / {full['recall']:.3f} / {full['f1']:.3f} | {every['f1']:.3f} | "
              f"{full['error_px']['centre']['median']:.2f} / {min(corners):.2f}-{max(corners):.2f} |")
    print("RESULT " + json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
