"""`Detections`: what the Detector found in one image, as plain numpy arrays (no torch).

Reconstruction caches detections to disk and reads them back without torch, so this module imports
only numpy and `assets.fileio`.  Pixels are continuous image coordinates (x right, y down, pixel
centres at integer + 0.5); the five localization points are in the order
`assets.pattern.LOCALIZATION_POINTS` (centre, TL, TR, BL, BR); K = crosspoints per side (25).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from assets.arrays import check_fields
from assets.fileio import check_limit, load_npz, npz_headers, save_npz

#: the most bytes one image's detections may expand to (a real one is a few MB: about 5 kB a marker)
MAX_BYTES = 2**30


@dataclass(frozen=True, eq=False)
class Detections:
    """N markers detected in one image.

      marker_id          (N,) int64          recognised ID (a row of the pattern's codebook)
      confidence         (N,) float32        presence probability x recognizer softmax probability
      points_px          (N, 5, 2) float32   centre, TL, TR, BL, BR in image pixels (estimated from
                                             neighbours where `partial`)
      crosspoints_px     (N, K, K, 2) float32  crosspoint (row, col) of the marker in image pixels
      crosspoint_visible (N, K, K) bool
      partial            (N,) bool           points_px come from a homography fitted to neighbouring
                                             markers (the marker is cut by a boundary or the image)
      id_support         (N,) int16          how many detected neighbours vote for marker_id on the
                                             garment's layout (`networks.neighbours.vote_ids`); -1 where
                                             no votes were taken (no garment, votes off, or detections
                                             saved before this field)

    On the factory's rendered shirt with the chained Detector's error rate (26% of IDs wrong, errors
    independent), 23 of 13,720 markers with support 1 or more kept a wrong ID,
    against 2,792 of 6,815 with support 0: support is the ID's best evidence after the recognizer.
    """

    marker_id: np.ndarray
    confidence: np.ndarray
    points_px: np.ndarray
    crosspoints_px: np.ndarray
    crosspoint_visible: np.ndarray
    partial: np.ndarray
    id_support: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.marker_id) if isinstance(self.marker_id, np.ndarray) and self.marker_id.ndim == 1 else -1
        if self.id_support is None:  # frozen: fill "not voted" once
            object.__setattr__(self, "id_support", np.full(max(n, 0), -1, np.int16))
        xy = self.crosspoints_px
        k = xy.shape[1] if isinstance(xy, np.ndarray) and xy.ndim == 4 else -1
        expected = {
            "marker_id": ((n,), np.int64),
            "confidence": ((n,), np.float32),
            "points_px": ((n, 5, 2), np.float32),
            "crosspoints_px": ((n, k, k, 2), np.float32),
            "crosspoint_visible": ((n, k, k), np.bool_),
            "partial": ((n,), np.bool_),
            "id_support": ((n,), np.int16),
        }
        check_fields(self, expected, valid=min(n, k) >= 0)

    def __len__(self) -> int:
        return len(self.marker_id)

    @classmethod
    def empty(cls, crosspoints_per_side: int) -> "Detections":
        """No markers, with crosspoint arrays of K = `crosspoints_per_side`."""
        k = crosspoints_per_side
        return cls(
            marker_id=np.zeros(0, np.int64),
            confidence=np.zeros(0, np.float32),
            points_px=np.zeros((0, 5, 2), np.float32),
            crosspoints_px=np.zeros((0, k, k, 2), np.float32),
            crosspoint_visible=np.zeros((0, k, k), bool),
            partial=np.zeros(0, bool),
            id_support=np.zeros(0, np.int16),
        )

    def select(self, index: np.ndarray) -> "Detections":
        """The detections at `index` (integer indices or a boolean mask)."""
        return Detections(**{name: array[index] for name, array in self.to_dict().items()})

    def to_dict(self) -> dict[str, np.ndarray]:
        """The arrays by field name (the same arrays, not copies)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def save(self, path: str | Path) -> None:
        """Write the arrays to an `.npz`, atomically."""
        save_npz(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path, max_bytes: int = MAX_BYTES) -> "Detections":
        """Read detections written by `save`; shapes and dtypes are checked, naming the file.  A file
        without id_support (written before it existed) reads as not voted (-1).  A file whose arrays
        would expand to more than `max_bytes` is refused before any is decompressed."""
        size = sum(int(np.prod(shape, dtype=np.float64)) * dtype.itemsize for shape, dtype in npz_headers(path).values())
        check_limit(size, max_bytes, "the arrays' size in bytes", str(path), "Detections.load(max_bytes=...)")
        names = tuple(f.name for f in fields(cls))
        data = load_npz(path, required=tuple(n for n in names if n != "id_support"))
        try:
            return cls(**{name: data[name] for name in names if name in data})
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc
