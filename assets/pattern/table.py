"""The marker table: where every marker, localization point and crosspoint is on the fabric.

Marker IDs are laid out row-major over the R x C marker grid (marker (i, j) has ID
``first_id + i * C + j``) and each uses codebook row ID; a garment gives each panel its own tiling
and a `first_id` after the previous panel's, so IDs are unique across the garment.  The five localization points of a marker are, in its own frame (row 0 at
the top as printed): centre = crosspoint (12, 12), TL = (0, 0), TR = (0, 24), BL = (24, 0),
BR = (24, 24) for the default 25 x 25 crosspoints; the orientation finder is the code-coloured square
inside the TL corner and the centre is the saddle of the central checker.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from assets.fileio import load_npz, save_json, save_npz
from assets.pattern.codebook import codebook_min_distance, generate_codebook
from assets.pattern.spec import PatternSpec

#: Names of the five localization points, in the order every array here uses.
LOCALIZATION_POINTS = ("centre", "TL", "TR", "BL", "BR")


def localization_rc(spec: PatternSpec) -> np.ndarray:
    """(5, 2) int local crosspoint (row, col) of centre, TL, TR, BL, BR in a marker's own frame."""
    return grid_localization_rc(spec.cells_per_side)


def grid_localization_rc(cells_per_side: int) -> np.ndarray:
    """`localization_rc` of a marker of `cells_per_side` cells (crosspoints_per_side - 1)."""
    n = int(cells_per_side)
    return np.array([[n // 2, n // 2], [0, 0], [0, n], [n, 0], [n, n]], dtype=np.int64)


@dataclass(frozen=True)
class MarkerTable:
    """Static geometry of one fabric.  M markers, K = crosspoints_per_side, P global crosspoints.

    Arrays (all derived on demand from `spec` and `codes`):
      marker_ids         (M,) int32          ID of each marker, row-major over the marker grid
      marker_rc          (M, 2) int32        (row i, col j) of each marker in the marker grid
      codes              (M, n, n) uint8     the module grid printed in each marker (1 = code colour)
      crosspoint_index   (M, K, K) int64     global index of each marker's local (row, col) crosspoint
      crosspoint_xy      (P, 2) float64      pattern_xy of every global crosspoint, metres
      localization_xy    (M, 5, 2) float64   centre, TL, TR, BL, BR in pattern_xy, metres
      marker_crosspoint_xy (M, K, K, 2) float64  pattern_xy of each marker's local (row, col)
      crosspoint_markers (P, 4, 3) int32     inverse lookup: (marker ID, local row, local col) for up
                                             to 4 markers sharing the crosspoint, rows of -1 after
    """

    spec: PatternSpec
    codes: np.ndarray
    first_id: int = 0

    @classmethod
    def build(cls, spec: PatternSpec, codebook: np.ndarray | None = None, first_id: int = 0) -> "MarkerTable":
        """The table for `spec` with IDs from `first_id`; `codebook` (num_ids, n, n) is generated
        from the spec if not given."""
        if codebook is None:
            codebook = generate_codebook(spec)
        count = spec.rows * spec.cols
        if first_id < 0 or first_id + count > len(codebook):
            raise ValueError(
                f"markers {first_id}..{first_id + count - 1} do not fit the codebook of {len(codebook)} IDs; "
                "raise num_ids"
            )
        return cls(spec=spec, codes=codebook[first_id : first_id + count], first_id=first_id)

    @property
    def num_markers(self) -> int:
        return self.spec.rows * self.spec.cols

    @cached_property
    def marker_ids(self) -> np.ndarray:
        return self.first_id + np.arange(self.num_markers, dtype=np.int32)

    @cached_property
    def marker_rc(self) -> np.ndarray:
        return np.stack(np.divmod(self.marker_ids - self.first_id, self.spec.cols), axis=1).astype(np.int32)

    @cached_property
    def crosspoint_index(self) -> np.ndarray:
        n = self.spec.cells_per_side
        grid_cols = self.spec.grid_shape[1]
        local = np.arange(n + 1)
        gr = self.marker_rc[:, 0, None, None] * n + local[None, :, None]
        gc = self.marker_rc[:, 1, None, None] * n + local[None, None, :]
        return (gr * grid_cols + gc).astype(np.int64)

    @cached_property
    def crosspoint_xy(self) -> np.ndarray:
        rows, cols = self.spec.grid_shape
        gr, gc = np.divmod(np.arange(rows * cols), cols)
        return self.spec.uv_to_xy(np.stack([gc, gr], axis=1))

    @cached_property
    def marker_crosspoint_xy(self) -> np.ndarray:
        return self.crosspoint_xy[self.crosspoint_index]

    @cached_property
    def localization_xy(self) -> np.ndarray:
        rc = localization_rc(self.spec)
        index = self.crosspoint_index[:, rc[:, 0], rc[:, 1]]
        return self.crosspoint_xy[index]

    @cached_property
    def crosspoint_markers(self) -> np.ndarray:
        k = self.spec.crosspoints_per_side
        m = self.num_markers
        index = self.crosspoint_index.reshape(-1)
        ids = np.repeat(self.marker_ids, k * k)
        rows = np.tile(np.repeat(np.arange(k), k), m)
        cols = np.tile(np.arange(k), k * m)
        order = np.argsort(index, kind="stable")
        index, ids, rows, cols = index[order], ids[order], rows[order], cols[order]
        first = np.searchsorted(index, index, side="left")
        slot = np.arange(len(index)) - first
        out = np.full((self.spec.num_crosspoints, 4, 3), -1, dtype=np.int32)
        out[index, slot] = np.stack([ids, rows, cols], axis=1)
        return out

    def markers_of_crosspoint(self, index: int) -> list[tuple[int, int, int]]:
        """(marker ID, local row, local col) for every marker containing global crosspoint `index`."""
        rows = self.crosspoint_markers[index]
        return [tuple(int(v) for v in row) for row in rows if row[0] >= 0]

    @cached_property
    def codebook_hash(self) -> str:
        """SHA-256 of the codes in use: detects a codebook that differs between machines."""
        return hashlib.sha256(np.ascontiguousarray(self.codes, dtype=np.uint8).tobytes()).hexdigest()

    # ---- files ---------------------------------------------------------------------------------
    def save(self, npz_path: str | Path, json_path: str | Path | None = None) -> None:
        """Write every array to `npz_path` and, if given, a small human-readable summary JSON."""
        save_npz(
            npz_path,
            {
                "marker_ids": self.marker_ids,
                "marker_rc": self.marker_rc,
                "codes": self.codes,
                "crosspoint_index": self.crosspoint_index,
                "crosspoint_xy": self.crosspoint_xy,
                "localization_xy": self.localization_xy,
                "marker_crosspoint_xy": self.marker_crosspoint_xy,
                "crosspoint_markers": self.crosspoint_markers,
                "spec_json": np.frombuffer(_spec_json(self.spec), dtype=np.uint8),
                "first_id": np.int64(self.first_id),
            },
        )
        if json_path is not None:
            save_json(json_path, self.summary())

    def summary(self) -> dict[str, object]:
        spec = self.spec
        xmin, ymin, xmax, ymax = spec.fabric_bounds
        return {
            "spec": spec.to_dict(),
            "markers": self.num_markers,
            "first_id": self.first_id,
            "marker_grid": [spec.rows, spec.cols],
            "marker_size_m": spec.marker_size,
            "crosspoints": spec.num_crosspoints,
            "crosspoint_grid": list(spec.grid_shape),
            "fabric_bounds_m": [xmin, ymin, xmax, ymax],
            "localization_points": list(LOCALIZATION_POINTS),
            "code_modules": [spec.modules_per_side, spec.modules_per_side],
            "min_code_distance": codebook_min_distance(self.codes),
            "codebook_sha256": self.codebook_hash,
        }

    @classmethod
    def load(cls, npz_path: str | Path) -> "MarkerTable":
        """Read a table written by `save`; the spec and codes are validated against each other."""
        data = load_npz(npz_path, required=("codes", "spec_json"))
        try:
            spec_dict = json.loads(data["spec_json"].tobytes().decode())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{npz_path}: spec_json is not valid JSON ({exc})") from exc
        spec = PatternSpec.from_dict(spec_dict, source=f"{npz_path}:spec_json")
        codes = data["codes"]
        n = spec.modules_per_side
        if codes.shape != (spec.rows * spec.cols, n, n):
            raise ValueError(
                f"{npz_path}: codes has shape {codes.shape}, expected {(spec.rows * spec.cols, n, n)}"
            )
        first_id = int(data["first_id"]) if "first_id" in data else 0
        return cls(spec=spec, codes=codes.astype(np.uint8), first_id=first_id)


def _spec_json(spec: PatternSpec) -> bytes:
    return json.dumps(spec.to_dict(), sort_keys=True).encode()
