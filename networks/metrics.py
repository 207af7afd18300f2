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
  given their image positions, in image pixels; given each crop's marker size in the image, the
  same errors by size (`MARKER_SIZE_BINS_PX`: a crop magnifies a small marker more, so the same
  image error reads larger in its crop).
* The whole Detector (`match_detections` per image, `detector_metrics` pooled): its `Detections`
  against an image's `ImageGroundTruth`: markers found, IDs, partial flags, five-point and crosspoint
  errors, and the layout residual that decides which markers are cut.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from assets.pattern import LOCALIZATION_POINTS, PatternSpec
from networks.homography import layout_residual

if TYPE_CHECKING:  # annotations only: the metrics import neither torch nor the observation module
    from assets.pattern.observation import ImageGroundTruth
    from networks.detections import Detections

#: a predicted marker centre within this distance of a ground-truth centre is a match (pixels)
MATCH_RADIUS_PX = 4.0
#: edges of the marker-size bins of `crosspoint_metrics` (side in image pixels, `marker_side_px`)
MARKER_SIZE_BINS_PX = (0.0, 12.0, 16.0, 20.0, 24.0, np.inf)


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
                      gt_full: Sequence[np.ndarray] | None = None, radius_px: float = MATCH_RADIUS_PX,
                      gt_ignore: Sequence[np.ndarray] | None = None) -> dict:
    """Marker detection accuracy over a set of images.

    pred_points: per image (N_i, 5, 2) predicted centre, TL, TR, BL, BR in pixels; gt_points: per
    image (M_i, 5, 2) ground truth (NaN for a point off the fabric, ignored in the errors); gt_full:
    per image (M_i,) bool, True for fully visible markers (None: not reported); gt_ignore: per image
    (L_i, 2) centres of markers in the image that are not targets (a marker whose centre is hidden,
    or whose centre shares its cell with a nearer one): a prediction on one of them (one to one,
    within the radius, after the matches to targets) finds a real marker and is neither a true nor a
    false positive.
    Returns {"radius_px", "images", "all": {precision, recall, f1, counts, "error_px": {point name:
    {median, p95, count}}}, "full": the same over fully visible markers, with "on_other_markers",
    "ignored": the predictions on non-target markers}.  For "full", a prediction on a marker that is
    not fully visible is neither a true nor a false positive: one matched to such a marker, and one
    matched to none whose nearest marker (targets and `gt_ignore`) is not a fully visible target and
    lies within the image's marker reach (`marker_reach_px`: a partial marker placed 4-8 px off was
    counted a false positive of the fully visible ones; "on_other_markers" counts them)."""
    if len(pred_points) != len(gt_points) or (gt_full is not None and len(gt_full) != len(gt_points)) or (
            gt_ignore is not None and len(gt_ignore) != len(gt_points)):
        raise ValueError(f"localizer_metrics: {len(pred_points)} predictions, {len(gt_points)} ground truths"
                         + ("" if gt_full is None else f", {len(gt_full)} full masks")
                         + ("" if gt_ignore is None else f", {len(gt_ignore)} ignore sets") + ": expected one per image")
    counts = {"all": np.zeros(3, np.int64), "full": np.zeros(3, np.int64)}  # tp, fp, fn
    errors: dict[str, list[np.ndarray]] = {"all": [], "full": []}
    ignored = on_other_markers = 0
    for i, (pred, gt) in enumerate(zip(pred_points, gt_points)):
        pred = np.asarray(pred, dtype=np.float64).reshape(-1, 5, 2)
        gt = np.asarray(gt, dtype=np.float64).reshape(-1, 5, 2)
        full = np.ones(len(gt), bool) if gt_full is None else np.asarray(gt_full[i], dtype=bool)
        if full.shape != (len(gt),):
            raise ValueError(f"localizer_metrics: image {i}: gt_full has shape {full.shape}, expected ({len(gt)},)")
        p, g = match_markers(pred[:, 0], gt[:, 0], radius_px)
        unmatched = len(pred) - len(p)
        if gt_ignore is not None:
            rest = np.setdiff1d(np.arange(len(pred)), p)
            on_other, _ = match_markers(pred[rest, 0], np.asarray(gt_ignore[i], np.float64).reshape(-1, 2), radius_px)
            ignored += len(on_other)
            unmatched -= len(on_other)
            others = np.setdiff1d(rest, rest[on_other])
        else:
            others = np.setdiff1d(np.arange(len(pred)), p)
        error = np.linalg.norm(pred[p] - gt[g], axis=-1)  # (K, 5), NaN where the truth is off the fabric
        counts["all"] += [len(p), unmatched, len(gt) - len(g)]
        errors["all"].append(error)
        matched_full = full[g]
        markers = np.concatenate([gt[:, 0], np.zeros((0, 2)) if gt_ignore is None else
                                  np.asarray(gt_ignore[i], np.float64).reshape(-1, 2)])
        on_partial = _on_partial_markers(pred[others, 0], markers, np.r_[full, np.zeros(len(markers) - len(gt), bool)],
                                         max(radius_px, marker_reach_px(gt[full])))
        on_other_markers += on_partial
        counts["full"] += [matched_full.sum(), unmatched - on_partial, full.sum() - matched_full.sum()]
        errors["full"].append(error[matched_full])
    result: dict[str, object] = {"radius_px": float(radius_px), "images": len(gt_points)}
    for subset in ("all", "full") if gt_full is not None else ("all",):
        error = np.concatenate(errors[subset]) if errors[subset] else np.zeros((0, 5))
        result[subset] = {**detection_scores(*counts[subset]),
                          "error_px": {name: error_stats(error[:, k]) for k, name in enumerate(LOCALIZATION_POINTS)}}
    if gt_full is not None:
        result["full"]["on_other_markers"] = on_other_markers
    if gt_ignore is not None:
        result["ignored"] = ignored
    return result


def marker_reach_px(markers: np.ndarray) -> float:
    """How far from its centre a point still lies on a marker: the median distance of the corners
    from the centre over `markers` (M, 5, 2) (finite points only); 0 when there are none."""
    markers = np.asarray(markers, dtype=np.float64).reshape(-1, 5, 2)
    reach = np.linalg.norm(markers[:, 1:] - markers[:, :1], axis=-1)
    reach = reach[np.isfinite(reach)]
    return float(np.median(reach)) if len(reach) else 0.0


def _on_partial_markers(centres: np.ndarray, markers: np.ndarray, full: np.ndarray, reach_px: float) -> int:
    """How many of the predicted `centres` (N, 2) lie on a marker that is not fully visible: their
    nearest of `markers` (M, 2) is not `full` (M,) and within `reach_px`."""
    if len(centres) == 0 or len(markers) == 0:
        return 0
    distance = np.linalg.norm(np.asarray(centres, np.float64)[:, None] - markers[None], axis=-1)
    distance[~np.isfinite(distance)] = np.inf  # a shown marker whose centre is off the fabric (NaN)
    nearest = distance.argmin(axis=1)
    return int((~full[nearest] & (distance[np.arange(len(centres)), nearest] <= reach_px)).sum())


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
                       pred_xy_image: np.ndarray | None = None, gt_xy_image: np.ndarray | None = None,
                       marker_side_px: np.ndarray | None = None) -> dict:
    """Crosspoint visibility and position accuracy over N crops of K x K crosspoints.

    pred_visible, gt_visible (N, K, K) bool; pred_xy, gt_xy (N, K, K, 2) crop pixels (NaN off the
    fabric); pred_xy_image, gt_xy_image optionally the same points in image pixels (the crop points
    mapped through the inverse crop homography).  Position errors are over the crosspoints visible
    in the ground truth, whatever the predicted visibility.  marker_side_px (N,) optionally each
    crop's marker side in the image (`networks.homography.marker_side_px` of its five points).
    Returns {"visibility": {precision, recall, f1, counts}, "crop_error_px": {median, p95, count},
    "image_error_px": the same or None, "crops": N, "fully_visible": {"crops", "crop_error_px",
    "image_error_px"} over the crops whose every crosspoint is visible (no fold or edge hides a part
    of the marker, and none lies outside the crop)}, and with marker_side_px "by_marker_size": {"<lo>-<hi> px": {"crops",
    "crop_error_px", "image_error_px"}} per bin of `MARKER_SIZE_BINS_PX` that holds a crop."""
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
    crop_error = np.where(gt_visible, np.linalg.norm(pred_xy - gt_xy, axis=-1), np.nan)  # (N, K, K)
    image_error = None
    if pred_xy_image is not None and gt_xy_image is not None:
        pred_image = np.asarray(pred_xy_image, dtype=np.float64)
        gt_image = np.asarray(gt_xy_image, dtype=np.float64)
        if pred_image.shape != gt_xy.shape or gt_image.shape != gt_xy.shape:
            raise ValueError(f"crosspoint_metrics: image points must have shape {gt_xy.shape}, got "
                             f"{pred_image.shape} and {gt_image.shape}")
        image_error = np.where(gt_visible, np.linalg.norm(pred_image - gt_image, axis=-1), np.nan)
    def errors(rows: np.ndarray) -> dict:
        return {"crops": int(rows.sum()), "crop_error_px": error_stats(crop_error[rows]),
                "image_error_px": None if image_error is None else error_stats(image_error[rows])}

    # the errors are NaN where the truth hides the crosspoint, and `error_stats` counts finite values only

    result = {"visibility": detection_scores(tp, fp, fn), "crop_error_px": error_stats(crop_error),
              "image_error_px": None if image_error is None else error_stats(image_error), "crops": int(len(gt_xy)),
              "fully_visible": errors(gt_visible.reshape(len(gt_visible), -1).all(axis=1))}
    if marker_side_px is not None:
        side = np.asarray(marker_side_px, dtype=np.float64)
        if side.shape != (len(gt_xy),):
            raise ValueError(f"crosspoint_metrics: marker_side_px must have shape ({len(gt_xy)},), got {side.shape}")
        result["by_marker_size"] = {}
        edges = MARKER_SIZE_BINS_PX
        for lo, hi in zip(edges[:-1], edges[1:]):
            rows = (side >= lo) & (side < hi)
            if rows.any():
                result["by_marker_size"][f"{lo:g}-{hi:g} px"] = errors(rows)
    return result


# ---- the whole Detector ---------------------------------------------------------------------------

def _found_by_id(detections: "Detections", gt: "ImageGroundTruth", rows: np.ndarray, radius_px: float) -> int:
    """How many of the detections `rows` (unmatched by centre) found a shown marker by its ID: a marker
    cut by the garment's edge has no centre on the fabric to match, so a detection with its ID whose
    crosspoints lie on its crosspoints (median offset within `radius_px` where both see them) found it
    too (the Detector places and grows such markers from their neighbours)."""
    shown = np.flatnonzero(gt.status > 0)
    ids, first = np.unique(gt.marker_id[shown], return_index=True)
    if len(ids) == 0 or len(rows) == 0:
        return 0
    at = np.minimum(np.searchsorted(ids, detections.marker_id[rows]), len(ids) - 1)
    known = ids[at] == detections.marker_id[rows]
    r, j = rows[known], shown[first[at[known]]]
    both = detections.crosspoint_visible[r] & gt.crosspoint_visible[j]  # (R, K, K)
    offset = np.linalg.norm(detections.crosspoints_px[r].astype(np.float64) - gt.crosspoints_px[j], axis=-1)
    seen = both.any(axis=(1, 2))
    if not seen.any():
        return 0
    k = both.shape[1]
    median = np.nanmedian(np.where(both, offset, np.nan)[seen].reshape(-1, k * k), axis=1)
    return int((median <= radius_px).sum())


def rows_by_id(marker_id: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """(W,) int64: the row of `marker_id` (M,) holding each `wanted` ID, -1 where none does (IDs are
    unique in an image's ground truth; -1 entries of `marker_id` are never matched)."""
    marker_id = np.asarray(marker_id, dtype=np.int64)
    wanted = np.asarray(wanted, dtype=np.int64)
    if len(marker_id) == 0:
        return np.full(len(wanted), -1, dtype=np.int64)
    order = np.argsort(marker_id, kind="stable")
    rows = order[np.minimum(np.searchsorted(marker_id[order], wanted), len(order) - 1)]
    return np.where((marker_id[rows] == wanted) & (wanted >= 0), rows, -1).astype(np.int64)


def match_detections(detections: "Detections", gt: "ImageGroundTruth", spec: PatternSpec,
                     radius_px: float = MATCH_RADIUS_PX, localized_px: np.ndarray | None = None) -> dict:
    """One image's Detector output against its ground truth, as raw arrays that `detector_metrics` pools.

    The ground-truth markers are those present in the image (status > 0 and centre point visible); a
    detection matches one whose centre is within `radius_px` of its own (`match_markers`).  "Full"
    means status 2 (every crosspoint and all five points visible), "partly" status 1.
    spec: the pattern (for `layout_residual`); localized_px: optionally the Marker Localizer's own
    five points (L, 5, 2) of the image, before the Detector replaced cut markers' points by their
    neighbours' estimate: matched to the present markers on their own, those matched to full ones
    give the layout residual that the Detector's cut test saw (none when None).

    Returns a dict: ints "detections" (N), "on_hidden" (of them, unmatched ones on a shown marker whose
    centre is hidden), "by_id" (of the rest, unmatched ones with the ID of a shown marker whose
    crosspoints they lie on: a marker cut by the edge, its centre off the fabric) (neither true nor
    false positives), "gt_markers" (M present), "gt_full" (of them status 2);
    over the K matches (K,) bool "matched_full", "id_correct", "partial" (flagged by the Detector) and
    "point_error_px" (K, 5) float64 (NaN where the truth is off the fabric); (R,) float64
    "localizer_residual_cells" (localized points matched to full markers) and (F,) "gt_residual_cells"
    (the ground-truth points of the full markers); for the matches with the right ID,
    "crosspoint_counts" (3,) int64 visible true positives, false positives, false negatives (per
    crosspoint) and "crosspoint_error_px" (P,) the image error of those visible in both; for the markers
    the Detector grew (flagged partial and not voted on, `Detections.id_support` -1: with ID votes on,
    as by default, only grown markers have no vote count), ints "grown" and "grown_shown" (of them, IDs
    shown in the image), "grown_point_error_px" (G, 5) float64 of the shown ones (NaN where the true
    point is hidden) and "grown_crosspoint_error_px" (Q,) of their crosspoints visible in both.
    """
    k = detections.crosspoints_px.shape[1]
    if gt.crosspoints_px.shape[1] != k:
        raise ValueError(f"match_detections: the detections have {k} crosspoints per side, the ground truth "
                         f"{gt.crosspoints_px.shape[1]}")
    truth = gt.select((gt.status > 0) & gt.point_visible[:, 0])
    full = truth.status == 2
    d, g = match_markers(detections.points_px[:, 0], truth.points_px[:, 0], radius_px)
    id_correct = detections.marker_id[d] == truth.marker_id[g]
    # a detection of a shown marker whose centre is hidden found a real marker: neither true nor false
    hidden = gt.select((gt.status > 0) & ~gt.point_visible[:, 0])
    rest = np.setdiff1d(np.arange(len(detections)), d)
    on_hidden, _ = match_markers(detections.points_px[rest, 0], hidden.points_px[:, 0], radius_px)
    by_id = _found_by_id(detections, gt, np.setdiff1d(rest, rest[on_hidden]), radius_px)
    point_error = np.linalg.norm(detections.points_px[d].astype(np.float64) - truth.points_px[g], axis=-1)

    # crosspoints compare only where the ID, so the grid of crosspoints, is the true one
    d_right, g_right = d[id_correct], g[id_correct]
    pred_visible = detections.crosspoint_visible[d_right]
    gt_visible = truth.crosspoint_visible[g_right]
    both = pred_visible & gt_visible
    crosspoint_error = np.linalg.norm(detections.crosspoints_px[d_right].astype(np.float64)
                                      - truth.crosspoints_px[g_right], axis=-1)[both]

    grown_all = np.flatnonzero(detections.partial.astype(bool) & (detections.id_support < 0))
    rows = rows_by_id(np.where(gt.status > 0, gt.marker_id, -1), detections.marker_id[grown_all])
    grown, rows = grown_all[rows >= 0], rows[rows >= 0]
    grown_error = np.linalg.norm(detections.points_px[grown].astype(np.float64) - gt.points_px[rows], axis=-1)
    grown_error = np.where(gt.point_visible[rows], grown_error, np.nan)
    grown_both = detections.crosspoint_visible[grown] & gt.crosspoint_visible[rows]
    grown_crosspoint_error = np.linalg.norm(detections.crosspoints_px[grown].astype(np.float64)
                                            - gt.crosspoints_px[rows], axis=-1)[grown_both]

    localizer_residual = np.zeros(0)
    if localized_px is not None:
        localized_px = np.asarray(localized_px, dtype=np.float64).reshape(-1, 5, 2)
        raw, raw_truth = match_markers(localized_px[:, 0], truth.points_px[:, 0], radius_px)
        localizer_residual = layout_residual(spec, localized_px[raw[full[raw_truth]]])
    return {
        "detections": len(detections),
        "on_hidden": len(on_hidden),
        "by_id": by_id,
        "gt_markers": truth.num_markers,
        "gt_full": int(full.sum()),
        "matched_full": full[g],
        "id_correct": id_correct,
        "partial": detections.partial[d].astype(bool),
        "point_error_px": point_error,
        "localizer_residual_cells": localizer_residual,
        "gt_residual_cells": layout_residual(spec, truth.points_px[full]),
        "crosspoint_counts": np.array([both.sum(), (pred_visible & ~gt_visible).sum(),
                                       (~pred_visible & gt_visible).sum()], dtype=np.int64),
        "crosspoint_error_px": crosspoint_error,
        "grown": len(grown_all),
        "grown_shown": len(grown),
        "grown_point_error_px": grown_error.reshape(-1, 5),
        "grown_crosspoint_error_px": grown_crosspoint_error,
    }


def _fraction(mask: np.ndarray, name: str) -> dict[str, float | int | None]:
    """{name: the share of True in `mask` (None when empty), "count": its length}."""
    mask = np.asarray(mask, dtype=bool)
    return {name: float(mask.mean()) if len(mask) else None, "count": int(len(mask))}


def residual_stats(residual: np.ndarray, threshold: float | None = None) -> dict[str, float | int | None]:
    """{"median", "p90", "count"} of the finite layout residuals (cells), and "above_threshold": the
    share of all of them (non-finite ones included) above `threshold` (None without one)."""
    residual = np.asarray(residual, dtype=np.float64).ravel()
    finite = residual[np.isfinite(residual)]
    above = None
    if threshold is not None and len(residual):
        above = float((~(residual <= threshold)).mean())
    if len(finite) == 0:
        return {"median": None, "p90": None, "count": 0, "above_threshold": above}
    return {"median": float(np.median(finite)), "p90": float(np.percentile(finite, 90)), "count": int(len(finite)),
            "above_threshold": above}


def detector_metrics(records: Sequence[dict], max_residual_cells: float | None = None) -> dict:
    """Pool `match_detections` records of several images into the Detector's accuracy.

    max_residual_cells: the Detector's `max_layout_residual_cells`, to report the share of residuals
    above it.  Returns (JSON-ready)::

      images, detections
      markers        {"all": precision, recall, f1, counts over the present ground-truth markers
                      (detections on a shown marker whose centre is hidden, "on_hidden", and unmatched
                      ones with a shown marker's ID on its crosspoints, "by_id", are neither),
                      "full": recall, true_positive, false_negative over the fully visible ones}
      id_accuracy    {"all", "full"}: {"accuracy": share of matched detections with the true ID, "count"}
      partial        {"full", "partly"}: {"fraction": share of the matched fully / partly visible
                      markers that the Detector flagged partial, "count"}
      point_error_px {"all", "not_partial"}: {point name: {median, p95, count}} over the matched fully
                      visible markers (all of them, or those not flagged partial)
      crosspoints    {"visibility": precision, recall, f1, counts per crosspoint, "error_px": {median,
                      p95, count} of those visible in both, "markers": matches with the true ID}
      layout_residual_cells {"localizer", "ground_truth": `residual_stats`, "threshold"}
      grown          {"count", "shown": grown markers and those whose ID the image shows, "centre_px",
                      "corners_px": `error_stats` of their placed points where the truth is visible,
                      "crosspoints_px": of their crosspoints visible in both}
    """
    if not records:
        raise ValueError("detector_metrics: no images to pool")
    pooled: dict[str, object] = {}
    for key, value in records[0].items():
        values = [record[key] for record in records]
        pooled[key] = sum(values) if isinstance(value, int) else np.concatenate(values)
    full = pooled["matched_full"]
    matched = len(full)
    partial = pooled["partial"]
    error = pooled["point_error_px"].reshape(-1, 5)
    full_scores = detection_scores(full.sum(), 0, pooled["gt_full"] - full.sum())  # precision: not defined
    by_point = {subset: {name: error_stats(error[rows, k]) for k, name in enumerate(LOCALIZATION_POINTS)}
                for subset, rows in (("all", full), ("not_partial", full & ~partial))}
    return {
        "images": len(records),
        "detections": int(pooled["detections"]),
        "markers": {
            "all": detection_scores(matched, pooled["detections"] - matched - pooled["on_hidden"] - pooled["by_id"],
                                    pooled["gt_markers"] - matched),
            "on_hidden": int(pooled["on_hidden"]),
            "by_id": int(pooled["by_id"]),
            "full": {key: full_scores[key] for key in ("recall", "true_positive", "false_negative")},
        },
        "id_accuracy": {"all": _fraction(pooled["id_correct"], "accuracy"),
                        "full": _fraction(pooled["id_correct"][full], "accuracy")},
        "partial": {"full": _fraction(partial[full], "fraction"), "partly": _fraction(partial[~full], "fraction")},
        "point_error_px": by_point,
        "crosspoints": {"visibility": detection_scores(*pooled["crosspoint_counts"].reshape(-1, 3).sum(axis=0)),
                        "error_px": error_stats(pooled["crosspoint_error_px"]),
                        "markers": int(pooled["id_correct"].sum())},
        "layout_residual_cells": {
            "localizer": residual_stats(pooled["localizer_residual_cells"], max_residual_cells),
            "ground_truth": residual_stats(pooled["gt_residual_cells"], max_residual_cells),
            "threshold": max_residual_cells,
        },
        "grown": {"count": int(pooled["grown"]), "shown": int(pooled["grown_shown"]),
                  "centre_px": error_stats(pooled["grown_point_error_px"][:, 0]),
                  "corners_px": error_stats(pooled["grown_point_error_px"][:, 1:]),
                  "crosspoints_px": error_stats(pooled["grown_crosspoint_error_px"])},
    }
