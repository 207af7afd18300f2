"""Contact sheets: rendered images with their ground truth drawn on top, tiled into one PNG
(`python -m factory.dataset preview`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from assets.fileio import atomic_path
from assets.pattern.observation import ImageGroundTruth


def draw_ground_truth(image: np.ndarray, gt: ImageGroundTruth, zoom: float = 1.0) -> np.ndarray:
    """The image (H, W, 3) uint8, resized by `zoom`, with every visible marker's outline (green: fully
    visible, orange: partially), its ID at the centre, and its visible crosspoints (magenta dots)."""
    import cv2

    h, w = image.shape[:2]
    canvas = cv2.resize(image[:, :, ::-1], (int(round(w * zoom)), int(round(h * zoom))), interpolation=cv2.INTER_AREA
                        if zoom < 1 else cv2.INTER_LINEAR)
    for m in np.flatnonzero(gt.status > 0):
        colour = (0, 200, 0) if gt.status[m] == 2 else (0, 160, 255)
        for x, y in gt.crosspoints_px[m][gt.crosspoint_visible[m]][::4] * zoom:
            canvas[min(int(y), canvas.shape[0] - 1), min(int(x), canvas.shape[1] - 1)] = (255, 0, 255)
        corners = gt.points_px[m, [1, 2, 4, 3]] * zoom  # TL, TR, BR, BL
        if np.isfinite(corners).all():
            cv2.polylines(canvas, [np.round(corners).astype(np.int32)], True, colour, 1, cv2.LINE_AA)
        if gt.point_visible[m, 0]:
            x, y = gt.points_px[m, 0] * zoom
            cv2.putText(canvas, str(int(gt.marker_id[m])), (int(x) - 8, int(y) + 3), cv2.FONT_HERSHEY_PLAIN, 0.7,
                        (255, 255, 255), 1, cv2.LINE_AA)
    return canvas[:, :, ::-1]


def contact_sheet(pairs: list[tuple[Path, Path]], png: str | Path, columns: int = 3, tile: int = 384,
                  labels: list[str] | None = None) -> Path:
    """Images with their ground truth drawn on top, tiled into one PNG: (image path, gt path) pairs,
    each tile `tile` pixels wide at the images' aspect, labelled with `labels` (default: file stems)."""
    import cv2

    if not pairs:
        raise ValueError(f"{png}: no finished images to show")
    tiles = []
    for k, (image_path, gt_path) in enumerate(pairs):
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"{image_path}: not a readable image")
        drawn = np.ascontiguousarray(draw_ground_truth(image[:, :, ::-1], ImageGroundTruth.load(gt_path),
                                                       tile / image.shape[1]))
        label = labels[k] if labels else image_path.stem
        cv2.putText(drawn, label, (4, drawn.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(drawn)
    tile_h = max(t.shape[0] for t in tiles)
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * tile_h, columns * tile, 3), 255, np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, columns)
        sheet[r * tile_h:r * tile_h + t.shape[0], c * tile:c * tile + t.shape[1]] = t
    with atomic_path(png) as tmp:
        ok, data = cv2.imencode(".png", sheet[:, :, ::-1])
        tmp.write_bytes(data.tobytes())
    return Path(png)


def preview(folder: str | Path, png: str | Path, count: int = 6) -> Path:
    """A contact sheet of a dataset (`manifest.jsonl`) or a capture (`cameras.json`) folder."""
    folder = Path(folder)
    if (folder / "manifest.jsonl").exists():
        entries = [json.loads(line) for line in (folder / "manifest.jsonl").read_text().splitlines() if line]
        step = max(1, len(entries) // count)
        pairs = [(folder / e["image"], folder / e["gt"]) for e in entries[::step][:count]]
    elif (folder / "cameras.json").exists():
        pngs = sorted(p for p in folder.glob("cam*/f*.png"))
        step = max(1, len(pngs) // count)
        shown = pngs[::step][:count]
        pairs = [(p, p.with_name(f"{p.stem}_gt.npz")) for p in shown]
        return contact_sheet(pairs, png, labels=[f"{p.parent.name}/{p.stem}" for p in shown])
    else:
        raise ValueError(f"{folder}: neither a dataset (manifest.jsonl) nor a capture (cameras.json)")
    return contact_sheet(pairs, png)
