"""Time of decoding a module reader's logits against the codebook (`networks.codes.CodeDecoder`).

For `--markers` crops (an image's worth, ~150 at 1080p) of random module logits, scored against every
candidate ID under its four rotations: the whole codebook (`--num-ids`, 4,096 by default) and a
garment's share of it (`--garment-ids`, 546 like the factory's shirt).  Construction (the candidates'
+-1 matrix) is timed apart; decode is the median of `--repeats` calls, on the CPU with one torch
thread and with torch's default threads (or `--device`).

    python benchmarks/code_decoding.py [--markers 150] [--num-ids 4096] [--device cpu]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from assets.pattern import PatternSpec, generate_codebook  # noqa: E402
from networks.codes import CodeDecoder  # noqa: E402


def measure(codebook: np.ndarray, candidates: np.ndarray | None, markers: int, repeats: int, device: str) -> dict:
    """{"build_ms", "decode_ms"} for `markers` random logit rows against `candidates` of `codebook`."""
    started = time.perf_counter()
    decoder = CodeDecoder(codebook, candidates, device)
    build_ms = (time.perf_counter() - started) * 1e3
    logits = torch.randn(markers, codebook.shape[1] ** 2, generator=torch.Generator().manual_seed(0)) * 4
    decoder.decode(logits)  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        reading = decoder.decode(logits)
        reading.marker_id.cpu()
        times.append((time.perf_counter() - started) * 1e3)
    return {"build_ms": build_ms, "decode_ms": float(np.median(times))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--markers", type=int, default=150)
    parser.add_argument("--num-ids", type=int, default=4096)
    parser.add_argument("--garment-ids", type=int, default=546)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    codebook = generate_codebook(PatternSpec(num_ids=args.num_ids))
    garment = np.arange(args.garment_ids)
    rows = []
    for threads in (1, torch.get_num_threads()):
        torch.set_num_threads(threads)
        for name, candidates in (("codebook", None), ("garment", garment)):
            count = args.num_ids if candidates is None else len(candidates)
            result = measure(codebook, candidates, args.markers, args.repeats, args.device)
            rows.append({"threads": threads, "candidates": name, "ids": count, "rotations": 4,
                         "markers": args.markers, **result})
    print(f"{'threads':>7} {'candidates':>10} {'IDs x rot':>10} {'markers':>7} {'build ms':>9} {'decode ms':>9}")
    for row in rows:
        print(f"{row['threads']:>7} {row['candidates']:>10} {row['ids']:>6} x 4 {row['markers']:>7} "
              f"{row['build_ms']:>9.2f} {row['decode_ms']:>9.3f}")
    print(json.dumps({"benchmark": "code_decoding", "device": args.device, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
