"""`PatternSpec`: every number that defines a two-level pattern, and the fixed marker layout.

Frames and units
----------------
* Crosspoint grid: global crosspoint (row, col) = (gr, gc); rows grow downwards on the printed
  fabric as seen from the outside, columns to the right.  Continuous grid coordinates (u, v) =
  (column, row) in units of one pitch; crosspoint (gr, gc) sits at (u, v) = (gc, gr).
* Marker (i, j) of the R x C marker grid owns crosspoints gr in [24 i, 24 i + 24] and gc in
  [24 j, 24 j + 24]; neighbours share their border crosspoints.  Local (row, col) in a marker is
  (gr - 24 i, gc - 24 j).
* `pattern_xy` (metres, x right, y up, as sewing patterns are drawn): the fabric's bottom-left
  crosspoint is at `origin_xy`, so crosspoint (gr, gc) is at
  ``origin_xy + pitch * (gc, 24 R - gr)``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from assets.fileio import check_json_object, load_json, save_json

RGB = tuple[int, int, int]

#: Edge length of the orientation finder and of each centre-checker quadrant, in cells.
FEATURE_CELLS = 4
#: crosspoint pitches (mm) that are printable cloth: finer lines blur into the weave, and a coarser
#: marker is wider than the fabric
PITCH_RANGE_MM = (0.5, 50.0)
#: the largest marker: a codebook search compares every pair of module grids
MAX_CROSSPOINTS_PER_SIDE = 97


@dataclass(frozen=True)
class PatternSpec:
    """A two-level pattern: R x C markers of (n x n) crosspoints, with a seeded codebook.

    Lengths in millimetres where the name says `_mm`; colours as 8-bit sRGB.
    """

    pitch_mm: float = 2.0
    crosspoints_per_side: int = 25
    rows: int = 32
    cols: int = 32
    seed: int = 0
    #: number of marker IDs in the codebook (IDs do not depend on the fabric size)
    num_ids: int = 4096
    #: side of one code module in cells; 2 gives a 12 x 12 module code per marker
    cells_per_module: int = 2
    #: the codebook's guaranteed minimum Hamming distance between module grids, all rotations
    min_code_distance: int = 32
    line_width_mm: float = 0.3
    border_line_width_mm: float = 0.8
    background_rgb: RGB = (255, 255, 255)
    code_rgb: RGB = (96, 148, 232)
    line_rgb: RGB = (0, 0, 0)
    #: pattern_xy of the fabric's bottom-left crosspoint, metres
    origin_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        cells = self.crosspoints_per_side - 1
        problems = []
        if not PITCH_RANGE_MM[0] <= self.pitch_mm <= PITCH_RANGE_MM[1]:
            problems.append(f"pitch_mm must be in [{PITCH_RANGE_MM[0]:g}, {PITCH_RANGE_MM[1]:g}] mm, got {self.pitch_mm}")
        if cells < 4 * FEATURE_CELLS or cells % 2 or self.crosspoints_per_side > MAX_CROSSPOINTS_PER_SIDE:
            problems.append(
                f"crosspoints_per_side must be odd and in [{4 * FEATURE_CELLS + 1}, {MAX_CROSSPOINTS_PER_SIDE}], "
                f"got {self.crosspoints_per_side}"
            )
        if self.seed < 0:
            problems.append(f"seed must be >= 0, got {self.seed}")
        if self.cells_per_module not in (1, 2, 4) or cells % self.cells_per_module:
            problems.append(
                f"cells_per_module must be 1, 2 or 4 and divide {cells}, got {self.cells_per_module}"
            )
        if self.rows < 1 or self.cols < 1:
            problems.append(f"rows and cols must be >= 1, got {self.rows} x {self.cols}")
        if self.rows * self.cols > self.num_ids:
            problems.append(
                f"{self.rows} x {self.cols} markers need more than num_ids={self.num_ids} IDs"
            )
        if not 0 < self.line_width_mm < self.pitch_mm / 2:
            problems.append(f"line_width_mm must be in (0, pitch/2), got {self.line_width_mm}")
        if not self.line_width_mm <= self.border_line_width_mm < self.pitch_mm:
            problems.append(
                f"border_line_width_mm must be in [line_width_mm, pitch), got {self.border_line_width_mm}"
            )
        for name in ("background_rgb", "code_rgb", "line_rgb"):
            value = getattr(self, name)
            if len(value) != 3 or not all(0 <= c <= 255 for c in value):
                problems.append(f"{name} must be three integers in 0..255, got {value}")
        if problems:
            raise ValueError("invalid PatternSpec: " + "; ".join(problems))

    # ---- derived sizes -------------------------------------------------------------------------
    @property
    def cells_per_side(self) -> int:
        return self.crosspoints_per_side - 1

    @property
    def modules_per_side(self) -> int:
        return self.cells_per_side // self.cells_per_module

    @property
    def pitch(self) -> float:
        """Crosspoint pitch in metres."""
        return self.pitch_mm * 1e-3

    @property
    def marker_size(self) -> float:
        """Marker edge length in metres."""
        return self.cells_per_side * self.pitch

    @property
    def grid_shape(self) -> tuple[int, int]:
        """Global crosspoint grid (rows, cols)."""
        return self.rows * self.cells_per_side + 1, self.cols * self.cells_per_side + 1

    @property
    def num_crosspoints(self) -> int:
        rows, cols = self.grid_shape
        return rows * cols

    @property
    def fabric_bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the marker grid in pattern_xy metres."""
        x0, y0 = self.origin_xy
        return x0, y0, x0 + self.cols * self.marker_size, y0 + self.rows * self.marker_size

    # ---- coordinate maps -----------------------------------------------------------------------
    def uv_to_xy(self, uv: np.ndarray) -> np.ndarray:
        """Grid coordinates (..., 2) (u = column, v = row, in pitches) -> pattern_xy (..., 2) metres."""
        uv = np.asarray(uv, dtype=np.float64)
        height = self.rows * self.cells_per_side
        x = self.origin_xy[0] + uv[..., 0] * self.pitch
        y = self.origin_xy[1] + (height - uv[..., 1]) * self.pitch
        return np.stack([x, y], axis=-1)

    def xy_to_uv(self, xy: np.ndarray) -> np.ndarray:
        """Inverse of `uv_to_xy`."""
        xy = np.asarray(xy, dtype=np.float64)
        height = self.rows * self.cells_per_side
        u = (xy[..., 0] - self.origin_xy[0]) / self.pitch
        v = height - (xy[..., 1] - self.origin_xy[1]) / self.pitch
        return np.stack([u, v], axis=-1)

    # ---- construction and files ----------------------------------------------------------------
    @classmethod
    def covering(cls, width_m: float, height_m: float, **overrides: object) -> "PatternSpec":
        """The smallest marker grid that covers a `width_m` x `height_m` fabric."""
        if not (width_m > 0 and height_m > 0):
            raise ValueError(f"fabric size must be positive, got {width_m} x {height_m} m")
        probe = cls(**{k: v for k, v in overrides.items() if k not in ("rows", "cols")})
        cols = max(1, math.ceil(width_m / probe.marker_size - 1e-9))
        rows = max(1, math.ceil(height_m / probe.marker_size - 1e-9))
        return dataclasses.replace(probe, rows=rows, cols=cols)

    def to_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, object], source: str = "PatternSpec") -> "PatternSpec":
        check_json_object(data, (f.name for f in dataclasses.fields(cls)), source)
        kwargs = {}
        for name, value in data.items():
            default = getattr(cls, name)
            if isinstance(default, tuple):
                kind = type(default[0])  # colours are whole numbers, origin_xy any numbers
                if (not isinstance(value, (list, tuple)) or len(value) != len(default)
                        or not all(_is_number(v, kind) for v in value)):
                    raise ValueError(f"{source}: field {name} must be a list of {len(default)} "
                                     f"{'whole ' if kind is int else ''}numbers, got {value!r}")
                value = tuple(value)
            elif not _is_number(value, type(default)):
                raise ValueError(f"{source}: field {name} must be a {'whole ' if type(default) is int else ''}"
                                 f"number, got {value!r}")
            kwargs[name] = value
        try:
            return cls(**kwargs)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from exc

    def save(self, path: str | Path) -> None:
        save_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "PatternSpec":
        return cls.from_dict(load_json(path), source=str(path))


def _is_number(value: object, kind: type) -> bool:
    """`value` is a JSON number of `kind`: int for whole-number fields, else any finite number;
    booleans are not numbers here."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return isinstance(value, int) if kind is int else math.isfinite(value)


def fixed_modules(spec: PatternSpec) -> tuple[np.ndarray, np.ndarray]:
    """The modules every marker shares, in the marker's own frame (row 0 at the top).

    Returns (mask, value), both (n, n) with n = modules_per_side: `mask` is True where the module is
    fixed, `value` is 1 (code colour) or 0 (background) there.  The top-left 4 x 4-cell corner is the
    orientation finder (code colour) inside a one-module background ring, so it stays a crisp square
    whatever the code; the three other corners are background; and the central 8 x 8 cells are a
    2 x 2 checker whose saddle is the marker's centre crosspoint.
    """
    n = spec.modules_per_side
    f = FEATURE_CELLS // spec.cells_per_module
    mask = np.zeros((n, n), dtype=bool)
    value = np.zeros((n, n), dtype=np.uint8)
    for rows in (slice(0, f), slice(n - f, n)):
        for cols in (slice(0, f), slice(n - f, n)):
            mask[rows, cols] = True
    mask[: f + 1, : f + 1] = True  # finder plus its ring
    value[:f, :f] = 1
    c = n // 2
    mask[c - f : c + f, c - f : c + f] = True
    value[c - f : c, c - f : c] = 1
    value[c : c + f, c : c + f] = 1
    return mask, value
