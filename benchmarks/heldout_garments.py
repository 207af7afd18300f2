"""ID top-1 per garment (issue 46): a recognizer on every part of a recipe build, the held-out garments
included, beside the stored ID classifier (the baseline) in the same run.

Each part of the build (`factory.dataset build --recipe`; its recipe.json lists them) is a dataset
folder: a training part is measured on its test split, a held-out part on all its images (no network
saw them).  Top-1 is over the fully visible markers' crops (the issue's target: >= 0.995), decoded
against the whole codebook and against the garment's own IDs (the Detector's restriction).  With
--localizer and --crosspoints, each recognizer also runs chained in the Detector on the same images
(`networks.evaluate_detector`: the markers found, their IDs after the votes, the points and crosspoints;
the issue's per-garment targets), one row per part and recognizer.

    python benchmarks/heldout_garments.py --build out/datasets/modules_reader --checkpoint runs/reader.pt \\
        --baseline out/weights/recognizer.pt --json out/bench/heldout_garments.json
    python benchmarks/heldout_garments.py ... --localizer out/weights/localizer.pt \\
        --crosspoints out/weights/crosspoints.pt --device cuda          # and the chain (seconds on a GPU)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from assets.fileio import save_json  # noqa: E402
from assets.recipes import read_build  # noqa: E402
from networks.evaluate import evaluate, split_entries  # noqa: E402
from networks.evaluate_detector import evaluate_detector, load_detector  # noqa: E402

TARGET_TOP1 = 0.995


def parts(build: Path) -> list[tuple[str, Path, str]]:
    """(kind, folder, split) of each part of the recipe build `build`."""
    record = read_build(build)
    listed = [("train", build / p, "test") for p in record["parts"]["train"]]
    listed += [("holdout", build / p, "all") for p in record["parts"]["holdout"]]
    missing = [str(f) for _, f, _ in listed if not (f / "manifest.jsonl").is_file()]
    if missing:
        raise FileNotFoundError(f"{build}: unfinished parts {', '.join(missing)} (factory.dataset build --recipe)")
    return listed


def measure(checkpoint: Path, folder: Path, split: str, device: str) -> dict:
    """Fully visible top-1 over the whole codebook and over the garment's IDs, and the crop count."""
    row = {}
    for name, restrict in (("codebook", False), ("garment", True)):
        metrics = evaluate(checkpoint, folder, split, "recognizer", device, batch_size=64, progress=False,
                           garment_ids=restrict)
        row[name] = metrics["fully_visible"]["top1"]
        row["crops"] = metrics["fully_visible"]["count"]
    return row


def chain(localizer: Path, recognizer: Path, crosspoints: Path, folder: Path, split: str, device: str) -> dict:
    """The Detector's metrics (default settings) on the part's images, as the issue's targets read them."""
    detector = load_detector(localizer, recognizer, crosspoints, folder, device)
    m = evaluate_detector(detector, folder, split, progress=False)
    points = m["point_error_px"]["all"]
    return {"precision": m["markers"]["all"]["precision"], "full_recall": m["markers"]["full"]["recall"],
            "id_full": m["id_accuracy"]["full"]["accuracy"], "id_all": m["id_accuracy"]["all"]["accuracy"],
            "centre_px": points["centre"]["median"],
            "corner_px": max(points[c]["median"] for c in ("TL", "TR", "BL", "BR")),
            "crosspoint_px": m["crosspoints"]["error_px"]["median"], "seconds_per_image": m["seconds_per_image"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", type=Path, required=True, help="a recipe build folder (recipe.json)")
    parser.add_argument("--checkpoint", type=Path, required=True, help="the recognizer measured")
    parser.add_argument("--baseline", type=Path, help="the stored ID classifier (networks.weights fetch)")
    parser.add_argument("--localizer", type=Path, help="with --crosspoints: also run each recognizer chained")
    parser.add_argument("--crosspoints", type=Path)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", type=Path, help="where to write the rows")
    args = parser.parse_args()

    rows = []
    for kind, folder, split in parts(args.build):
        row = {"part": str(folder.relative_to(args.build)), "kind": kind, "split": split,
               "images": len(split_entries(folder, split)), "network": measure(args.checkpoint, folder, split,
                                                                               args.device)}
        if args.baseline is not None:
            row["baseline"] = measure(args.baseline, folder, split, args.device)
        if args.localizer is not None and args.crosspoints is not None:
            row["chain"] = {name: chain(args.localizer, checkpoint, args.crosspoints, folder, split, args.device)
                            for name, checkpoint in (("network", args.checkpoint), ("baseline", args.baseline))
                            if checkpoint is not None}
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json is not None:
        save_json(args.json, {"checkpoint": str(args.checkpoint), "baseline": str(args.baseline), "rows": rows})

    def cell(value: float | None) -> str:
        return "-" if value is None else f"{value:.4f}"

    print(f"\nID top-1 on fully visible markers (target >= {TARGET_TOP1}); network: {args.checkpoint}, "
          f"baseline: {args.baseline}")
    print("| part | split | images | crops | network, codebook | network, garment IDs | baseline, codebook "
          "| baseline, garment IDs |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        b = r.get("baseline", {})
        print(f"| {r['part']} | {r['split']} | {r['images']} | {r['network']['crops']} | {cell(r['network']['codebook'])} "
              f"| {cell(r['network']['garment'])} | {cell(b.get('codebook'))} | {cell(b.get('garment'))} |")
    if any("chain" in r for r in rows):
        print("\nChained in the Detector (stored localizer and crosspoints; targets: precision and fully visible "
              "recall >= 0.99, fully visible ID >= 0.995, centre and corners < 0.5 px)")
        print("| part | recognizer | precision | recall, fully visible | ID, fully visible | ID, all found "
              "| centre px | worst corner px | crosspoints px |")
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            for name, c in r.get("chain", {}).items():
                print(f"| {r['part']} | {name} | {c['precision']:.4f} | {c['full_recall']:.4f} | {c['id_full']:.4f} "
                      f"| {c['id_all']:.4f} | {c['centre_px']:.3f} | {c['corner_px']:.3f} | {c['crosspoint_px']:.3f} |")


if __name__ == "__main__":
    main()
