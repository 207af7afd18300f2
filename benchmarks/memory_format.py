"""Training step rate of the three networks with NCHW (PyTorch's default) and NHWC (channels_last)
convolutions, side by side, on one GPU: the baseline for `networks.train` and `networks.Detector`
putting their networks in channels_last on CUDA.

Each network trains on random tensors of the benchmark's batch shapes (`benchmarks/networks.py`
SCHEDULE and IMAGE_SIZE: localizer 32 x 256^2, recognizer 256 crops of 96^2, crosspoints 64 pairs of
112^2), bf16 autocast and Adam as in `networks.train`: `--warmup` steps, then `--steps` timed steps
(synchronised), for each memory format in turn.  Data loading is not part of it.

    python benchmarks/memory_format.py [--steps 40] [--warmup 10] [--device cuda]

Prints a table and a `RESULT {json}` line; `--json FILE` also writes it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from assets.fileio import save_json  # noqa: E402
from networks.tasks import autocast, build_model, forward  # noqa: E402

#: per task: (batch, the batch's tensors as (name, shape, dtype)); 546 classes as the factory's shirt
NUM_IDS = 4096
SHAPES = {
    "localizer": (32, {"image": ((3, 256, 256), torch.uint8), "cells": ((32, 32, 11), torch.float32)}),
    "recognizer": (256, {"crop": ((3, 96, 96), torch.uint8), "marker_id": ((), torch.int64)}),
    "crosspoints": (64, {"crop": ((3, 112, 112), torch.uint8), "reference": ((3, 112, 112), torch.uint8),
                         "xy": ((25, 25, 2), torch.float32), "visible": ((25, 25), torch.bool)}),
}


def make_batch(task: str, batch: int, device: torch.device) -> dict[str, torch.Tensor]:
    """Random tensors of the task's batch: images uniform, targets in range (cells: a marker in one
    cell of four, so the point losses have work)."""
    g = torch.Generator().manual_seed(0)
    out = {}
    for name, (shape, dtype) in SHAPES[task][1].items():
        full = (batch, *shape)
        if dtype == torch.uint8:
            out[name] = torch.randint(0, 256, full, generator=g, dtype=torch.uint8)
        elif dtype == torch.int64:
            out[name] = torch.randint(0, 546, full, generator=g)
        elif dtype == torch.bool:
            out[name] = torch.rand(full, generator=g) < 0.8
        else:
            out[name] = torch.rand(full, generator=g) * 8.0
    if task == "localizer":
        out["cells"][..., 0] = (torch.rand(out["cells"].shape[:-1], generator=g) < 0.25).float()
    if task == "crosspoints":
        out["xy"] *= 14.0  # crop pixels
    return {k: v.to(device) for k, v in out.items()}


def steps_per_s(task: str, layout: torch.memory_format, device: torch.device, steps: int, warmup: int) -> float:
    torch.manual_seed(0)
    model = build_model(task, NUM_IDS).to(device).to(memory_format=layout).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    batch = make_batch(task, SHAPES[task][0], device)

    def step() -> None:
        optimizer.zero_grad(set_to_none=True)
        with autocast(device, True):
            _, loss, _ = forward(task, model, batch, device)
        loss.backward()
        optimizer.step()

    for _ in range(warmup):
        step()
    if device.type == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--tasks", default=",".join(SHAPES))
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    device = torch.device(args.device)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            sys.exit("benchmarks/memory_format.py: no CUDA GPU visible (--device cpu for a smoke run)")
        torch.backends.cudnn.benchmark = True
    rows = []
    for task in args.tasks.split(","):
        nchw = steps_per_s(task, torch.contiguous_format, device, args.steps, args.warmup)
        nhwc = steps_per_s(task, torch.channels_last, device, args.steps, args.warmup)
        rows.append({"task": task, "batch": SHAPES[task][0], "nchw_steps_per_s": nchw, "nhwc_steps_per_s": nhwc,
                     "speedup": nhwc / nchw})
    name = torch.cuda.get_device_name() if device.type == "cuda" else "CPU"
    result = {"date": time.strftime("%Y-%m-%d"), "device": name, "torch": torch.__version__, "steps": args.steps,
              "rows": rows}
    print(f"# memory format, {result['date']}, {name}, torch {torch.__version__}, {args.steps} timed steps, bf16 autocast")
    print("\n| network | batch | NCHW steps/s (baseline) | channels_last steps/s | speed-up |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['task']} | {r['batch']} | {r['nchw_steps_per_s']:.2f} | {r['nhwc_steps_per_s']:.2f} | "
              f"{r['speedup']:.2f}x |")
    if args.json:
        save_json(args.json, result)
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
