"""Inference time of the three networks with NCHW (PyTorch's default) and NHWC (channels_last)
convolutions, side by side, on the CPU (or `--device`): the baseline for `networks.Detector` putting its
networks in channels_last on every device.  (`benchmarks/memory_format.py` measures training on a GPU.)

Each network runs under `torch.inference_mode()` in float32 on random inputs of the Detector's shapes:
the localizer on one `--image`-pixel square image, the recognizer on `--crops` 96 x 96 crops, the
crosspoint network on `--crops` pairs of 112 x 112 crops; one warm-up call, then `--repeats` timed
calls, the two layouts alternated `--rounds` times so drift in the machine's speed hits both.  Untrained
networks of the factory shirt's ID count unless `--weights DIR` holds localizer.pt, recognizer.pt and
crosspoints.pt (`python -m networks.weights fetch --out DIR`).

    python benchmarks/inference_layout.py [--weights out/weights] [--image 1024] [--crops 32]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from networks.checkpoint import load_checkpoint  # noqa: E402
from networks.tasks import build_model  # noqa: E402

TASKS = ("localizer", "recognizer", "crosspoints")
LAYOUTS = {"NCHW": torch.contiguous_format, "NHWC (channels_last)": torch.channels_last}
NUM_IDS = 4096


def networks(weights: Path | None) -> dict[str, torch.nn.Module]:
    """The three networks, trained (from `weights`) or untrained."""
    if weights is None:
        return {task: build_model(task, NUM_IDS, 25).eval() for task in TASKS}
    return {task: load_checkpoint(weights / f"{task}.pt", expected_task=task)[0].eval() for task in TASKS}


def inputs(task: str, image: int, crops: int) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(0)
    if task == "localizer":
        return (torch.randn(1, 3, image, image, generator=g),)
    if task == "recognizer":
        return (torch.randn(crops, 3, 96, 96, generator=g),)
    return torch.randn(crops, 3, 112, 112, generator=g), torch.randn(crops, 3, 112, 112, generator=g)


def seconds(model: torch.nn.Module, args: tuple[torch.Tensor, ...], layout: torch.memory_format,
            repeats: int, device: torch.device) -> float:
    """Mean seconds of one call of `model` on `args`, both in `layout`."""
    model = model.to(device, memory_format=layout)
    args = tuple(a.to(device).contiguous(memory_format=layout) for a in args)
    with torch.inference_mode():
        model(*args)
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        for _ in range(repeats):
            model(*args)
        if device.type == "cuda":
            torch.cuda.synchronize()
    return (time.perf_counter() - start) / repeats


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--weights", type=Path, help="a folder of localizer.pt, recognizer.pt, crosspoints.pt")
    parser.add_argument("--image", type=int, default=1024, help="the localizer's image side, pixels")
    parser.add_argument("--crops", type=int, default=32, help="crops per recognizer and crosspoint call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    if args.image < 64 or args.image % 8 or args.crops < 1 or args.repeats < 1 or args.rounds < 1:
        parser.error("--image: a multiple of 8 from 64; --crops, --repeats, --rounds: at least 1")
    device = torch.device(args.device)
    models = networks(args.weights)
    print(f"# inference layout, {device}, torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"{'weights ' + str(args.weights) if args.weights else 'untrained networks'}\n")
    print("| network | input | " + " | ".join(f"{name} s" for name in LAYOUTS) + " | NHWC / NCHW |")
    print("|---|---|" + "---|" * (len(LAYOUTS) + 1))
    for task in TASKS:
        batch = inputs(task, args.image, args.crops)
        times = {name: [] for name in LAYOUTS}
        for _ in range(args.rounds):
            for name, layout in LAYOUTS.items():
                times[name].append(seconds(models[task], batch, layout, args.repeats, device))
        best = {name: min(values) for name, values in times.items()}
        shape = " + ".join("x".join(map(str, a.shape)) for a in batch)
        nchw, nhwc = best.values()
        print(f"| {task} | {shape} | " + " | ".join(f"{best[n]:.4g}" for n in LAYOUTS) + f" | {nhwc / nchw:.2f} |",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
