"""Rendered training items read per image (the baseline) against decoded ahead into one memory-mapped
file (`RenderedDataset(decode_ahead=True)`, `networks.decoded`), same run, side by side: the time
to make the dataset, the CPU time per item in this process, and the items per second a DataLoader's
workers deliver (the fork server, as `networks.train`).  Items as the benchmark's main runs train on
them (`TASK_SETTINGS`), augmented: the localizer's 256 px crops or view warps, the recognizer's
jittered crops of whole and partial markers (`recognizer_partial`), the crosspoint network's jittered
crops (`crosspoints_jitter`, `crosspoints_rendered`).

    python benchmarks/decode_ahead.py --data .bench/rendered_i [--task crosspoints] [--items 300] [--workers 2]

Prints a table and a `RESULT {json}` line.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch.utils.data import DataLoader, Subset  # noqa: E402

from networks.augment import Augment, ViewWarp  # noqa: E402
from networks.data import RenderedDataset, dataset_spec  # noqa: E402
from networks.workers import one_thread, worker_context  # noqa: E402


#: how each task's items are cut for the benchmark's main runs (the localizer's crop size apart)
TASK_SETTINGS = {"localizer": {"view_warp": ViewWarp()},
                 "recognizer": {"crop_jitter_px": 1.0, "partial_markers": True},
                 "crosspoints": {"crop_jitter_px": 1.0}}


def measure(data: Path, items: int, workers: int, crop_px: int = 256, seed: int = 0,
            task: str = "localizer") -> list[dict]:
    """One row per loader: seconds to make the dataset, ms per item in this process, items/s from
    `workers` DataLoader workers (0: none), over the same `items` random items of `task`'s train split."""
    spec = dataset_spec(data)
    settings = {**TASK_SETTINGS[task], **({"crop_px": crop_px} if task == "localizer" else {})}
    rows = []
    for name, ahead in (("read per image", False), ("decoded ahead", True)):
        started = time.perf_counter()
        dataset = RenderedDataset(data, "train", task, augment=Augment(), spec=spec, seed=seed,
                                  decode_ahead=ahead, **settings)
        made_s = time.perf_counter() - started
        order = np.random.default_rng(seed).integers(0, len(dataset), items)
        started = time.perf_counter()
        for i in order:
            dataset[int(i)]
        item_ms = 1000 * (time.perf_counter() - started) / items
        row = {"loader": name, "task": task, "images": len(dataset.entries), "made_s": made_s, "item_ms": item_ms,
               "decoded_mib": dataset.decoded_bytes / 2**20}
        if workers:
            loader = DataLoader(Subset(dataset, order.tolist()), batch_size=16, num_workers=workers,
                                multiprocessing_context=worker_context("networks.train"), worker_init_fn=one_thread)
            batches = iter(loader)
            next(batches)  # the workers' start is not the items' cost
            started, count = time.perf_counter(), 0
            for batch in batches:
                count += len(next(iter(batch.values())))
            row["loader_items_per_s"] = count / (time.perf_counter() - started)
            del batches, loader
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="a factory dataset folder with a train split")
    parser.add_argument("--items", type=int, default=300)
    parser.add_argument("--workers", type=int, default=2, help="DataLoader workers (0: no loader row)")
    parser.add_argument("--task", choices=sorted(TASK_SETTINGS), default="localizer")
    parser.add_argument("--crop-px", type=int, default=256, help="the localizer's crop size")
    args = parser.parse_args(argv)
    if args.workers and args.items < 32:
        parser.error(f"--items {args.items}: at least 32 with workers (the first batch of 16 is not counted)")
    if not (args.data / "manifest.jsonl").is_file():
        parser.error(f"{args.data}: no manifest.jsonl (not a factory dataset folder)")
    rows = measure(args.data, args.items, args.workers, args.crop_px, task=args.task)
    machine = f"{platform.node()}, {multiprocessing.cpu_count()} CPUs, torch {torch.__version__}"
    print(f"# {args.task} items decoded ahead, {time.strftime('%Y-%m-%d')}, {machine}, {args.data}, "
          f"{rows[0]['images']} images, {args.items} items, {args.workers} workers")
    print("| loader | dataset made s | decoded MiB | ms per item (one process) | items/s from the workers |\n"
          "|---|---|---|---|---|")
    for r in rows:
        per_s = f"{r['loader_items_per_s']:.0f}" if "loader_items_per_s" in r else "-"
        print(f"| {r['loader']} | {r['made_s']:.1f} | {r['decoded_mib']:.0f} | {r['item_ms']:.1f} | {per_s} |")
    print("RESULT " + json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
