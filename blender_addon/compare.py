"""A reconstruction against its factory capture's ground truth, vertex by vertex, for the heat map.

The capture's ``garment.npz`` holds the ground-truth sewn mesh at the simulation's level (12 mm); a
reconstruction is on its finest refine level (12, 4, ... mm) of the same template.  The ground truth
is carried onto the reconstruction's level by the template's exact barycentric prolongation
(`assets.garments.Template.upsample`, seams merged with `Level.sew`), so both have the same sewn
vertices and the error of vertex v at frame f is ``|reconstruction[f, v] - truth[f, v]|``.
"""

from __future__ import annotations

import numpy as np

#: the heat map's colour ramp (linear RGBA) from no error to `max_mm` and beyond
HEAT_STOPS = np.array([[0.02, 0.05, 0.6, 1.0], [0.0, 0.6, 0.2, 1.0], [0.9, 0.8, 0.0, 1.0], [0.8, 0.02, 0.02, 1.0]])


def truth_on_level(capture, level_mm: int, frames: np.ndarray) -> np.ndarray:
    """The ground-truth garment of `capture` (`reconstruction.GroundTruthCapture`) at capture frames
    `frames` (T,) on the sewn mesh of template level `level_mm`: (T, V, 3) metres."""
    garment = capture.garment
    known = garment["frames"].tolist()
    missing = [int(f) for f in frames if int(f) not in known]
    if missing:
        raise ValueError(f"{capture.folder / 'garment.npz'}: no ground truth for frames {missing} (it has {known})")
    truth = garment["positions"][[known.index(int(f)) for f in frames]].astype(np.float64)
    truth_mm = int(garment["level_mm"])
    if truth_mm == level_mm:
        return truth
    if level_mm > truth_mm:
        raise NotImplementedError(f"the reconstruction's {level_mm} mm level is coarser than the ground truth's "
                                  f"{truth_mm} mm: restricting a fine mesh to a coarse one is not in the library")
    template = capture.template
    coarse, fine = template.level(truth_mm), template.level(level_mm)
    unsewn = template.upsample(truth[:, coarse.sewn_index], truth_mm, level_mm)
    return fine.sew(unsewn)


def vertex_errors(capture, level_mm: int, frames: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Per-vertex distance (T, V) metres between `positions` (T, V, 3) of a reconstruction on level
    `level_mm` at capture frames `frames` and the ground truth there."""
    truth = truth_on_level(capture, level_mm, frames)
    if truth.shape != positions.shape:
        raise ValueError(f"the reconstruction has {positions.shape[1]} vertices, the ground truth on its "
                         f"{level_mm} mm level {truth.shape[1]}: not the capture's template")
    return np.linalg.norm(positions - truth, axis=-1)


def heat_colours(error_m: np.ndarray, max_mm: float) -> np.ndarray:
    """Linear RGBA (N, 4) float32 of errors (N,) metres: blue at 0, green, yellow, red at `max_mm`."""
    t = np.clip(np.asarray(error_m) * 1e3 / max_mm, 0.0, 1.0) * (len(HEAT_STOPS) - 1)
    low = np.minimum(t.astype(int), len(HEAT_STOPS) - 2)
    w = (t - low)[:, None]
    return ((1 - w) * HEAT_STOPS[low] + w * HEAT_STOPS[low + 1]).astype(np.float32)
