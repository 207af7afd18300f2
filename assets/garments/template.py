"""The garment template: the model every captured point refers to.

A `Template` is a sewing pattern, its sheet layout (marker tiling and texture placement), and meshes
at four resolution levels (grid spacing 12, 4, 2, 1 mm: the reference's 12x, 4x, 2x, 1x).  Levels are
built on first use and stored in the template's npz under keys ``L{mm}/...``; `Template.load` reads
a level's arrays only when that level is asked for, so the 1 mm level (about a million vertices for a
shirt) costs nothing until used.

`Level` arrays (V vertices, F faces, S seam pairs), all in the unsewn mesh (each panel separate):
  pattern_xy (V, 2) float64   position on the flat panel, metres, panel frame
  panel      (V,) int16       panel index into pattern.panels
  faces      (F, 3) int32     counter-clockwise seen from the outside
  flags      (V,) uint8       mesh.GRID | BOUNDARY | SEAM | STEINER
  uv         (V, 2) float32   texture coordinates on the sheet (origin bottom-left)
  crosspoint (V,) int64       garment-global crosspoint index at this vertex, or -1
  seam_pairs (S, 2) int32     vertex pairs to sew
  seam       (S,) int16       which seam of pattern.seams each pair belongs to
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from assets.fileio import load_npz, save_npz
from assets.garments.layout import SheetLayout, layout_garment
from assets.garments.mesh import mesh_panel, seam_segment_counts
from assets.garments.sewing import SewingPattern
from assets.pattern.spec import PatternSpec

LEVELS_MM = (12, 4, 2, 1)
_LEVEL_KEYS = ("pattern_xy", "panel", "faces", "flags", "uv", "crosspoint", "seam_pairs", "seam")
#: a level array's shape (V vertices, F faces, S seam pairs, -1 any) and numpy dtype kinds
_LEVEL_LAYOUT = {
    "pattern_xy": (("V", 2), "f"),
    "panel": (("V",), "iu"),
    "faces": ((-1, 3), "iu"),
    "flags": (("V",), "iu"),
    "uv": (("V", 2), "f"),
    "crosspoint": (("V",), "iu"),
    "seam_pairs": ((-1, 2), "iu"),
    "seam": (("S",), "iu"),
}


@dataclass(frozen=True)
class Level:
    spacing_mm: int
    pattern_xy: np.ndarray
    panel: np.ndarray
    faces: np.ndarray
    flags: np.ndarray
    uv: np.ndarray
    crosspoint: np.ndarray
    seam_pairs: np.ndarray
    seam: np.ndarray

    @property
    def num_vertices(self) -> int:
        return len(self.pattern_xy)

    @cached_property
    def sewn_index(self) -> np.ndarray:
        """(V,) int64: the vertex of the sewn mesh each vertex becomes (seam pairs merged)."""
        n = self.num_vertices
        pairs = self.seam_pairs
        graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
        # number merged vertices by their first member, so the sewn order follows the unsewn one
        _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
        order = np.argsort(np.argsort(first))
        return order[inverse]

    @cached_property
    def sewn_faces(self) -> np.ndarray:
        """(F, 3) int32 faces of the sewn mesh."""
        return self.sewn_index[self.faces].astype(np.int32)

    @property
    def num_sewn_vertices(self) -> int:
        return int(self.sewn_index.max()) + 1

    def sew(self, positions: np.ndarray) -> np.ndarray:
        """Unsewn per-vertex values (..., V, D) -> sewn (..., Vs, D), averaging merged vertices."""
        n = self.num_sewn_vertices
        weight = np.bincount(self.sewn_index, minlength=n).astype(np.float64)
        moved = np.moveaxis(np.asarray(positions, np.float64), -2, 0)
        summed = np.zeros((n,) + moved.shape[1:])
        np.add.at(summed, self.sewn_index, moved)
        return np.moveaxis(summed / weight.reshape((n,) + (1,) * (moved.ndim - 1)), 0, -2)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {key: getattr(self, key) for key in _LEVEL_KEYS}


@dataclass(frozen=True)
class Prolongation:
    """Fine vertex -> coarse triangle and barycentric coordinates (exact in pattern space)."""

    triangle: np.ndarray  # (Vf,) int64 coarse face index
    barycentric: np.ndarray  # (Vf, 3) float64; slightly outside [0, 1] where a curved outline bulges

    def __call__(self, coarse_faces: np.ndarray, coarse_values: np.ndarray) -> np.ndarray:
        """Coarse per-vertex values (..., Vc, D) -> fine (..., Vf, D)."""
        corners = np.asarray(coarse_values)[..., coarse_faces[self.triangle], :]  # (..., Vf, 3, D)
        return np.einsum("...vkd,vk->...vd", corners, self.barycentric)


class Template:
    """A garment template: pattern + layout + lazily built or loaded levels."""

    def __init__(
        self, pattern: SewingPattern, layout: SheetLayout, source: Path | None = None, stored: tuple[int, ...] = ()
    ):
        self.pattern = pattern
        self.layout = layout
        self._source = source  # npz holding the levels in `stored`, read on demand
        self._stored = stored
        self._levels: dict[int, Level] = {}

    @classmethod
    def build(cls, pattern: SewingPattern, spec: PatternSpec = PatternSpec(), dpi: float = 300.0) -> "Template":
        return cls(pattern, layout_garment(pattern, spec, dpi))

    @property
    def name(self) -> str:
        return self.pattern.name

    def level(self, spacing_mm: int) -> Level:
        """The mesh at `spacing_mm` (one of LEVELS_MM or any whole number of mm)."""
        if spacing_mm not in self._levels:
            self._levels[spacing_mm] = self._read_level(spacing_mm) or self._build_level(spacing_mm)
        return self._levels[spacing_mm]

    def prolongation(self, coarse_mm: int, fine_mm: int) -> Prolongation:
        """Locate every fine vertex in the coarse mesh of the same panel."""
        coarse, fine = self.level(coarse_mm), self.level(fine_mm)
        triangle = np.zeros(fine.num_vertices, dtype=np.int64)
        bary = np.zeros((fine.num_vertices, 3))
        for p in range(len(self.pattern.panels)):
            faces = np.flatnonzero(coarse.panel[coarse.faces[:, 0]] == p)
            verts = np.flatnonzero(fine.panel == p)
            t, b = _locate(coarse.pattern_xy, coarse.faces[faces], fine.pattern_xy[verts])
            triangle[verts], bary[verts] = faces[t], b
        return Prolongation(triangle, bary)

    def upsample(self, coarse_positions: np.ndarray, coarse_mm: int, fine_mm: int) -> np.ndarray:
        """Coarse positions (..., Vc, 3) -> fine (..., Vf, 3); seam pairs of the fine level are set to
        their mean so the sewn fine mesh stays closed."""
        fine = self.level(fine_mm)
        out = self.prolongation(coarse_mm, fine_mm)(self.level(coarse_mm).faces, coarse_positions)
        return fine.sew(out)[..., fine.sewn_index, :]

    # ---- building ------------------------------------------------------------------------------
    def _build_level(self, spacing_mm: int) -> Level:
        h = spacing_mm * 1e-3
        counts = seam_segment_counts(self.pattern, h)
        sewn: dict[int, set[int]] = {i: set() for i in range(len(self.pattern.panels))}
        for seam in self.pattern.seams:
            for side in (seam.a, seam.b):
                pi = self.pattern.panel_index(side.panel)
                sewn[pi].add(self.pattern.panels[pi].edge_index(side.edge))
        parts, offsets, offset = [], [], 0
        for p, (panel, sheet) in enumerate(zip(self.pattern.panels, self.layout.panels)):
            mesh = mesh_panel(panel, h, counts[p], np.asarray(sheet.spec.origin_xy), sewn[p])
            parts.append(mesh)
            offsets.append(offset)
            offset += len(mesh.vertices)
        pairs = []
        for seam in self.pattern.seams:
            pa, pb = self.pattern.panel_index(seam.a.panel), self.pattern.panel_index(seam.b.panel)
            va = parts[pa].edge_vertices[self.pattern.panels[pa].edge_index(seam.a.edge)] + offsets[pa]
            vb = parts[pb].edge_vertices[self.pattern.panels[pb].edge_index(seam.b.edge)] + offsets[pb]
            pairs.append(np.stack([va, vb[::-1] if seam.reverse else vb], axis=1))
        pattern_xy = np.concatenate([m.vertices for m in parts])
        panel = np.concatenate([np.full(len(m.vertices), p, np.int16) for p, m in enumerate(parts)])
        uv = np.concatenate([self.layout.uv(p, m.vertices) for p, m in enumerate(parts)]).astype(np.float32)
        crosspoint = np.concatenate([self._crosspoints(p, m.vertices) for p, m in enumerate(parts)])
        return Level(
            spacing_mm=spacing_mm,
            pattern_xy=pattern_xy,
            panel=panel,
            faces=np.concatenate([m.faces + o for m, o in zip(parts, offsets)]).astype(np.int32),
            flags=np.concatenate([m.flags for m in parts]),
            uv=uv,
            crosspoint=crosspoint,
            seam_pairs=np.concatenate(pairs).astype(np.int32) if pairs else np.zeros((0, 2), np.int32),
            seam=np.concatenate([np.full(len(p), i, np.int16) for i, p in enumerate(pairs)]) if pairs
            else np.zeros(0, np.int16),
        )

    def _crosspoints(self, panel: int, xy: np.ndarray) -> np.ndarray:
        sheet = self.layout.panels[panel]
        uv = sheet.spec.xy_to_uv(xy)
        whole = np.rint(uv)
        rows, cols = sheet.spec.grid_shape
        on = (np.abs(uv - whole).max(axis=1) < 1e-6) & (whole[:, 0] >= 0) & (whole[:, 1] >= 0)
        on &= (whole[:, 0] < cols) & (whole[:, 1] < rows)
        index = sheet.first_crosspoint + whole[:, 1].astype(np.int64) * cols + whole[:, 0].astype(np.int64)
        return np.where(on, index, -1)

    # ---- files ---------------------------------------------------------------------------------
    def save(self, path: str | Path, levels: tuple[int, ...] | None = None) -> None:
        """Write pattern, layout and the given levels (default: every level built or on file)."""
        if levels is None:
            levels = tuple(sorted(set(self._levels) | set(self._stored), reverse=True))
        arrays: dict[str, np.ndarray] = {
            "pattern_json": _text(json.dumps(self.pattern.to_dict())),
            "layout_json": _text(json.dumps(self.layout.to_dict())),
            "levels_mm": np.asarray(levels, dtype=np.int64),
        }
        for mm in levels:
            arrays.update({f"L{mm}/{k}": v for k, v in self.level(mm).to_arrays().items()})
        save_npz(path, arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Template":
        """A saved template; its pattern and layout are checked now, each level's arrays when it is
        first read (`_read_level`).  Errors name the file and the array."""
        path = Path(path)
        data = load_npz(path, only=("pattern_json", "layout_json", "levels_mm"))
        pattern = SewingPattern.from_dict(_json(data["pattern_json"], f"{path}: pattern_json"), f"{path}: pattern_json")
        layout = SheetLayout.from_dict(_json(data["layout_json"], f"{path}: layout_json"), f"{path}: layout_json")
        if [p.name for p in layout.panels] != [p.name for p in pattern.panels]:
            raise ValueError(f"{path}: layout_json lays out panels {[p.name for p in layout.panels]}, "
                             f"pattern_json has {[p.name for p in pattern.panels]}")
        levels = data["levels_mm"]
        if levels.ndim != 1 or levels.dtype.kind not in "iu" or (levels <= 0).any():
            raise ValueError(f"{path}: levels_mm must be a list of positive whole millimetres, got {levels!r}")
        return cls(pattern, layout, source=path, stored=tuple(int(v) for v in levels))

    def _read_level(self, spacing_mm: int) -> Level | None:
        if spacing_mm not in self._stored:
            return None
        keys = tuple(f"L{spacing_mm}/{k}" for k in _LEVEL_KEYS)
        data = load_npz(self._source, only=keys)
        arrays = {k: data[f"L{spacing_mm}/{k}"] for k in _LEVEL_KEYS}
        _check_level(arrays, len(self.pattern.panels), len(self.pattern.seams), f"{self._source}: L{spacing_mm}")
        return Level(spacing_mm, **arrays)


def _check_level(arrays: dict[str, np.ndarray], num_panels: int, num_seams: int, source: str) -> None:
    """Refuse level arrays of the wrong shape or dtype, or whose indices point past what they index
    (a face past the vertices would fail deep inside every consumer); errors name `source`/array."""
    xy = arrays["pattern_xy"]
    sizes = {"V": len(xy) if xy.ndim else -1, "S": len(arrays["seam_pairs"]) if arrays["seam_pairs"].ndim else -1}
    for key, (shape, kinds) in _LEVEL_LAYOUT.items():
        array = arrays[key]
        wanted = tuple(sizes.get(s, s) for s in shape)
        if (array.dtype.kind not in kinds or array.ndim != len(wanted)
                or any(w != -1 and w != a for w, a in zip(wanted, array.shape))):
            named = "x".join(str(s) for s in shape).replace("-1", "any")
            raise ValueError(f"{source}/{key}: expected {named} of dtype kind {kinds} (V = {sizes['V']} vertices, "
                             f"S = {sizes['S']} seam pairs), got {array.shape} {array.dtype}")
    for key in ("pattern_xy", "uv"):
        if not np.isfinite(arrays[key]).all():
            raise ValueError(f"{source}/{key}: not finite")
    bounds = {"faces": (0, sizes["V"]), "seam_pairs": (0, sizes["V"]), "panel": (0, num_panels),
              "seam": (0, num_seams), "crosspoint": (-1, np.iinfo(np.int64).max)}
    for key, (low, high) in bounds.items():
        array = arrays[key]
        if array.size and not (low <= array.min() and array.max() < high):
            raise ValueError(f"{source}/{key}: values must be in [{low}, {high}), found {array.min()} .. {array.max()}")


def _json(array: np.ndarray, source: str) -> object:
    """JSON text stored as a uint8 array, parsed; ValueError naming `source` if it is not."""
    if array.ndim != 1 or array.dtype != np.uint8:
        raise ValueError(f"{source}: expected JSON text as bytes (uint8), got {array.shape} {array.dtype}")
    try:
        return json.loads(array.tobytes())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{source}: not valid JSON ({exc})") from None


def _text(s: str) -> np.ndarray:
    return np.frombuffer(s.encode(), dtype=np.uint8)


def _locate(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each point (N, 2), the face (of `faces`) containing it, or the one it is least outside,
    and its barycentric coordinates (N, 3) (unclamped, so linear fields are reproduced exactly)."""
    tri = vertices[faces]  # (F, 3, 2)
    centroids = tri.mean(axis=1)
    k = min(12, len(faces))
    _, candidates = cKDTree(centroids).query(points, k=k)
    candidates = candidates.reshape(len(points), k)
    a, b, c = (tri[candidates, i] for i in range(3))  # (N, k, 2)
    v0, v1, v2 = b - a, c - a, points[:, None] - a
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = (v2[..., 0] * v1[..., 1] - v2[..., 1] * v1[..., 0]) / det
    l2 = (v0[..., 0] * v2[..., 1] - v0[..., 1] * v2[..., 0]) / det
    bary = np.stack([1 - l1 - l2, l1, l2], axis=-1)  # (N, k, 3)
    best = bary.min(axis=-1).argmax(axis=1)
    rows = np.arange(len(points))
    return candidates[rows, best], bary[rows, best]
