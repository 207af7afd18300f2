"""The Marker Recognizer's top-1 inside a `networks.Detector`, given each marker's true five points, on
images with ground truth (a factory dataset's or a capture's): whole markers (all five points
visible) against partial ones (the others of
`assets.pattern.observation.recognizer_markers(partial=True)`: centre visible, a point hidden, a sane
crop, a point off the fabric completed from the marker's crosspoints, `completed_points`), by marker
size in the image, and whole markers by the share of their crosspoints visible and by layout
residual.  The localizer and the ID votes take no part: this isolates the recognizer.

A marker's size in the image (`marker_shape`) comes from its four corners: the linear map from the
printed square that fits them best (least squares) has singular values s_min <= s_max; `ratio` =
s_min / s_max is its foreshortening (1 frontal, 0.5 seen at 60 degrees, 0 edge-on) and `size` =
sqrt(s_min s_max) * edge its size in pixels (the square root of its area).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from assets.pattern.observation import ImageGroundTruth, completed_points, recognizer_markers
from networks.evaluate import read_manifest
from networks.homography import layout_residual

if TYPE_CHECKING:
    from networks.detector import Detector

#: the printed square's corners TL, TR, BL, BR (unit edge), as `ImageGroundTruth.points_px[:, 1:]`
SQUARE = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.float64)


def marker_affine(points_px: np.ndarray) -> np.ndarray:
    """(M, 5, 2) localization points -> (K, 2, 2) least-squares linear map from the printed square to
    the four corners, per marker whose four corners are known (a partial marker's off-fabric corners
    are NaN)."""
    corners = np.asarray(points_px, np.float64)[:, 1:]
    corners = corners[np.isfinite(corners).all(axis=(1, 2))]
    centred = corners - corners.mean(axis=1, keepdims=True)
    square = SQUARE - SQUARE.mean(axis=0)
    # corners ~ square @ A.T: A = (square^+ corners).T for every marker at once
    return np.einsum("ij,mjk->mki", np.linalg.pinv(square), centred)


def marker_shape(points_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 5, 2) localization points -> (ratio, size) per marker whose four corners are known (see the
    module docstring)."""
    singular = np.linalg.svd(marker_affine(points_px), compute_uv=False)
    ratio = singular[:, 1] / np.maximum(singular[:, 0], 1e-12)
    size = np.sqrt(singular[:, 0] * singular[:, 1])
    return ratio, size


def rendered_pairs(folder: Path, splits: tuple[str, ...] | None = None) -> list[tuple[Path, Path]]:
    """(image, ground truth) paths of a factory dataset folder's images of `splits` (None: all)."""
    return [(folder / e["image"], folder / e["gt"]) for e in read_manifest(folder)
            if splits is None or e["split"] in splits]


GROUPS = ("all five points visible", "partial: centre visible, a point hidden")


def groups(gt: ImageGroundTruth, spec, completed: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per group, (M,) bool over `gt`'s markers: whole markers, and the partial ones the recognizer
    trains on with `recognizer_partial` (`recognizer_markers`; completed: `completed_points(gt)`)."""
    taken = np.zeros(len(gt.marker_id), bool)
    taken[recognizer_markers(gt, spec, True, completed)] = True
    whole = gt.point_visible.all(axis=1)
    return dict(zip(GROUPS, (taken & whole, taken & ~whole)))


#: marker size bins, px (`marker_shape`: the square root of its area in the image)
SIZES = (0.0, 12.0, 16.0, 24.0, 32.0, np.inf)


def size_bin(low: float, high: float) -> str:
    return f"size {low:.0f}-{high:.0f} px" if np.isfinite(high) else f"size >= {low:.0f} px"


def recognized(detector: Detector, pairs: list[tuple[Path, Path]]) -> list[tuple]:
    """Per image and group (`GROUPS`) that has markers: (image path, group, right (K,) bool: the
    recognizer's ID given the true points is the marker's, size (K,) px: the marker's in the image,
    residual (K,) cells: its five points off a homography (`layout_residual`), visible (K,): the share
    of its crosspoints visible in the image)."""
    records = []
    for image_path, gt_path in pairs:
        image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
        gt = ImageGroundTruth.load(gt_path)
        completed = completed_points(gt)  # what the crops are cut from (a point off the fabric completed)
        for name, mask in groups(gt, detector.spec, completed).items():
            pick = np.flatnonzero(mask)
            if len(pick):
                points = completed[pick].astype(np.float64)
                ids, _ = detector.recognize([image], np.zeros(len(pick), np.int64), points)
                # crops' points are finite: every marker has a size
                records.append((image_path, name, ids == gt.marker_id[pick], marker_shape(points)[1],
                                layout_residual(detector.spec, points),
                                gt.crosspoint_visible[pick].reshape(len(pick), -1).mean(axis=1)))
    return records


def tally(records: list[tuple[Path, str, np.ndarray, np.ndarray]]) -> tuple[dict[str, dict], dict[str, dict]]:
    """Per group, markers and top-1 of `recognized`'s records; and the same per group and marker size
    (`SIZES`): the recognizer's misses by how large the marker is in the image."""
    counts = {name: [0, 0] for name in GROUPS}
    bins = {(name, size_bin(lo, hi)): [0, 0] for name in GROUPS for lo, hi in zip(SIZES[:-1], SIZES[1:])}
    for _, name, right, size, *_ in records:
        counts[name][0] += len(right)
        counts[name][1] += int(right.sum())
        which = np.digitize(size, SIZES[1:-1])
        for k, (lo, hi) in enumerate(zip(SIZES[:-1], SIZES[1:])):
            bins[name, size_bin(lo, hi)][0] += int((which == k).sum())
            bins[name, size_bin(lo, hi)][1] += int(right[which == k].sum())
    by_size: dict[str, dict] = {name: {} for name in GROUPS}
    for (name, label), (n, right) in bins.items():
        if n:
            by_size[name][label] = {"markers": n, "top1": right / n}
    return {name: {"markers": n, "top1": right / max(n, 1)} for name, (n, right) in counts.items()}, by_size


#: bins of how far a marker's five points are off a homography, cells (`networks.homography.layout_residual`)
RESIDUALS = (0.0, 1.0, 2.0, 4.0, np.inf)
#: bins of the share of a whole marker's crosspoints visible in the image (a fold, the body or the
#: garment's edge hides the rest although its five points show): under 80%, 80-95%, 95% and more but
#: not all, and `EVERY_CROSSPOINT`
VISIBLE_SHARES = (0.0, 0.8, 0.95, 1.0)
EVERY_CROSSPOINT = "every crosspoint visible"


def _whole(records: list[tuple], column: int) -> tuple[np.ndarray, np.ndarray]:
    """`recognized`'s whole markers (all five points visible): right (K,) and the record's `column` (K,)."""
    rows = [r for r in records if r[1] == GROUPS[0]]
    return (np.concatenate([r[2] for r in rows] or [np.zeros(0, bool)]),
            np.concatenate([r[column] for r in rows] or [np.zeros(0)]))


def _binned(right: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, dict]:
    return {label: {"markers": int(mask.sum()), "top1": float(right[mask].mean())}
            for label, mask in masks.items() if mask.any()}


def by_residual(records: list[tuple]) -> dict[str, dict]:
    """Markers and top-1 of `recognized`'s whole markers (all five points visible) by their layout
    residual (`RESIDUALS`): the crop homography's misfit, which curved cloth makes."""
    right, residual = _whole(records, 4)
    which = np.digitize(residual, RESIDUALS[1:-1])
    return _binned(right, {(f"residual {lo:g}-{hi:g} cells" if np.isfinite(hi) else f"residual >= {lo:g} cells"):
                           which == k for k, (lo, hi) in enumerate(zip(RESIDUALS[:-1], RESIDUALS[1:]))})


def by_visible(records: list[tuple]) -> dict[str, dict]:
    """Markers and top-1 of `recognized`'s whole markers by the share of their crosspoints visible
    (`VISIBLE_SHARES`, and `EVERY_CROSSPOINT`): a marker whose five points show can still lie partly
    under a fold, and its crop then shows a part of its code or none."""
    right, share = _whole(records, 5)
    masks = {f"{lo:.0%}-{hi:.0%} of its crosspoints visible" + (" (not all)" if hi == 1.0 else ""):
             (share >= lo) & (share < hi) for lo, hi in zip(VISIBLE_SHARES[:-1], VISIBLE_SHARES[1:])}
    return _binned(right, {**masks, EVERY_CROSSPOINT: share >= 1.0})


def top1(detector: Detector, pairs: list[tuple[Path, Path]]) -> dict[str, dict]:
    """The recognizer's top-1 given the true points: {"groups": per group, "by_size": per group and
    marker size (`tally`), "by_visible": whole markers by the share of their crosspoints visible,
    "by_residual": by their layout residual} of `recognized`'s records."""
    records = recognized(detector, pairs)
    groups, by_size = tally(records)
    return {"groups": groups, "by_size": by_size, "by_visible": by_visible(records), "by_residual": by_residual(records)}
