"""Is the crosspoint target (median error under 0.3 px in the 112 x 112 crop) a property of the network or
of the marker's size in the image?  The Crosspoint Localizer's errors by marker size, on a rendered
dataset's held-out images and on a capture's views, each crop cut from the marker's true five points
(`assets.pattern.observation.crosspoint_crops`, as the training samples are), so only the crosspoint
network is measured.

A marker of 20 px in the image is magnified about 5 times into its crop, one of 60 px about twice: the
same image error is a larger crop error on small markers.  The table gives both errors per size bin
(`networks.recognizer_top1.SIZES`, the square root of the marker's area in the image) and their ratio,
and both errors on the crops whose every crosspoint is visible (no fold or edge hides a part of the
marker).

    python research/crosspoint_scale.py --checkpoint crosspoints_jitter.pt --rendered .bench/rendered23 \
        --capture .bench/cap8/capture --frames f000120 [--max-images 10] [--device cpu]

Prints a table and a `RESULT {json}` line.  CPU or GPU.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "research"))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm import tqdm  # noqa: E402

from assets.pattern import CROSSPOINT_CROP, CropSpec, generate_codebook  # noqa: E402
from assets.pattern.observation import ImageGroundTruth, crosspoint_crops  # noqa: E402
from foreshortening import images_and_truth  # noqa: E402
from networks.checkpoint import check_pattern, checkpoint_spec, load_checkpoint  # noqa: E402
from networks.data import dataset_spec  # noqa: E402
from networks.evaluate import (  # noqa: E402
    crop_batches,
    crosspoint_arrays,
    crosspoint_crop_points,
    crosspoint_predictions,
    model_crop,
)
from networks.homography import crop_to_image  # noqa: E402
from networks.metrics import crosspoint_metrics  # noqa: E402
from networks.recognizer_top1 import SIZES, marker_shape, size_bin  # noqa: E402
from networks.tasks import autocast, forward  # noqa: E402


def crop_set(pairs: list[tuple[Path, Path]], spec, codebook: np.ndarray, crop: CropSpec = CROSSPOINT_CROP
             ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every crosspoint crop of the images in `crop` (the network's), as `evaluate_model` takes them
    (with the image points for the image error), and each crop's marker size px."""
    parts, sizes = [], []
    for image_path, gt_path in tqdm(pairs, desc="crops", unit="image", leave=False):
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"{image_path}: not a readable image")
        gt = ImageGroundTruth.load(gt_path)
        crops, ids, xy, visible = crosspoint_crops(image[:, :, ::-1].copy(), gt, spec, crop)
        if not len(ids):
            continue
        arrays = crosspoint_arrays(spec, codebook, crops, ids, xy, visible, crop)
        arrays["points_px"], arrays["gt_xy_image"] = crosspoint_crop_points(gt, spec, ids, gt_path, crop)
        parts.append(arrays)
        sizes.append(marker_shape(arrays["points_px"])[1])  # completed points: all finite
    if not parts:
        raise ValueError("no crosspoint crops in these images")
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}, np.concatenate(sizes)


@torch.no_grad()
def by_size(model, arrays: dict[str, np.ndarray], sizes: np.ndarray, spec, device: torch.device,
            batch_size: int) -> dict[str, dict]:
    """The crosspoint metrics of all crops and of each size bin with crops, from one pass of the model."""
    model.eval()
    visible, xy = [], []
    for batch in crop_batches(arrays, batch_size):
        with autocast(device, device.type == "cuda"):
            output, _, _ = forward("crosspoints", model, batch, device)
        v, p = crosspoint_predictions(output)
        visible.append(v)
        xy.append(p)
    visible, xy = np.concatenate(visible), np.concatenate(xy)
    image = crop_to_image(spec, model_crop(model), arrays["points_px"].astype(np.float64), xy)
    which = np.digitize(sizes, SIZES[1:-1])
    groups = {"all sizes": np.ones(len(sizes), bool)}
    groups.update({size_bin(lo, hi): which == k for k, (lo, hi) in enumerate(zip(SIZES[:-1], SIZES[1:]))})
    result = {}
    for label, mask in groups.items():
        if mask.any():
            metrics = crosspoint_metrics(visible[mask], xy[mask], arrays["visible"][mask], arrays["xy"][mask],
                                         image[mask], arrays["gt_xy_image"][mask])
            result[label] = {"crops": metrics["crops"], "size_median": float(np.median(sizes[mask])),
                             "visibility": metrics["visibility"], "crop_error_px": metrics["crop_error_px"],
                             "image_error_px": metrics["image_error_px"], "fully_visible": metrics["fully_visible"]}
    return result


def _number(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _fully_visible(row: dict) -> str:
    """A size bin's crops whose every crosspoint is visible: their count and median errors."""
    full = row["fully_visible"]  # image errors too: `by_size` passes the image points
    return (f"{full['crops']}, {_number(full['crop_error_px']['median'], '.3f')}, "
            f"{_number(full['image_error_px']['median'], '.3f')}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", type=Path, required=True, help="a crosspoints checkpoint")
    parser.add_argument("--rendered", type=Path, help="a factory dataset folder (its validation and test images)")
    parser.add_argument("--capture", type=Path, help="a capture folder")
    parser.add_argument("--frames", default="", help="only these capture frames (comma-separated stems, e.g. f000120)")
    parser.add_argument("--max-images", type=int, help="at most this many images of each source")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args(argv)
    if not (args.rendered or args.capture):
        parser.error("give --rendered and/or --capture")
    device = torch.device(args.device)
    model, _, saved = load_checkpoint(args.checkpoint, expected_task="crosspoints", device=device)
    spec = checkpoint_spec(saved)
    codebook = generate_codebook(spec)
    results = {}
    for label, rendered, capture in (("renders, held out", args.rendered, None), ("capture", None, args.capture)):
        if rendered is None and capture is None:
            continue
        pairs, template = images_and_truth(rendered, capture)
        if template.is_file():  # a checkpoint for another pattern stops here, naming both files
            check_pattern(saved, dataset_spec(template), source=f"{args.checkpoint} against {template}")
        if capture is not None and args.frames:
            wanted = set(args.frames.split(","))
            pairs = [p for p in pairs if p[0].stem in wanted]
        pairs = pairs[:args.max_images]
        if not pairs:
            parser.error(f"{rendered or capture}: no images with ground truth (check --frames)")
        arrays, sizes = crop_set(pairs, spec, codebook, model_crop(model))
        results[f"{label} ({len(pairs)} images)"] = by_size(model, arrays, sizes, spec, device, args.batch_size)
    print(f"# crosspoint error by marker size, {args.checkpoint.name} (crops cut from the true points)")
    print("| images | marker size | crops | size median px | visibility P / R | crop px median / p95 "
          "| image px median / p95 | crop / image median | fully visible: crops, crop px median, image px median "
          "|\n|---|---|---|---|---|---|---|---|---|")
    for source, rows in results.items():
        for label, r in rows.items():
            crop, image, vis = r["crop_error_px"], r["image_error_px"], r["visibility"]
            ratio = crop["median"] / image["median"] if crop["median"] and image["median"] else None
            print(f"| {source} | {label} | {r['crops']} | {r['size_median']:.1f} | {vis['precision']:.3f} / "
                  f"{vis['recall']:.3f} | {_number(crop['median'], '.3f')} / {_number(crop['p95'], '.2f')} | "
                  f"{_number(image['median'], '.3f')} / {_number(image['p95'], '.2f')} | {_number(ratio, '.1f')} | "
                  f"{_fully_visible(r)} |")
    print("RESULT " + json.dumps(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
