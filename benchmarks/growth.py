"""Where the Detector places the markers it grows from their detected neighbours
(`networks.neighbours.predict_missing`): one homography over the whole neighbourhood (the baseline,
`none/0`, the placement before 2026-11-27) against the fits of `networks.neighbours.place_from_neighbours`
that follow the cloth (WIDTH/DEGREE: weights of that width in marker sides, a residual polynomial of that
degree; the Detector's default is `networks.config.NEIGHBOUR_SIGMA_SIDES`/`NEIGHBOUR_DEGREE`), on a
factory dataset's exact ground truth.

In every image the fully visible markers (status 2) are the detections: their true five points moved by
Gaussian noise (`--point-noise` px per coordinate; 0.35 gives a median point error of 0.41 px, the
stored localizer's 0.33-0.46 px), minus a share (`--drop`) that plays the markers the localizer missed.
The dropped markers and every partly visible marker (status 1) are what growth may place. Each method's
points are compared with the truth where the truth is visible: the dropped markers (all five points
visible) and the partly visible ones (their visible points) apart, centre and corners apart. 3 draws.

    python benchmarks/growth.py --data .bench/rendered2 [--split all] [--models none/0,1/0,none/2]

Prints a table and a `RESULT {json}` line.
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

from assets.cli import parse_neighbour_fit  # noqa: E402
from assets.pattern import generate_codebook  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.data import dataset_spec  # noqa: E402
from networks.detector import DetectorConfig  # noqa: E402
from networks.evaluate import read_manifest, split_entries  # noqa: E402
from networks.evaluate_detector import garment_tables  # noqa: E402
from networks.metrics import rows_by_id  # noqa: E402
from networks.neighbours import NEIGHBOUR_OFFSETS, MarkerLayout, predict_missing  # noqa: E402

DRAWS = 3
KINDS = ("full", "partial", "surrounded", "one-sided")


def parse_models(text: str) -> list[tuple[float | None, int]]:
    """`none/0,1/0,none/2` -> [(None, 0), (1.0, 0), (None, 2)]: (width in sides or None, degree)."""
    try:
        return [parse_neighbour_fit(item) for item in text.split(",")]
    except ValueError as exc:
        raise SystemExit(f"--models: {exc}") from None


def load_truth(data: Path, split: str) -> list[ImageGroundTruth]:
    entries = read_manifest(data) if split == "all" else split_entries(data, split)
    return [ImageGroundTruth.load(data / entry["gt"]) for entry in entries]


def grow_errors(layout: MarkerLayout, truth: list[ImageGroundTruth], model: tuple[float | None, int],
                point_noise: float, drop: float, min_neighbours: int) -> dict[str, np.ndarray]:
    """Per placed marker and point: the error (px) to the truth, NaN where the truth is hidden, for the
    dropped fully visible markers ('full', (A, 5)) and the partly visible ones ('partial', (B, 5)), and
    of both those with detected neighbours on all four sides ('surrounded') and the others ('one-sided':
    the fit extrapolates)."""
    errors: dict[str, list[np.ndarray]] = {kind: [] for kind in KINDS}
    for draw in range(DRAWS):
        rng = np.random.default_rng([draw, 7])
        for gt in truth:
            on_garment = layout.contains(gt.marker_id) & (gt.status > 0)
            full = on_garment & (gt.status == 2) & np.isfinite(gt.points_px).all(axis=(1, 2))
            dropped = full & (rng.random(len(full)) < drop)
            detected = np.flatnonzero(full & ~dropped)
            noisy = gt.points_px[detected].astype(np.float64) + rng.normal(0.0, point_noise, (len(detected), 5, 2))
            ids, points, _ = predict_missing(layout, gt.marker_id[detected].astype(np.int64), noisy,
                                             np.ones(len(detected), bool), np.ones(len(detected)),
                                             (gt.width, gt.height), min_neighbours, *model)
            rows = rows_by_id(gt.marker_id, ids)
            known = rows >= 0
            rows, points = rows[known], points[known]
            error = np.linalg.norm(points - gt.points_px[rows], axis=-1)
            error = np.where(gt.point_visible[rows], error, np.nan)
            errors["full"].append(error[dropped[rows]])
            errors["partial"].append(error[(gt.status[rows] == 1) & on_garment[rows]])
            scored = dropped[rows] | ((gt.status[rows] == 1) & on_garment[rows])
            around = surrounded(layout, ids[known], gt.marker_id[detected])
            errors["surrounded"].append(error[scored & around])
            errors["one-sided"].append(error[scored & ~around])
    return {key: np.concatenate(value) if value else np.zeros((0, 5)) for key, value in errors.items()}


def surrounded(layout: MarkerLayout, ids: np.ndarray, detected_ids: np.ndarray) -> np.ndarray:
    """(A,) bool: each marker has a detected neighbour (`MarkerLayout.neighbours`) on each of its four
    sides (above, below, left, right; a diagonal one counts for both of its sides)."""
    neighbours = layout.neighbours(np.asarray(ids, dtype=np.int64))  # (A, 8), slots as NEIGHBOUR_OFFSETS
    seen = np.isin(neighbours, detected_ids) & (neighbours >= 0)
    rows, cols = NEIGHBOUR_OFFSETS[:, 0], NEIGHBOUR_OFFSETS[:, 1]
    sides = [rows < 0, rows > 0, cols < 0, cols > 0]
    return np.all([(seen & side).any(axis=1) for side in sides], axis=0)


def summary(error: np.ndarray) -> dict[str, float | int]:
    """Median and p90 (px) of the visible centres and corners, and the share of visible points > 2 px."""
    centre, corners = error[:, 0], error[:, 1:].ravel()
    centre, corners = centre[np.isfinite(centre)], corners[np.isfinite(corners)]
    both = np.concatenate([centre, corners])

    def stat(values: np.ndarray, q: float) -> float:
        return float(np.percentile(values, q)) if len(values) else float("nan")

    return {"markers": int(len(error)), "centres": int(len(centre)), "corners": int(len(corners)),
            "centre_median": stat(centre, 50), "centre_p90": stat(centre, 90),
            "corner_median": stat(corners, 50), "corner_p90": stat(corners, 90),
            "over_2px": float((both > 2.0).mean()) if len(both) else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="a factory dataset folder with gt/ and template.npz")
    parser.add_argument("--split", default="all", help="a split of the dataset, or all (default)")
    parser.add_argument("--models", default="none/0,1/0,none/2,1.5/2,none/3",
                        help="WIDTH/DEGREE of `place_from_neighbours`: the weights' width in marker sides (none: "
                        "equal weights) and the residual polynomial's degree; none/0 is one homography (the baseline)")
    parser.add_argument("--point-noise", type=float, default=0.35, help="px, standard deviation per coordinate")
    parser.add_argument("--drop", type=float, default=0.1, help="share of the fully visible markers left undetected")
    args = parser.parse_args()
    models = parse_models(args.models)
    if not 0 < args.drop < 1:
        raise SystemExit(f"--drop must lie in (0, 1), got {args.drop}")
    spec = dataset_spec(args.data)
    codebook = generate_codebook(spec)
    tables = garment_tables(args.data, codebook)
    if tables is None:
        raise SystemExit(f"{args.data}: no template.npz, so no garment layout to grow on")
    layout = MarkerLayout.from_tables(tables, len(codebook))
    truth = load_truth(args.data, args.split)
    min_neighbours = DetectorConfig().grow_min_neighbours
    print(f"{args.data} ({args.split}): {len(truth)} images, point noise {args.point_noise} px, "
          f"drop {args.drop}, {DRAWS} draws, at least {min_neighbours} neighbours")
    header = ("| model (width / degree) | markers | centre median / p90 px | corners median / p90 px | points > 2 px | "
              "time s |")
    rows, result = [], []
    for model in models:
        started = time.perf_counter()
        errors = grow_errors(layout, truth, model, args.point_noise, args.drop, min_neighbours)
        seconds = time.perf_counter() - started
        for kind in KINDS:
            s = summary(errors[kind])
            result.append({"sigma_sides": model[0], "degree": model[1], "markers": kind, "seconds": seconds, **s})
            label = "one homography" if model == (None, 0) else f"{model[0]} / {model[1]}"
            rows.append(f"| {label} | {kind} {s['markers']} | {s['centre_median']:.2f} / {s['centre_p90']:.2f} "
                        f"({s['centres']}) | {s['corner_median']:.2f} / {s['corner_p90']:.2f} ({s['corners']}) | "
                        f"{s['over_2px']:.3f} | {seconds:.1f} |")
    print(header)
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))
    print("RESULT " + json.dumps({"data": str(args.data), "split": args.split, "point_noise": args.point_noise,
                                  "drop": args.drop, "rows": result}))


if __name__ == "__main__":
    main()
