"""The chained Detector's images/s beside its three networks' alone, on the same images (issue 47).

The issue's target: the Detector at >= 90% of its networks' bf16 rate at 1920 x 1080 with ~150
markers an image on one H200.  Each frame here is `--images` renders of a factory dataset (`--data`),
scaled by `--upscale` into a 1920 x 1080 grey canvas, so the localizer's automatic scale, the marker
count and the crop work are those of a capture.  Timed in one run, each the median of `--repeats` after a warm-up:

- the Detector (`Detector.detect`, default settings but `--localizer-scale`, the garment's tables
  from the dataset's template.npz), images/s and seconds per stage;
- the networks alone: the localizer on the images resized and padded as the Detector does, the
  recognizer and the crosspoint network on as many crops as the Detector cut, in its batches, from
  tensors already on the device (float32, then bf16 autocast): the rate the Detector could reach.

    python benchmarks/detector_speed.py --localizer out/weights/localizer.pt \\
        --recognizer out/weights/recognizer.pt --crosspoints out/weights/crosspoints.pt \\
        --data out/datasets/modules_reader/train/shirt-default --device cuda

The speed does not depend on what the weights learned, except through the markers found.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project's packages

from networks.detector import Detector, DetectorConfig, DetectorResult, pad_images, resize_for_localizer  # noqa: E402
from networks.evaluate import resolve_device  # noqa: E402
from networks.evaluate_detector import garment_tables  # noqa: E402

CANVAS = (1920, 1080)


def frame_images(data: Path, count: int, upscale: float) -> list[np.ndarray]:
    """`count` canvases (1080, 1920, 3) uint8: the dataset's first renders, scaled by `upscale`, at the centre."""
    entries = [json.loads(line) for line in (data / "manifest.jsonl").read_text().splitlines() if line.strip()]
    if len(entries) < count:
        raise ValueError(f"{data}: {len(entries)} images, fewer than --images {count}")
    images = []
    for entry in entries[:count]:
        render = cv2.cvtColor(cv2.imread(str(data / entry["image"]), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        render = cv2.resize(render, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
        height, width = min(render.shape[0], CANVAS[1]), min(render.shape[1], CANVAS[0])
        canvas = np.full((CANVAS[1], CANVAS[0], 3), 96, np.uint8)
        top, left = (CANVAS[1] - height) // 2, (CANVAS[0] - width) // 2
        canvas[top:top + height, left:left + width] = render[:height, :width]
        images.append(canvas)
    return images


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_detector(detector: Detector, images: list[np.ndarray], repeats: int) -> tuple[float, dict, DetectorResult]:
    """(median seconds per call over `images`, median seconds per stage, the last call's result)."""
    found = detector.detect(images)  # warm-up
    seconds, stages = [], []
    for _ in range(repeats):
        synchronize(detector.device)
        start = time.perf_counter()
        found = detector.detect(images)
        synchronize(detector.device)
        seconds.append(time.perf_counter() - start)
        stages.append(found.stage_seconds)
    median_stages = {k: statistics.median(s[k] for s in stages) for k in stages[0]}
    return statistics.median(seconds), median_stages, found


def time_networks(detector: Detector, images: list[np.ndarray], scales: list[float], markers: int, repeats: int,
                  bf16: bool) -> float:
    """Median seconds of the three networks alone on device tensors of the Detector's sizes (the images at
    the localizer `scales` the Detector chose)."""
    device = detector.device
    batches = []
    for start in range(0, len(images), detector.config.image_batch_size):
        chunk = [resize_for_localizer(image, scale)[0]
                 for image, scale in zip(images[start:start + detector.config.image_batch_size],
                                         scales[start:start + detector.config.image_batch_size])]
        batches.append(detector._to_device(pad_images(chunk)))
    rec, xp = detector.recognizer.crops.recognizer.size_px, detector.crosspoints.crop.size_px
    generator = torch.Generator(device="cpu").manual_seed(0)
    rec_crops = torch.randn(markers, 3, rec, rec, generator=generator).to(device)
    xp_crops = torch.randn(markers, 3, xp, xp, generator=generator).to(device)
    references = torch.randn(markers, 3, xp, xp, generator=generator).to(device)

    def run() -> None:
        with torch.inference_mode(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            for batch in batches:
                detector.localizer(batch)
            for start in range(0, markers, detector.batch_size):
                part = slice(start, start + detector.batch_size)
                detector.recognizer(rec_crops[part])
                detector.crosspoints(xp_crops[part], references[part])

    run()
    seconds = []
    for _ in range(repeats):
        synchronize(device)
        start = time.perf_counter()
        run()
        synchronize(device)
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--localizer", type=Path, required=True)
    parser.add_argument("--recognizer", type=Path, required=True)
    parser.add_argument("--crosspoints", type=Path, required=True)
    parser.add_argument("--data", type=Path, required=True,
                        help="a factory dataset folder: its first renders make the frame, its template.npz the tables")
    parser.add_argument("--device", default=None, help="cuda or cpu (default: cuda when available)")
    parser.add_argument("--images", type=int, default=8, help="images a frame (one Detector call; default 8)")
    parser.add_argument("--upscale", type=float, default=2.0,
                        help="the renders' scale in the 1920 x 1080 frame (default 2: 512 px renders, markers ~28 px)")
    parser.add_argument("--localizer-scale", type=float, default=None,
                        help="a fixed localizer scale (default: the Detector's automatic one)")
    parser.add_argument("--batch-sizes", default="64",
                        help="comma-separated crop batch sizes of the Detector to time (Detector batch_size; default 64)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path, help="write the numbers here")
    args = parser.parse_args()
    if args.images < 1 or args.repeats < 1:
        parser.error("--images and --repeats must be >= 1")
    if not 0.1 <= args.upscale <= 4:
        parser.error(f"--upscale must be in [0.1, 4], got {args.upscale}")

    try:
        batch_sizes = [int(b) for b in args.batch_sizes.split(",")]
    except ValueError:
        parser.error(f"--batch-sizes must be integers separated by commas, got {args.batch_sizes!r}")
    if min(batch_sizes) < 1:
        parser.error("--batch-sizes must be >= 1")

    device = resolve_device(args.device)
    config = DetectorConfig(localizer_scale=args.localizer_scale)
    loaded = Detector.from_checkpoints(args.localizer, args.recognizer, args.crosspoints, device=device)
    tables = garment_tables(args.data, loaded.codebook)
    images = frame_images(args.data, args.images, args.upscale)
    name = torch.cuda.get_device_name(loaded.device) if loaded.device.type == "cuda" else "CPU"
    rows, record = [], {"device": name, "images": args.images, "batches": {}}
    for batch_size in batch_sizes:
        detector = Detector(loaded.localizer, loaded.recognizer, loaded.crosspoints, loaded.spec,
                            device=loaded.device, batch_size=batch_size, tables=tables, config=config,
                            codebook=loaded.codebook)
        seconds, stages, found = time_detector(detector, images, args.repeats)
        markers, scales = sum(len(d) for d in found.detections), found.localizer_scales
        alone = {"float32": time_networks(detector, images, scales, markers, args.repeats, bf16=False)}
        if detector.device.type == "cuda":
            alone["bf16"] = time_networks(detector, images, scales, markers, args.repeats, bf16=True)
        rows.append((batch_size, seconds, alone, stages))
        record["markers"], record["localizer_scales"] = markers, scales
        record["batches"][batch_size] = {"detector_s": seconds, "networks_alone_s": alone, "stages": stages}
    if args.json:
        args.json.write_text(json.dumps(record, indent=2) + "\n")
    print(f"\n{args.images} images of {CANVAS[0]} x {CANVAS[1]}, {record['markers'] / args.images:.0f} markers an "
          f"image, localizer scales {sorted(set(round(s, 3) for s in record['localizer_scales']))}, {name}")
    print("| crop batch | Detector (float32) images/s | networks alone float32 | networks alone bf16 | "
          "Detector / best alone |\n|---|---|---|---|---|")
    for batch_size, seconds, alone, _ in rows:
        best = min(alone.values())
        print(f"| {batch_size} | {args.images / seconds:.1f} | {args.images / alone['float32']:.1f} | "
              f"{args.images / alone['bf16']:.1f} | " if "bf16" in alone else
              f"| {batch_size} | {args.images / seconds:.1f} | {args.images / alone['float32']:.1f} | - | ", end="")
        print(f"{best / seconds:.2f} (target >= 0.9) |")
    for batch_size, _, _, stages in rows:
        print(f"Detector stages at crop batch {batch_size}, s a frame: "
              + ", ".join(f"{k} {v:.3f}" for k, v in stages.items()))


if __name__ == "__main__":
    main()
