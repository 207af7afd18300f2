"""How well a marker's crop map follows the cloth: the crop homography fitted to the five localization
points (`assets.pattern.crop_homography`, the reference's) against the bent crop map
(`assets.pattern.bent_crop_map`: the corners' homography plus a displacement that puts the centre on
its point), on a factory dataset's exact ground truth.

For each fully visible marker (status 2, at least `MIN_CROSSPOINTS` visible crosspoints) each map
takes the crop's canonical crosspoint grid into the image; the distance from each visible crosspoint's
true projection, in the marker's cells (its side over 24), is what a network reading the crop sees
as distortion.  Per marker the median over its crosspoints; reported as the median over markers, in
all and by how far the five points are off a homography (`networks.homography.layout_residual`,
quartiles and the top tenth), and by marker size.  CPU, seconds.

    python benchmarks/crop_bend.py --data .bench/rendered2 [--split all]

Prints a table and a `RESULT {json}` line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from assets.geometry import apply_homography, invert_3x3  # noqa: E402
from assets.pattern import (RECOGNIZER_CROP, PatternSpec, bent_crop_map, crop_crosspoints_px,  # noqa: E402
                            crop_homography)
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.data import dataset_spec  # noqa: E402
from networks.evaluate import read_manifest, split_entries  # noqa: E402
from networks.homography import layout_residual, marker_side_px  # noqa: E402

#: markers with fewer visible crosspoints are left out (a fold or occluder hides most of them)
MIN_CROSSPOINTS = 100
MAPS = ("homography (five points, least squares)", "bent")


def marker_errors(gt: ImageGroundTruth, spec: PatternSpec) -> dict[str, np.ndarray]:
    """Per fully visible marker of `gt` with enough visible crosspoints: each map's median crosspoint
    error in cells (`MAPS`), its layout residual in cells and its side in pixels."""
    pick = np.flatnonzero((gt.status == 2) & (gt.crosspoint_visible.sum(axis=(1, 2)) >= MIN_CROSSPOINTS))
    grid = crop_crosspoints_px(spec, RECOGNIZER_CROP).reshape(-1, 2)
    points = gt.points_px[pick].astype(np.float64)
    truth = gt.crosspoints_px[pick].reshape(len(pick), -1, 2).astype(np.float64)
    visible = gt.crosspoint_visible[pick].reshape(len(pick), -1)
    cell = marker_side_px(points) / spec.cells_per_side
    mapped = {MAPS[0]: apply_homography(invert_3x3(crop_homography(spec, RECOGNIZER_CROP, points)),
                                        np.broadcast_to(grid, (len(pick), *grid.shape))),
              MAPS[1]: bent_crop_map(spec, RECOGNIZER_CROP, points, grid)}
    out = {"residual_cells": layout_residual(spec, points), "side_px": marker_side_px(points)}
    for name, where in mapped.items():
        distance = np.where(visible, np.linalg.norm(where - truth, axis=-1), np.nan)
        out[name] = np.nanmedian(distance, axis=1) / cell
    return out


def gather(data: Path, split: str, spec: PatternSpec) -> dict[str, np.ndarray]:
    entries = read_manifest(data) if split == "all" else split_entries(data, split)
    parts = [marker_errors(ImageGroundTruth.load(data / e["gt"]), spec) for e in entries]
    if not parts:
        raise SystemExit(f"{data}: no images in split {split!r}")
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def table(errors: dict[str, np.ndarray]) -> list[dict]:
    """Rows: all markers, the layout residual's quartiles and top tenth, and three size bins, each with
    the markers' count and each map's median error in cells."""
    residual, side = errors["residual_cells"], errors["side_px"]
    edges = np.percentile(residual, [0, 25, 50, 75, 90, 100])
    groups = [("all", np.ones(len(residual), bool))]
    groups += [(f"residual {lo:.1f}-{hi:.1f} cells", (residual >= lo) & (residual <= hi))
               for lo, hi in zip(edges[:-1], edges[1:])]
    groups += [(f"side {lo:.0f}-{hi:.0f} px" if np.isfinite(hi) else f"side >= {lo:.0f} px",
                (side >= lo) & (side < hi)) for lo, hi in ((0, 12), (12, 16), (16, np.inf))]
    return [{"markers": label, "count": int(mask.sum()),
             **{name: float(np.median(errors[name][mask])) if mask.any() else float("nan") for name in MAPS}}
            for label, mask in groups]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="a factory dataset folder with gt/ and template.npz")
    parser.add_argument("--split", default="all", help="a split of the dataset, or all (default)")
    args = parser.parse_args()
    rows = table(gather(args.data, args.split, dataset_spec(args.data)))
    print(f"# crosspoints' distance from the crop map's place, cells (median over markers), {args.data} ({args.split})")
    print("| markers | count | " + " | ".join(MAPS) + " |\n|---|---|" + "---|" * len(MAPS))
    for row in rows:
        print(f"| {row['markers']} | {row['count']} | " + " | ".join(f"{row[name]:.3f}" for name in MAPS) + " |")
    print("RESULT " + json.dumps({"data": str(args.data), "split": args.split, "rows": rows}))


if __name__ == "__main__":
    main()
