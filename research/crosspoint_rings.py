"""Where in the crop does the crosspoint network err?  Its error by ring of the 25 x 25 crosspoint grid:
ring 0 the outermost crosspoints (nearest the crop's edge, least context around them), ring 12 the
marker's centre.  On a shard folder of synthesized samples (`networks.shards write`: exact ground
truth, unlimited) or the crosspoint crops of a factory dataset's split.

    python research/crosspoint_rings.py --checkpoint .bench/weights15/crosspoints_jitter.pt --data /tmp/xs_exact
    python research/crosspoint_rings.py --checkpoint XP.pt --data .bench/rendered23 --split test --device cpu

Prints a table (ring, crosspoints, median and p95 crop error of the crosspoints visible in the ground
truth), a second one of the median error by ring group and by displacement (how far the true
crosspoint lies from its canonical crop position, the flat marker's: what the network must undo), and a
`RESULT {json}` line.  The second table tells the crop's edge from the deformation: if the outer rings
erred only because their crosspoints are displaced more, their error would match the inner rings' at
equal displacement.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from assets.pattern import crop_crosspoints_px  # noqa: E402
from networks.checkpoint import checkpoint_spec, load_checkpoint  # noqa: E402
from networks.evaluate import crosspoint_predictions, data_batches, model_crop, resolve_device  # noqa: E402
from networks.tasks import forward  # noqa: E402


def rings(k: int) -> np.ndarray:
    """(k, k) ring index of each crosspoint: its distance in grid steps to the nearest edge of the grid."""
    edge = np.minimum(np.arange(k), k - 1 - np.arange(k))  # per row (or column): steps to its nearer edge
    return np.minimum(edge[:, None], edge[None, :])


#: the ring groups and displacement bins (crop pixels) of the second table
RING_GROUPS = ((0, 0), (1, 2), (3, 5), (6, 12))
DISPLACEMENT_BINS = (0.0, 0.5, 1.0, 2.0, 4.0, np.inf)


def crop_errors(checkpoint: Path, data: Path, split: str = "test", device: str | None = None, batch_size: int = 32
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, K, K) crop-pixel error of every predicted crosspoint, (N, K, K) its ground-truth
    visibility and (N, K, K) its displacement (the distance of the true crosspoint from its canonical
    position in the network's crop), over a shard folder or a factory dataset's split."""
    device = resolve_device(device)
    model, _, saved = load_checkpoint(checkpoint, expected_task="crosspoints", device=device)
    spec = checkpoint_spec(saved)
    canonical = crop_crosspoints_px(spec, model_crop(model))
    errors, visible, displacement = [], [], []
    with torch.no_grad():
        for batch in data_batches("crosspoints", data, split, spec, batch_size, model_crop(model)):
            output, _, _ = forward("crosspoints", model, batch, device)
            _, xy = crosspoint_predictions(output)
            errors.append(np.linalg.norm(xy - batch["xy"].numpy(), axis=-1))
            visible.append(batch["visible"].numpy().astype(bool))
            displacement.append(np.linalg.norm(batch["xy"].numpy() - canonical, axis=-1))
    if not errors:
        raise ValueError(f"{data}: no crosspoint crops to measure")
    return np.concatenate(errors), np.concatenate(visible), np.concatenate(displacement)


def by_ring(errors: np.ndarray, visible: np.ndarray) -> list[dict]:
    """Per ring: the count and the median and 95th-percentile error of its visible crosspoints."""
    ring = np.broadcast_to(rings(errors.shape[-1]), errors.shape)
    rows = []
    for r in range(int(ring.max()) + 1):
        values = errors[(ring == r) & visible]
        rows.append({"ring": r, "crosspoints": int(values.size),
                     "median": float(np.median(values)) if values.size else None,
                     "p95": float(np.percentile(values, 95)) if values.size else None})
    return rows


def by_ring_and_displacement(errors: np.ndarray, visible: np.ndarray, displacement: np.ndarray) -> list[dict]:
    """Per ring group (`RING_GROUPS`, first to last ring inclusive): the median error and count of its
    visible crosspoints in each displacement bin (`DISPLACEMENT_BINS`, lower bound inclusive)."""
    ring = np.broadcast_to(rings(errors.shape[-1]), errors.shape)
    rows = []
    for first, last in RING_GROUPS:
        cells = []
        for low, high in zip(DISPLACEMENT_BINS[:-1], DISPLACEMENT_BINS[1:]):
            values = errors[(ring >= first) & (ring <= last) & visible & (displacement >= low) & (displacement < high)]
            cells.append({"low": low, "high": high, "crosspoints": int(values.size),
                          "median": float(np.median(values)) if values.size else None})
        rows.append({"rings": [first, last], "bins": cells})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", type=Path, required=True, help="a crosspoint network checkpoint")
    parser.add_argument("--data", type=Path, required=True, help="a shard folder or a factory dataset folder")
    parser.add_argument("--split", default="test", help="the dataset's split (not for shards)")
    parser.add_argument("--device", help="cuda or cpu (default: a CUDA GPU when there is one)")
    args = parser.parse_args(argv)
    errors, visible, displacement = crop_errors(args.checkpoint, args.data, args.split, args.device)
    rows = by_ring(errors, visible)
    print("| ring (0: the crop's edge) | crosspoints | crop error median px | p95 px |\n|---|---|---|---|")
    for row in rows:
        median = "-" if row["median"] is None else f"{row['median']:.3f}"
        p95 = "-" if row["p95"] is None else f"{row['p95']:.2f}"
        print(f"| {row['ring']} | {row['crosspoints']} | {median} | {p95} |")
    overall = float(np.median(errors[visible]))
    print(f"| all | {int(visible.sum())} | {overall:.3f} | {np.percentile(errors[visible], 95):.2f} |")
    grid = by_ring_and_displacement(errors, visible, displacement)
    bins = [f"{b['low']:g}-{b['high']:g} px" for b in grid[0]["bins"]]
    print("\n| rings \\ displacement | " + " | ".join(bins) + " |\n|---|" + "---|" * len(bins))
    for row in grid:
        cells = ["-" if b["median"] is None else f"{b['median']:.3f} ({b['crosspoints']:,})" for b in row["bins"]]
        print(f"| {row['rings'][0]}-{row['rings'][1]} | " + " | ".join(cells) + " |")
    print("RESULT " + json.dumps({"checkpoint": str(args.checkpoint), "data": str(args.data), "rings": rows,
                                  "by_displacement": grid, "median": overall}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
