"""Accuracy of the three networks on plain arrays (numpy only): predictions against ground truth.

Pixels are continuous image or crop coordinates (x right, y down, pixel centres at integer + 0.5);
the five localization points are in the order `assets.pattern.LOCALIZATION_POINTS`.  Every function
returns a dict of plain floats and ints (JSON-ready); a statistic over no values is None.

* Marker Localizer (`localizer_metrics`): a predicted marker matches a ground-truth marker when their
  centres are within `radius_px` (one-to-one, by minimum total distance); precision, recall and F1
  over all markers and over fully visible ones, and the median and 95th percentile of the pixel
  error of each localization point over the matches.
* Marker Recognizer (`recognizer_metrics`): top-1 and top-5 accuracy.
* Crosspoint Localizer (`crosspoint_metrics`): visibility precision and recall, and the median and
  95th percentile pixel error of the crosspoints visible in the ground truth, in crop pixels and,
  given their image positions, in image pixels.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from assets.pattern import LOCALIZATION_POINTS

#: a predicted marker centre within this distance of a ground-truth centre is a match (pixels)
MATCH_RADIUS_PX = 4.0


def error_stats(errors: np.ndarray) -> dict[str, float | int | None]:
    """{"median", "p95", "count"} of the finite values of `errors` (any shape); None when empty."""
    values = np.asarray(errors, dtype=np.float64).ravel()
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return {"median": None, "p95": None, "count": 0}
    return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)), "count": int(len(values))}


def detection_scores(true_positive: int, false_positive: int, false_negative: int) -> dict[str, float | int]:
    """Precision, recall and F1 from counts; precision is 1 with no predictions, recall 1 with no
    ground truth (nothing was missed or made up)."""
    predicted = true_positive + false_positive
    actual = true_positive + false_negative
    precision = true_positive / predicted if predicted else 1.0
    recall = true_positive / actual if actual else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {"precision": float(precision), "recall": float(recall), "f1": float(f1),
            "true_positive": int(true_positive), "false_positive": int(false_positive),
            "false_negative": int(false_negative)}


def match_markers(pred_centres: np.ndarray, gt_centres: np.ndarray, radius_px: float = MATCH_RADIUS_PX
                  ) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches of predicted to ground-truth centres within `radius_px` (inclusive).

    pred_centres (N, 2), gt_centres (M, 2) pixels.  Returns (pred_index (K,), gt_index (K,)) int64:
    the assignment of least total distance among pairs within the radius (Hungarian method)."""
    pred = np.asarray(pred_centres, dtype=np.float64).reshape(-1, 2)
    gt = np.asarray(gt_centres, dtype=np.float64).reshape(-1, 2)
    if len(pred) == 0 or len(gt) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    distance = np.linalg.norm(pred[:, None] - gt[None], axis=-1)
    within = distance <= radius_px
    # pairs beyond the radius cost more than any full assignment within it, so they are chosen last
    cost = np.where(within, distance, radius_px * (min(len(pred), len(gt)) + 1))
    rows, cols = linear_sum_assignment(cost)
    keep = within[rows, cols]
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def cells_to_markers(cells: np.ndarray, cell: int = 8) -> np.ndarray:
    """Ground-truth markers of a localizer target: (M, 5, 2) float32 absolute image pixels.

    cells (h, w, 11) as `assets.pattern.observation.localizer_targets` writes them (presence, then
    the points relative to the cell corner, NaN off the fabric).  A marker written to two cells
    (`networks.decode.duplicate_border_targets`) is returned once."""
    cells = np.asarray(cells, dtype=np.float32)
    if cells.ndim != 3 or cells.shape[-1] != 11:
        raise ValueError(f"cells_to_markers: expected cells (h, w, 11), got {cells.shape}")
    row, col = np.nonzero(cells[..., 0] > 0.5)
    corner = np.stack([col, row], axis=1).astype(np.float32) * cell
    points = cells[row, col, 1:].reshape(-1, 5, 2) + corner[:, None, :]
    # copies address the same pixels up to float32 rounding of the shifted offsets
    _, first = np.unique(np.round(points[:, 0] * 64), axis=0, return_index=True)
    return points[np.sort(first)]


def localizer_metrics(pred_points: Sequence[np.ndarray], gt_points: Sequence[np.ndarray],
                      gt_full: Sequence[np.ndarray] | None = None, radius_px: float = MATCH_RADIUS_PX) -> dict:
    """Marker detection accuracy over a set of images.

    pred_points: per image (N_i, 5, 2) predicted centre, TL, TR, BL, BR in pixels; gt_points: per
    image (M_i, 5, 2) ground truth (NaN for a point off the fabric, ignored in the errors); gt_full:
    per image (M_i,) bool, True for fully visible markers (None: not reported).
    Returns {"radius_px", "images", "all": {precision, recall, f1, counts, "error_px": {point name:
    {median, p95, count}}}, "full": the same over fully visible markers}.  For "full", predictions
    matched to a marker that is not fully visible are neither true nor false positives."""
    if len(pred_points) != len(gt_points) or (gt_full is not None and len(gt_full) != len(gt_points)):
        raise ValueError(f"localizer_metrics: {len(pred_points)} predictions, {len(gt_points)} ground truths"
                         + ("" if gt_full is None else f", {len(gt_full)} full masks") + ": expected one per image")
    counts = {"all": np.zeros(3, np.int64), "full": np.zeros(3, np.int64)}  # tp, fp, fn
    errors: dict[str, list[np.ndarray]] = {"all": [], "full": []}
    for i, (pred, gt) in enumerate(zip(pred_points, gt_points)):
        pred = np.asarray(pred, dtype=np.float64).reshape(-1, 5, 2)
        gt = np.asarray(gt, dtype=np.float64).reshape(-1, 5, 2)
        full = np.ones(len(gt), bool) if gt_full is None else np.asarray(gt_full[i], dtype=bool)
        if full.shape != (len(gt),):
            raise ValueError(f"localizer_metrics: image {i}: gt_full has shape {full.shape}, expected ({len(gt)},)")
        p, g = match_markers(pred[:, 0], gt[:, 0], radius_px)
        error = np.linalg.norm(pred[p] - gt[g], axis=-1)  # (K, 5), NaN where the truth is off the fabric
        counts["all"] += [len(p), len(pred) - len(p), len(gt) - len(g)]
        errors["all"].append(error)
        matched_full = full[g]
        counts["full"] += [matched_full.sum(), len(pred) - len(p), full.sum() - matched_full.sum()]
        errors["full"].append(error[matched_full])
    result: dict[str, object] = {"radius_px": float(radius_px), "images": len(gt_points)}
    for subset in ("all", "full") if gt_full is not None else ("all",):
        error = np.concatenate(errors[subset]) if errors[subset] else np.zeros((0, 5))
        result[subset] = {**detection_scores(*counts[subset]),
                          "error_px": {name: error_stats(error[:, k]) for k, name in enumerate(LOCALIZATION_POINTS)}}
    return result


def recognizer_metrics(ranked_ids: np.ndarray, marker_id: np.ndarray) -> dict:
    """Top-1 and top-5 accuracy: ranked_ids (N, k) int the k most probable IDs per crop, best
    first (k >= 1; top-5 uses the first min(5, k)); marker_id (N,) the true IDs."""
    ranked_ids = np.asarray(ranked_ids)
    marker_id = np.asarray(marker_id).reshape(-1)
    if ranked_ids.ndim != 2 or ranked_ids.shape[1] < 1 or len(ranked_ids) != len(marker_id):
        raise ValueError(f"recognizer_metrics: expected ranked IDs (N, k) and IDs (N,), got {ranked_ids.shape} "
                         f"and {marker_id.shape}")
    if len(marker_id) == 0:
        return {"top1": None, "top5": None, "count": 0}
    hit = ranked_ids[:, :5] == marker_id[:, None]
    return {"top1": float(hit[:, 0].mean()), "top5": float(hit.any(axis=1).mean()), "count": int(len(marker_id))}


def crosspoint_metrics(pred_visible: np.ndarray, pred_xy: np.ndarray, gt_visible: np.ndarray, gt_xy: np.ndarray,
                       pred_xy_image: np.ndarray | None = None, gt_xy_image: np.ndarray | None = None) -> dict:
    """Crosspoint visibility and position accuracy over N crops of K x K crosspoints.

    pred_visible, gt_visible (N, K, K) bool; pred_xy, gt_xy (N, K, K, 2) crop pixels (NaN off the
    fabric); pred_xy_image, gt_xy_image optionally the same points in image pixels (the crop points
    mapped through the inverse crop homography).  Position errors are over the crosspoints visible
    in the ground truth, whatever the predicted visibility.
    Returns {"visibility": {precision, recall, f1, counts}, "crop_error_px": {median, p95, count},
    "image_error_px": the same or None, "crops": N}."""
    pred_visible = np.asarray(pred_visible, dtype=bool)
    gt_visible = np.asarray(gt_visible, dtype=bool)
    pred_xy = np.asarray(pred_xy, dtype=np.float64)
    gt_xy = np.asarray(gt_xy, dtype=np.float64)
    if pred_visible.shape != gt_visible.shape or pred_xy.shape != gt_xy.shape or pred_xy.shape[:-1] != gt_visible.shape:
        raise ValueError(f"crosspoint_metrics: shapes differ: pred_visible {pred_visible.shape}, gt_visible "
                         f"{gt_visible.shape}, pred_xy {pred_xy.shape}, gt_xy {gt_xy.shape} (expected (N, K, K[, 2]))")
    tp = int((pred_visible & gt_visible).sum())
    fp = int((pred_visible & ~gt_visible).sum())
    fn = int((~pred_visible & gt_visible).sum())
    crop_error = np.linalg.norm(pred_xy - gt_xy, axis=-1)[gt_visible]
    image_error = None
    if pred_xy_image is not None and gt_xy_image is not None:
        pred_image = np.asarray(pred_xy_image, dtype=np.float64)
        gt_image = np.asarray(gt_xy_image, dtype=np.float64)
        if pred_image.shape != gt_xy.shape or gt_image.shape != gt_xy.shape:
            raise ValueError(f"crosspoint_metrics: image points must have shape {gt_xy.shape}, got "
                             f"{pred_image.shape} and {gt_image.shape}")
        image_error = error_stats(np.linalg.norm(pred_image - gt_image, axis=-1)[gt_visible])
    return {"visibility": detection_scores(tp, fp, fn), "crop_error_px": error_stats(crop_error),
            "image_error_px": image_error, "crops": int(len(gt_xy))}
