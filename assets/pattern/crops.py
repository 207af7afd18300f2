"""Marker crops: the one mapping between a marker's crosspoints and the pixels of its unwarped crop.

A crop (`CropSpec`) is a square image of `size_px` pixels showing one marker axis-aligned in its own
frame (TL corner top-left) with `margin_cells` cells of surroundings on every side, so at
``s = size_px / (cells_per_side + 2 margin)`` pixels per cell, crosspoint (row r, col c) of the marker
sits at continuous crop coordinates (pixel centres at +0.5, DESIGN.md)::

    x = (c + margin) * s,    y = (r + margin) * s

The reference's crops: the Marker Recognizer sees 96 x 96 (`RECOGNIZER_CROP`: margin 0, 4 px per cell,
corners on the crop's outer edge) and the Crosspoint Localizer 112 x 112 (`CROSSPOINT_CROP`: margin 2
cells, 4 px per cell, crosspoints at 8, 12, ..., 104).

`crop_homography` (image -> crop, fitted by least squares to the five localization points) is the one
function that makes training crops from ground truth, unwarps detections at inference, and renders the
reference textures' frame, so all three agree by construction.

`CropGeometry` is the whole crop recipe in one record: both crops and the jitter of the five points
training crops were cut from.  Checkpoints and shard folders carry it, and the Detector cuts its crops
as the checkpoints say.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from assets.fileio import check_json_object
from assets.geometry import fit_homography
from assets.pattern.raster import cell_weights, composite, line_coverage
from assets.pattern.spec import PatternSpec
from assets.pattern.table import localization_rc


@dataclass(frozen=True)
class CropSpec:
    """A square marker crop: `size_px` pixels, `margin_cells` cells around the marker."""

    size_px: int
    margin_cells: float

    def __post_init__(self) -> None:
        if self.size_px < 8 or self.margin_cells < 0:
            raise ValueError(f"invalid CropSpec: size_px={self.size_px} (>= 8), margin_cells={self.margin_cells} (>= 0)")

    def px_per_cell(self, spec: PatternSpec) -> float:
        return self.size_px / (spec.cells_per_side + 2 * self.margin_cells)


RECOGNIZER_CROP = CropSpec(size_px=96, margin_cells=0)
CROSSPOINT_CROP = CropSpec(size_px=112, margin_cells=2)

#: the largest crop jitter (pixels, standard deviation) a `CropGeometry` takes; the localizer's points
#: are about 1 px off at the median
MAX_CROP_JITTER_PX = 8.0


@dataclass(frozen=True)
class CropGeometry:
    """How the crop networks' inputs are cut from a marker's five points: the recognizer's crop, the
    crosspoint network's crop (`CropSpec`: size and margin), and jitter_px, the standard deviation
    (pixels) of the Gaussian noise that moved the five points training crops were cut from, as the
    Detector cuts them from the localizer's points (0: exact points).  The defaults are the
    reference's: 96 x 96 and 112 x 112 crops from exact points.  A network's checkpoint and a shard
    folder carry the geometry they were made with (`to_dict`)."""

    recognizer: CropSpec = RECOGNIZER_CROP
    crosspoints: CropSpec = CROSSPOINT_CROP
    jitter_px: float = 0.0

    def __post_init__(self) -> None:
        problems = [f"{name} must be a CropSpec, got {getattr(self, name)!r}" for name in ("recognizer", "crosspoints")
                    if not isinstance(getattr(self, name), CropSpec)]
        jitter = self.jitter_px
        if isinstance(jitter, bool) or not isinstance(jitter, (int, float)) or not 0 <= jitter <= MAX_CROP_JITTER_PX:
            problems.append(f"jitter_px must be in [0, {MAX_CROP_JITTER_PX:g}] pixels, got {jitter!r}")
        if problems:
            raise ValueError("invalid CropGeometry: " + "; ".join(problems))

    def to_dict(self) -> dict[str, object]:
        """Plain JSON types: {"recognizer": {"size_px", "margin_cells"}, "crosspoints": {...}, "jitter_px"}."""
        return {"recognizer": {"size_px": self.recognizer.size_px, "margin_cells": self.recognizer.margin_cells},
                "crosspoints": {"size_px": self.crosspoints.size_px, "margin_cells": self.crosspoints.margin_cells},
                "jitter_px": float(self.jitter_px)}

    @classmethod
    def from_dict(cls, data: object, source: str = "CropGeometry") -> "CropGeometry":
        """From a dict as `to_dict` writes; errors name `source` and the field."""
        check_json_object(data, ("recognizer", "crosspoints", "jitter_px"), source)
        missing = [name for name in ("recognizer", "crosspoints", "jitter_px") if name not in data]
        if missing:
            raise ValueError(f"{source}: missing field(s) {', '.join(missing)}")
        crops = {}
        for name in ("recognizer", "crosspoints"):
            crop = check_json_object(data[name], ("size_px", "margin_cells"), f"{source}.{name}")
            size, margin = crop.get("size_px"), crop.get("margin_cells")
            if isinstance(size, bool) or not isinstance(size, int) or isinstance(margin, bool) \
                    or not isinstance(margin, (int, float)):
                raise ValueError(f"{source}.{name}: size_px must be an integer and margin_cells a number, got "
                                 f"{size!r}, {margin!r}")
            try:
                crops[name] = CropSpec(size_px=size, margin_cells=margin)
            except ValueError as exc:
                raise ValueError(f"{source}.{name}: {exc}") from None
        try:
            return cls(**crops, jitter_px=data["jitter_px"])
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None

    def differences(self, other: "CropGeometry") -> list[str]:
        """What differs from `other`, one "field: this vs other" per field."""
        return [f"{name}: {getattr(self, name)} vs {getattr(other, name)}"
                for name in ("recognizer", "crosspoints", "jitter_px") if getattr(self, name) != getattr(other, name)]


def crop_crosspoints_px(spec: PatternSpec, crop: CropSpec) -> np.ndarray:
    """(K, K, 2) continuous crop coordinates (x, y) of every marker crosspoint (row, col)."""
    s = crop.px_per_cell(spec)
    k = np.arange(spec.crosspoints_per_side, dtype=np.float64)
    x = (k[None, :] + crop.margin_cells) * s
    y = (k[:, None] + crop.margin_cells) * s
    return np.stack(np.broadcast_arrays(x, y), axis=-1)


def crop_localization_px(spec: PatternSpec, crop: CropSpec) -> np.ndarray:
    """(5, 2) crop coordinates of centre, TL, TR, BL, BR."""
    rc = localization_rc(spec)
    return crop_crosspoints_px(spec, crop)[rc[:, 0], rc[:, 1]]


def crop_homography(spec: PatternSpec, crop: CropSpec, localization_px: np.ndarray) -> np.ndarray:
    """Homographies image -> crop from a marker's five localization points in an image.

    localization_px: (5, 2) or (N, 5, 2) continuous image coordinates of centre, TL, TR, BL, BR.
    Returns (3, 3) or (N, 3, 3), mapping continuous image coordinates to continuous crop coordinates.
    """
    points = np.asarray(localization_px, dtype=np.float64)
    if points.shape[-2:] != (5, 2):
        raise ValueError(f"localization points must have shape (5, 2) or (N, 5, 2), got {points.shape}")
    return fit_homography(points, crop_localization_px(spec, crop))


def unwarp(image: np.ndarray, spec: PatternSpec, crop: CropSpec, localization_px: np.ndarray) -> np.ndarray:
    """Cut the crops of N markers out of one image.

    image (H, W) or (H, W, C); localization_px (N, 5, 2) or (5, 2) continuous image coordinates.
    Returns (N, S, S[, C]) (or (S, S[, C])) with the image's dtype, bilinear, zero outside the image.
    """
    points = np.asarray(localization_px, dtype=np.float64)
    single = points.ndim == 2
    size = (crop.size_px, crop.size_px)
    homographies = crop_homography(spec, crop, points[None] if single else points)
    # OpenCV puts pixel centres at integers; ours are at +0.5: conjugate by a half-pixel shift.
    to_cv = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]])
    from_cv = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    crops = np.stack(
        [cv2.warpPerspective(image, to_cv @ h @ from_cv, size, flags=cv2.INTER_LINEAR) for h in homographies]
    )
    return crops[0] if single else crops


def reference_textures(spec: PatternSpec, codes: np.ndarray, crop: CropSpec) -> np.ndarray:
    """The canonical crops of markers with module grids `codes` (N, n, n): (N, S, S, 3) uint8.

    Exactly what `unwarp` yields for a flat, fronto-parallel marker, rendered with the same box
    filter as the printable pattern.  The margin shows the grid lines, which continue on the fabric,
    over background: the neighbours' codes are not part of a marker's identity.
    """
    codes = np.asarray(codes)
    n = spec.cells_per_side
    k = spec.cells_per_module
    cells = np.repeat(np.repeat(codes, k, axis=-2), k, axis=-1).astype(np.float32)  # (N, n, n)
    s = crop.px_per_cell(spec)
    edges = np.arange(crop.size_px + 1) / s - crop.margin_cells
    weights = cell_weights(edges, 0, n).toarray()  # (S, n)
    fill = weights @ cells @ weights.T
    lo, hi = int(np.floor(edges[0])), int(np.ceil(edges[-1]))
    lines_1d = line_coverage(spec, edges, lo, hi)
    lines = lines_1d[:, None] + lines_1d[None, :] - lines_1d[:, None] * lines_1d[None, :]
    return composite(spec, fill, np.broadcast_to(lines, fill.shape))
