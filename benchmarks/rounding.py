"""Which of a network's weights its accuracy needs in full precision: round chosen parts of a checkpoint
coarser (`--bits`, symmetric per output channel, as `networks.checkpoint.quantize_weights` does at 8)
and evaluate each copy on a dataset split beside the checkpoint as it is (`networks.evaluate`).

A part is a key prefix of the state dict (``head``, ``backbone``, ``head.out``, ``backbone.layer4``);
``none`` is the baseline.  Rounding to fewer bits than a compact checkpoint's 8 magnifies what the
8 bits cost, so the parts whose rounding moves the metrics are those to keep float
(`networks.checkpoint.FLOAT_WEIGHTS`).  The table gives the localizer's precision, recall and point
errors on fully visible markers, the recognizer's top-1, the crosspoint network's crop error.

    python benchmarks/rounding.py --checkpoint store/localizer.pt --data /tmp/h20h/heldout --split heldout \\
        --bits 6 --parts none,head,backbone,head.out,head.conv
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from networks.checkpoint import dequantize_weights, quantize_weights, read_checkpoint  # noqa: E402
from networks.evaluate import evaluate  # noqa: E402

POINTS = ("centre", "TL", "TR", "BL", "BR")


def rounded_state(state: dict[str, torch.Tensor], part: str, bits: int) -> dict[str, torch.Tensor]:
    """`state` with the weights (2 or more dimensions) under the key prefix `part` rounded to `bits`
    bits as a compact checkpoint rounds them (`quantize_weights`), back in float32 ("none": none)."""
    under = {key: value for key, value in state.items() if part != "none" and key.startswith(f"{part}.")}
    return {**state, **dequantize_weights(*quantize_weights(under, bits=bits))}


def summary(task: str, metrics: dict) -> list[str]:
    """The table's cells of one evaluation."""
    if task == "localizer":
        full = metrics["full"]
        return [f"{full['precision']:.4f}", f"{full['recall']:.4f}",
                ", ".join(f"{full['error_px'][p]['median']:.3f}" for p in POINTS)]
    if task == "recognizer":
        return [f"{metrics['top1']:.4f}"]
    return [f"{metrics['crop_error_px']['median']:.3f}", f"{metrics['crop_error_px']['p95']:.2f}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, required=True, help="a checkpoint (a compact one reads as float)")
    parser.add_argument("--data", type=Path, required=True, help="a dataset folder (networks.evaluate --data)")
    parser.add_argument("--split", default="test")
    parser.add_argument("--bits", type=int, default=6, help="bits of the coarser rounding (2-8)")
    parser.add_argument("--parts", default="none,head,backbone", help="comma-separated key prefixes; none: the baseline")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    if not 2 <= args.bits <= 8:
        parser.error(f"--bits {args.bits}: give 2 to 8")
    data = read_checkpoint(args.checkpoint)
    task, state = data["task"], data["model"]
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    unknown = [p for p in parts if p != "none" and not any(k.startswith(f"{p}.") for k in state)]
    if unknown:
        parser.error(f"--parts: {args.checkpoint} has no weights under {', '.join(unknown)}")
    heads = {"localizer": ["precision, full", "recall, full", f"median px {', '.join(POINTS)}"],
             "recognizer": ["top-1"], "crosspoints": ["crop median px", "crop p95 px"]}[task]
    print(f"# {args.checkpoint} ({task}, step {data.get('step')}) on {args.data} [{args.split}], "
          f"parts rounded to {args.bits} bits per output channel\n")
    print("| rounded | weights | " + " | ".join(heads) + " |")
    print("|---|---|" + "---|" * len(heads))
    with tempfile.TemporaryDirectory() as tmp:
        for part in parts:
            model = rounded_state(state, part, args.bits)
            count = sum(v.numel() for k, v in state.items() if v.dim() >= 2 and part != "none"
                        and k.startswith(f"{part}."))
            path = Path(tmp) / f"{part}.pt"
            torch.save({**data, "model": model, "int8_scales": {}}, path)
            metrics = evaluate(path, args.data, split=args.split, device=args.device, progress=False)
            print(f"| {part} | {count:,} | " + " | ".join(summary(task, metrics)) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
