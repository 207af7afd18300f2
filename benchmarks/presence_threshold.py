"""Choose the Marker Localizer's presence threshold on one split and check it on another.

The reference thresholds presence at 0.5 (`DetectorConfig.presence_threshold`).  A localizer whose
presence probability is conservative (precision 0.999, recall 0.987 on fully visible held-out markers)
finds more markers at a lower threshold, and reading the best threshold off the test renders
themselves is no way to choose it.  This sweeps the thresholds on the choosing split (`--choose-split`,
default val), takes the one with the best F1 on fully visible markers (a tie goes to the higher
threshold, the nearer the reference), and evaluates it beside the reference's 0.5 on the test split
(`networks.evaluate`).

    python benchmarks/presence_threshold.py --checkpoint store/localizer.pt --data .bench/rendered_m \\
        [--thresholds 0.2,0.3,0.4,0.5] [--choose-split val] [--test-split test] [--device cpu]

Prints a table per split and a `RESULT {json}` line.  CPU or GPU; the localizer runs once per split,
decoded at every threshold (`networks.evaluate.evaluate_at`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from networks.evaluate import evaluate_at  # noqa: E402

REFERENCE = 0.5
#: the thresholds swept by default (`thresholds_arg` adds the reference)
DEFAULT_THRESHOLDS = "0.2,0.3,0.35,0.4,0.45,0.5"
POINTS = ("centre", "TL", "TR", "BL", "BR")


def thresholds_arg(text: str) -> list[float]:
    """'0.2,0.3,0.5' -> sorted distinct thresholds in (0, 1); the reference's 0.5 is always among them."""
    try:
        values = {float(item) for item in text.split(",") if item.strip()}
    except ValueError:
        raise argparse.ArgumentTypeError(f"--thresholds: {text!r} is not a comma-separated list of numbers")
    outside = sorted(v for v in values if not 0 < v < 1)
    if outside:
        raise argparse.ArgumentTypeError(f"--thresholds: {outside} are not in (0, 1)")
    return sorted(values | {REFERENCE})


def choose(metrics: dict[float, dict]) -> float:
    """The threshold whose fully visible markers' F1 is highest in `metrics` (threshold -> the
    localizer's `networks.evaluate` metrics); of equal F1, the highest threshold."""
    if not metrics:
        raise ValueError("no thresholds were evaluated")
    return max(metrics, key=lambda t: (round(metrics[t]["full"]["f1"], 9), t))


def row(threshold: float, metrics: dict, mark: str = "") -> str:
    full, every = metrics["full"], metrics["all"]
    corners = ", ".join(f"{full['error_px'][p]['median']:.2f}" for p in POINTS)
    return (f"| {threshold:g}{mark} | {full['precision']:.4f} / {full['recall']:.4f} / {full['f1']:.4f} | "
            f"{every['precision']:.4f} / {every['recall']:.4f} | {full.get('on_other_markers', 0)} | {corners} |")


HEADER = ("| threshold | fully visible P / R / F1 | all markers P / R | predictions on partial markers | "
          "median px centre, TL, TR, BL, BR |\n|---|---|---|---|---|")


def sweep(checkpoint: Path, data: Path, thresholds: list[float], choose_split: str = "val",
          test_split: str = "test", device: str = "cpu") -> dict:
    """The localizer `checkpoint` on `data`'s `choose_split` at each of `thresholds` (`networks.evaluate`),
    the threshold chosen there (`choose`), and that one and the reference's on `test_split`:
    {"chosen", "choose_split", "test_split", "choose": {t: metrics}, "test": {t: metrics}}."""
    if choose_split == test_split:
        raise ValueError("the threshold must be chosen on another split than the one it is tested on: a "
                         "threshold read off its test split proves nothing")

    def measure(split: str, wanted: list[float]) -> dict[float, dict]:  # one localizer pass per split
        metrics = evaluate_at(checkpoint, data, wanted, split=split, task="localizer", device=device, progress=False)
        full = metrics[wanted[0]]["full"]
        if full["true_positive"] + full["false_negative"] == 0:
            raise ValueError(f"{data}: the split {split!r} has no fully visible markers")
        return metrics

    chosen_metrics = measure(choose_split, sorted(set(thresholds) | {REFERENCE}))
    chosen = choose(chosen_metrics)
    return {"chosen": chosen, "choose_split": choose_split, "test_split": test_split, "choose": chosen_metrics,
            "test": measure(test_split, sorted({chosen, REFERENCE}))}


def print_sweep(result: dict, title: str) -> None:
    """`sweep`'s two tables under `title`."""
    chosen = float(result["chosen"])  # the keys are strings once the result went through JSON

    def mark(t: float) -> str:
        return " (chosen)" if t == chosen else " (reference)" if t == REFERENCE else ""

    print(f"{title}\n\n## chosen on {result['choose_split']!r} (best F1 on fully visible markers: {chosen:g})\n"
          f"{HEADER}")
    for t, m in result["choose"].items():
        print(row(float(t), m, mark(float(t))))
    print(f"\n## checked on {result['test_split']!r}, beside the reference\n{HEADER}")
    for t, m in result["test"].items():
        print(row(float(t), m, mark(float(t))))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, required=True, help="a localizer checkpoint")
    parser.add_argument("--data", type=Path, required=True, help="a factory dataset folder with both splits")
    parser.add_argument("--thresholds", type=thresholds_arg, default=thresholds_arg(DEFAULT_THRESHOLDS))
    parser.add_argument("--choose-split", default="val", help="the split the threshold is chosen on")
    parser.add_argument("--test-split", default="test", help="the split it is checked on")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    try:
        result = sweep(args.checkpoint, args.data, args.thresholds, args.choose_split, args.test_split, args.device)
    except ValueError as exc:
        sys.exit(str(exc))
    print_sweep(result, f"# presence threshold of {args.checkpoint.name} on {args.data}")
    print("RESULT " + json.dumps({"checkpoint": str(args.checkpoint), "data": str(args.data), **result,
                                  "choose": {str(t): m for t, m in result["choose"].items()},
                                  "test": {str(t): m for t, m in result["test"].items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
