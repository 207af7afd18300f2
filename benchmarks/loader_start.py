"""How long does a DataLoader take to deliver its first batches, by worker start method?  Same run,
side by side: workers from the fork server (`networks.workers.worker_context`, what training uses),
spawned (the baseline before it) and plainly forked, with and without pinned memory, in a process
that has imported torch and (on a GPU machine) initialised CUDA, as `networks.train` has when its
loader starts.

Items cost nothing (a 256 x 256 image of zeros and an 11-channel cell grid, as the localizer's), so
the times are the workers' start alone.  In the eighth GPU run's logs (`networks.train`'s start-up
record) the localizer's first batch came 29-30 s after its loop began, and its 50th step at 39 s.

    python benchmarks/loader_start.py [--workers 7] [--batches 14]

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

import torch  # noqa: E402
from torch.utils.data import DataLoader, Dataset  # noqa: E402

from networks.workers import one_thread, worker_context  # noqa: E402


class Zeros(Dataset):
    """Localizer-shaped items that cost nothing to make."""

    def __len__(self) -> int:
        return 1 << 20

    def __getitem__(self, index: int) -> dict:
        return {"image": torch.zeros(3, 256, 256, dtype=torch.uint8), "cells": torch.zeros(32, 32, 11)}


def first_batches(context: str, workers: int, batches: int, pin: bool) -> dict:
    started = time.perf_counter()
    method = worker_context("networks.train") if context == "fork server" else multiprocessing.get_context(
        "spawn" if context == "spawn" else "fork")
    loader = DataLoader(Zeros(), batch_size=32, num_workers=workers, multiprocessing_context=method,
                        worker_init_fn=one_thread, persistent_workers=True, pin_memory=pin)
    times = []
    for k, _ in enumerate(loader):
        times.append(time.perf_counter() - started)
        if k + 1 == batches:
            break
    del loader
    return {"first_batch_s": times[0], "all_workers_s": times[min(workers, batches) - 1], "last_s": times[-1]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=7)
    parser.add_argument("--batches", type=int, default=14)
    args = parser.parse_args(argv)
    cuda = torch.cuda.is_available()
    if cuda:
        torch.zeros(1, device="cuda")  # as the trainer: CUDA is up before its loader starts
    rows = []
    # the fork server first: it is started once per process, so its row includes the server's start
    for context in ("fork server", "spawn", "fork"):
        for pin in ((False, True) if cuda else (False,)):
            times = first_batches(context, args.workers, args.batches, pin)
            rows.append({"context": context, "pin_memory": pin, **times})
    device = torch.cuda.get_device_name() if cuda else "CPU"
    machine = f"{platform.node()}, {device}, {multiprocessing.cpu_count()} CPUs"
    print(f"# DataLoader start, {time.strftime('%Y-%m-%d')}, {machine}, {args.workers} workers, "
          f"torch {torch.__version__}")
    print("| workers from | pin memory | first batch s | one batch from every worker s | batch "
          f"{args.batches} s |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['context']} | {'yes' if r['pin_memory'] else 'no'} | {r['first_batch_s']:.2f} | "
              f"{r['all_workers_s']:.2f} | {r['last_s']:.2f} |")
    print("RESULT " + json.dumps({"machine": machine, "workers": args.workers, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
