"""The evaluate stage: a reconstruction folder's points and sequence against a factory capture's
ground truth -> ``evaluation.json`` (`evaluate`; the fractions' `DEFINITIONS` are written beside them).
`reconstruction.pipeline` runs it with the other stages."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from assets.fileio import save_json

#: what `evaluate`'s fractions measure, written beside them in evaluation.json
DEFINITIONS = {
    "garment_coverage": "triangulated crosspoints / all crosspoints on the garment's fabric (the rest is "
                        "filled by the physics pass)",
    "captured_fraction": "triangulated crosspoints / crosspoints visible in at least two cameras' ground "
                         "truth (a detection measure, not coverage)",
}


def evaluate(out: str | Path, groundtruth: str | Path) -> dict:
    """Accuracy of the folder's points and sequence against a factory capture's ground truth, whichever
    mode made the detections (networks or ground truth).

    Per frame: the garment coverage (the crosspoints on the garment's fabric that were triangulated,
    over all of them: the share the cameras and the detections captured; physics filled the rest);
    the captured fraction (of the crosspoints seen by at least two cameras in the ground truth, the
    share that were triangulated: a detection measure, not coverage); the median and 95th-percentile
    3D error of the triangulated points (mm); the error of filled regions (the refined surface at the
    crosspoints that were not triangulated, mm); intersecting triangle pairs before and after
    post-processing (refine's diagnostics); and the temporal jitter (mean magnitude of the second
    difference over frames of the refined surface at every crosspoint, mm per frame^2) beside the
    ground truth's own.  Writes ``evaluation.json``: the
    summary (medians over frames), the `DEFINITIONS` of its fractions and the rows per frame."""
    from reconstruction.correspondence import CrosspointMap
    from reconstruction.groundtruth import GroundTruthCapture
    from reconstruction.points import load_sequence
    from reconstruction.refinement import RefinedSequence

    out = Path(out)
    capture = GroundTruthCapture(groundtruth)
    captures = {p.frame: p for p in load_sequence(out / "points")}
    refined = RefinedSequence.load(out / "sequence.npz") if (out / "sequence.npz").exists() else None
    truth_map = capture.crosspoint_map
    every_key = truth_map.unflat(np.arange(truth_map.num_crosspoints))
    refined_map = CrosspointMap.build(capture.template, refined.level_mm) if refined is not None else None
    on_fabric = truth_map.face >= 0
    rows, surfaces, truths = [], [], []
    for frame in sorted(captures):
        points = captures[frame]
        seen = _seen_twice(capture, frame, truth_map)
        truth = capture.crosspoints(frame, points.key)
        error_mm = 1e3 * np.linalg.norm(points.xyz - truth, axis=1)
        flat = truth_map.flat(points.key)
        triangulated = np.isin(flat, seen)
        covered = np.zeros(truth_map.num_crosspoints, dtype=bool)
        covered[flat] = True
        row = {"frame": int(frame),
               "garment_coverage": float((covered & on_fabric).sum() / max(1, on_fabric.sum())),
               "captured_fraction": float(triangulated.sum() / max(1, len(seen))),
               "points": len(points), "error_mm_median": _q(error_mm, 50), "error_mm_p95": _q(error_mm, 95)}
        if refined is not None and frame in refined.frames.tolist():
            t = refined.frames.tolist().index(frame)
            surface = refined_map.points(refined.positions[t].astype(np.float64), every_key)
            exact = capture.crosspoints(frame, every_key)
            filled = ~np.isin(np.arange(truth_map.num_crosspoints), truth_map.flat(points.key))
            filled_mm = 1e3 * np.linalg.norm(surface - exact, axis=1)[filled]
            diagnostics = refined.diagnostics[t]
            row.update({"filled_error_mm_median": _q(filled_mm, 50), "filled_error_mm_p95": _q(filled_mm, 95),
                        "intersections_before": diagnostics.get("intersections_before"),
                        "intersections_after": diagnostics.get("intersections_after")})
            surfaces.append(surface)
            truths.append(exact)
        rows.append(row)
    summary = {"frames": len(rows), "source": next(iter(captures.values())).source if captures else None}
    for key in ("garment_coverage", "captured_fraction", "error_mm_median", "error_mm_p95", "filled_error_mm_median",
                "filled_error_mm_p95"):
        values = [r[key] for r in rows if r.get(key) is not None]
        summary[key] = float(np.median(values)) if values else None
    after = [r["intersections_after"] for r in rows if r.get("intersections_after") is not None]
    summary["intersections_after_max"] = max(after) if after else None
    if len(surfaces) >= 3:
        summary["jitter_mm"] = _jitter(np.stack(surfaces))
        summary["jitter_mm_groundtruth"] = _jitter(np.stack(truths))
    result = {"summary": summary, "definitions": DEFINITIONS, "frames": rows}
    save_json(out / "evaluation.json", result)
    return result


def _seen_twice(capture, frame: int, crosspoints) -> np.ndarray:
    """Flat indices of the crosspoints visible in at least two cameras' ground truth at `frame`."""
    counts = np.zeros(crosspoints.num_crosspoints, dtype=np.int64)
    k = None
    for c in range(len(capture.cameras)):
        gt = capture.ground_truth(frame, c)
        k = gt.crosspoints_px.shape[1]
        rows, cols = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        marker = np.repeat(gt.marker_id, k * k)
        key, known = crosspoints.lookup(marker, np.tile(rows.ravel(), len(gt.marker_id)),
                                        np.tile(cols.ravel(), len(gt.marker_id)))
        visible = gt.crosspoint_visible.reshape(-1) & known
        flat = np.unique(crosspoints.flat(key[visible]))
        counts[flat] += 1
    return np.flatnonzero(counts >= 2)


def _q(values: np.ndarray, q: float) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.percentile(values, q)) if len(values) else None


def _jitter(surfaces: np.ndarray) -> float:
    """Mean |x[t+1] - 2 x[t] + x[t-1]| over frames and points, mm."""
    second = surfaces[2:] - 2 * surfaces[1:-1] + surfaces[:-2]
    return float(1e3 * np.nanmean(np.linalg.norm(second, axis=-1)))
