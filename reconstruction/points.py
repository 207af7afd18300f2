"""`CapturedPoints`: one frame's triangulated crosspoints on one template level.

The plain-data contract between triangulation (`reconstruction.triangulation`) and the physics pass
(`reconstruction.refinement`).  P points, C cameras (in the order of the capture's cameras):

  level_mm        int               template level whose sewn mesh `face` / `bary` refer to
  key (P, 2) int64                  (panel index, global crosspoint index in that panel's
                                    `MarkerTable`): the crosspoint's identity on the garment
  xyz (P, 3) float64                triangulated position, world metres
  face (P,) int64                   row of the level's `sewn_faces` holding the crosspoint (its
                                    template pattern position), or -1 off the level's fabric
  bary (P, 3) float64               barycentric weights in that face
  views (P, C) bool                 cameras that contributed (RANSAC inliers)
  reprojection_px (P,) float64      RMS reprojection error over the inlier views, pixels
  confidence (P,) float64           in [0, 1] (`reconstruction.triangulation` says how it is made)
  frame           int               frame number of the capture (-1 when unknown)
  source          str               where the 2D observations came from: "detector" or
                                    "groundtruth(noise=..px, dropout=..)" (`reconstruction.groundtruth`)

A sequence is a list of CapturedPoints (one per frame, same level), saved as one npz per frame
(`save_sequence`: ``<folder>/f<frame:06d>.npz``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from assets.arrays import check_fields
from assets.fileio import load_npz, save_npz

_ARRAYS = ("key", "xyz", "face", "bary", "views", "reprojection_px", "confidence")


@dataclass(frozen=True, eq=False)
class CapturedPoints:
    """Triangulated crosspoints of one frame (see the module docstring for shapes and units)."""

    level_mm: int
    key: np.ndarray
    xyz: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    views: np.ndarray
    reprojection_px: np.ndarray
    confidence: np.ndarray
    frame: int = -1
    source: str = "detector"

    def __post_init__(self) -> None:
        n = len(self.key) if isinstance(self.key, np.ndarray) and self.key.ndim == 2 else -1
        c = self.views.shape[1] if isinstance(self.views, np.ndarray) and self.views.ndim == 2 else -1
        expected = {
            "key": ((n, 2), np.int64),
            "xyz": ((n, 3), np.float64),
            "face": ((n,), np.int64),
            "bary": ((n, 3), np.float64),
            "views": ((n, c), np.bool_),
            "reprojection_px": ((n,), np.float64),
            "confidence": ((n,), np.float64),
        }
        check_fields(self, expected, valid=min(n, c) >= 0)
        for name in ("level_mm", "frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"CapturedPoints.{name}: expected an integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.level_mm <= 0:
            raise ValueError(f"CapturedPoints.level_mm: expected a positive number of mm, got {self.level_mm}")
        if not isinstance(self.source, str):
            raise ValueError(f"CapturedPoints.source: expected a string, got {self.source!r}")
        if n and not ((self.confidence >= 0) & (self.confidence <= 1)).all():
            raise ValueError("CapturedPoints.confidence: expected values in [0, 1]")

    def __len__(self) -> int:
        return len(self.key)

    @property
    def num_cameras(self) -> int:
        return self.views.shape[1]

    def select(self, mask: np.ndarray) -> "CapturedPoints":
        """The points at `mask` (boolean (P,) or integer indices)."""
        return CapturedPoints(level_mm=self.level_mm, frame=self.frame, source=self.source,
                              **{name: getattr(self, name)[mask] for name in _ARRAYS})

    @classmethod
    def empty(cls, level_mm: int, num_cameras: int, frame: int = -1, source: str = "detector") -> "CapturedPoints":
        """No points, for `num_cameras` cameras."""
        return cls(level_mm=level_mm, key=np.zeros((0, 2), np.int64), xyz=np.zeros((0, 3)),
                   face=np.zeros(0, np.int64), bary=np.zeros((0, 3)), views=np.zeros((0, num_cameras), bool),
                   reprojection_px=np.zeros(0), confidence=np.zeros(0), frame=frame, source=source)

    # ---- files ---------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write every field to an npz, atomically."""
        save_npz(path, {**{name: getattr(self, name) for name in _ARRAYS}, "level_mm": np.int64(self.level_mm),
                        "frame": np.int64(self.frame), "source": np.array(self.source)})

    @classmethod
    def load(cls, path: str | Path) -> "CapturedPoints":
        """Read a file written by `save`; shapes and dtypes are checked, naming the file."""
        data = load_npz(path, required=_ARRAYS + ("level_mm", "frame", "source"))
        for name, kinds, what in (("level_mm", "iu", "an integer"), ("frame", "iu", "an integer"),
                                  ("source", "U", "a string")):
            if data[name].shape != () or data[name].dtype.kind not in kinds:
                raise ValueError(f"{path}: {name}: expected {what}, got {data[name].dtype} of shape "
                                 f"{data[name].shape}")
        try:
            return cls(level_mm=int(data["level_mm"]), frame=int(data["frame"]), source=str(data["source"]),
                       **{name: data[name] for name in _ARRAYS})
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: {exc}") from exc


def sequence_path(folder: str | Path, frame: int) -> Path:
    """Where frame `frame` of a sequence lives: ``<folder>/f<frame:06d>.npz``."""
    return Path(folder) / f"f{frame:06d}.npz"


def save_sequence(folder: str | Path, sequence: Sequence[CapturedPoints]) -> list[Path]:
    """Write one npz per frame (`sequence_path`); frames must be distinct and share one level."""
    frames = [points.frame for points in sequence]
    if len(set(frames)) != len(frames) or min(frames, default=0) < 0:
        raise ValueError(f"{folder}: a saved sequence needs distinct, known (>= 0) frame numbers, got {frames}")
    levels = {points.level_mm for points in sequence}
    if len(levels) > 1:
        raise ValueError(f"{folder}: a sequence shares one template level, got levels {sorted(levels)} mm")
    paths = []
    for points in sequence:
        paths.append(sequence_path(folder, points.frame))
        points.save(paths[-1])
    return paths


def load_sequence(folder: str | Path) -> list[CapturedPoints]:
    """Every ``f<frame>.npz`` of `folder`, in frame order; they must share one level and camera count."""
    folder = Path(folder)
    files = sorted(folder.glob("f*.npz"))
    if not files:
        raise ValueError(f"{folder}: no captured points (f<frame>.npz files)")
    sequence = sorted((CapturedPoints.load(f) for f in files), key=lambda p: p.frame)
    levels = {p.level_mm for p in sequence}
    cameras = {p.num_cameras for p in sequence}
    if len(levels) > 1 or len(cameras) > 1:
        raise ValueError(f"{folder}: frames disagree on the level ({sorted(levels)} mm) or the number of cameras "
                         f"({sorted(cameras)})")
    return sequence
