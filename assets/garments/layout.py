"""Panel layout: each panel's own marker tiling, and the panels packed on one printable sheet.

Every panel is tiled by markers in its own frame, from the pitch-aligned corner below-left of its
bounding box, with marker IDs following the previous panel's (unique across the garment; markers cut
by the outline are the partial markers the networks must handle).  The panels are shelf-packed on a
sheet of the print width at true scale, turned by multiples of 90 degrees only (so the exact
axis-aligned pattern renderer applies) and placed at whole pixels.  The sheet rendered at `dpi` is at
once the print file and the render texture; `uv` maps panel points onto it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from assets.garments.sewing import SewingPattern
from assets.pattern.codebook import generate_codebook
from assets.pattern.raster import region_shape, render_region, xy_to_pixel
from assets.pattern.spec import PatternSpec
from assets.pattern.table import MarkerTable

#: outlines for the cut line are sampled this finely (metres)
_OUTLINE_STEP = 5e-4


@dataclass(frozen=True)
class PanelSheet:
    """Where one panel's tiling and image are.  bounds: panel-frame region that is printed."""

    name: str
    spec: PatternSpec
    first_id: int
    first_crosspoint: int
    bounds: tuple[float, float, float, float]
    turns: int
    offset_px: tuple[int, int]


@dataclass(frozen=True)
class SheetLayout:
    spec: PatternSpec
    dpi: float
    size_px: tuple[int, int]  # (width, height)
    panels: tuple[PanelSheet, ...]

    @property
    def num_markers(self) -> int:
        return sum(p.spec.rows * p.spec.cols for p in self.panels)

    @property
    def num_crosspoints(self) -> int:
        return sum(p.spec.num_crosspoints for p in self.panels)

    def tables(self, codebook: np.ndarray | None = None) -> list[MarkerTable]:
        """Each panel's marker table (IDs from its first_id)."""
        if codebook is None:
            codebook = generate_codebook(self.spec)
        return [MarkerTable.build(p.spec, codebook, p.first_id) for p in self.panels]

    def sheet_pixels(self, panel: int, xy: np.ndarray) -> np.ndarray:
        """Panel-frame points (N, 2) metres -> continuous sheet pixel coordinates (N, 2)."""
        p = self.panels[panel]
        px = xy_to_pixel(xy, p.bounds, self.dpi)
        height, width = region_shape(p.bounds, self.dpi)
        for _ in range(p.turns):  # np.rot90 turns counter-clockwise: (x, y) -> (y, W - x)
            px = np.stack([px[:, 1], width - px[:, 0]], axis=1)
            width, height = height, width
        return px + np.asarray(p.offset_px, dtype=np.float64)

    def uv(self, panel: int, xy: np.ndarray) -> np.ndarray:
        """Panel-frame points (N, 2) -> texture UV (N, 2), origin bottom-left, v up."""
        px = self.sheet_pixels(panel, xy)
        width, height = self.size_px
        return np.stack([px[:, 0] / width, 1.0 - px[:, 1] / height], axis=1)

    def render(self, pattern: SewingPattern, progress: bool = False) -> np.ndarray:
        """The sheet (H, W, 3) uint8: every panel's pattern inside its outline, with a cut line."""
        width, height = self.size_px
        sheet = np.empty((height, width, 3), dtype=np.uint8)
        sheet[:] = np.asarray(self.spec.background_rgb, dtype=np.uint8)
        from tqdm import tqdm  # here, not at import: Blender's own Python may lack it
        for sheet_panel, table in tqdm(
            list(zip(self.panels, self.tables())), desc="sheet", unit="panel", disable=not progress
        ):
            outline = pattern.panel(sheet_panel.name).outline(_OUTLINE_STEP)
            image = np.rot90(render_region(table, sheet_panel.bounds, self.dpi, [outline]), sheet_panel.turns)
            x, y = sheet_panel.offset_px
            sheet[y : y + image.shape[0], x : x + image.shape[1]] = image
        return sheet

    def to_dict(self) -> dict[str, Any]:
        return {
            "spec": self.spec.to_dict(),
            "dpi": self.dpi,
            "size_px": list(self.size_px),
            "panels": [
                {**dataclasses.asdict(p), "spec": p.spec.to_dict(), "bounds": list(p.bounds),
                 "offset_px": list(p.offset_px)}
                for p in self.panels
            ],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "layout") -> "SheetLayout":
        try:
            panels = tuple(
                PanelSheet(
                    name=p["name"],
                    spec=PatternSpec.from_dict(p["spec"], f"{source}: panel {p['name']}"),
                    first_id=int(p["first_id"]),
                    first_crosspoint=int(p["first_crosspoint"]),
                    bounds=tuple(float(v) for v in p["bounds"]),
                    turns=int(p["turns"]),
                    offset_px=tuple(int(v) for v in p["offset_px"]),
                )
                for p in data["panels"]
            )
            return cls(PatternSpec.from_dict(data["spec"], source), float(data["dpi"]),
                       tuple(int(v) for v in data["size_px"]), panels)
        except (KeyError, TypeError, ValueError) as exc:
            if str(exc).startswith(source):  # a PatternSpec's own error names the source already
                raise
            raise ValueError(f"{source}: malformed layout ({exc!r})") from exc


def layout_garment(
    pattern: SewingPattern,
    spec: PatternSpec = PatternSpec(),
    dpi: float = 300.0,
    sheet_width_m: float = 1.5,
    gap_m: float = 0.01,
) -> SheetLayout:
    """Tile every panel with markers and pack the panels on a sheet `sheet_width_m` wide."""
    ppm = dpi / 0.0254
    sheet_width = math.ceil(sheet_width_m * ppm)
    gap = math.ceil(gap_m * ppm)
    tilings, sizes = [], []
    first_id = first_crosspoint = 0
    for panel in pattern.panels:
        outline = panel.outline(_OUTLINE_STEP)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        origin = np.floor(lo / spec.pitch) * spec.pitch
        cols, rows = np.ceil((hi - origin) / spec.marker_size - 1e-9).astype(int)
        panel_spec = dataclasses.replace(spec, rows=int(rows), cols=int(cols), origin_xy=(float(origin[0]), float(origin[1])))
        bounds = (float(lo[0] - gap_m / 2), float(lo[1] - gap_m / 2), float(hi[0] + gap_m / 2), float(hi[1] + gap_m / 2))
        height, width = region_shape(bounds, dpi)
        turns = 1 if width > sheet_width else 0
        if turns:
            width, height = height, width
        if width > sheet_width:
            raise ValueError(f"panel '{panel.name}' ({width / ppm:.2f} m) does not fit a {sheet_width_m} m sheet")
        tilings.append((panel.name, panel_spec, first_id, first_crosspoint, bounds, turns))
        sizes.append((width, height))
        first_id += panel_spec.rows * panel_spec.cols
        first_crosspoint += panel_spec.num_crosspoints
    if first_id > spec.num_ids:
        raise ValueError(f"the garment needs {first_id} markers but the codebook has {spec.num_ids}; raise num_ids")
    # shelf packing, tallest first
    order = sorted(range(len(sizes)), key=lambda i: -sizes[i][1])
    offsets: dict[int, tuple[int, int]] = {}
    x = y = shelf = 0
    for i in order:
        width, height = sizes[i]
        if x + width > sheet_width:
            x, y, shelf = 0, y + shelf + gap, 0
        offsets[i] = (x, y)
        x += width + gap
        shelf = max(shelf, height)
    panels = tuple(PanelSheet(*tilings[i], offset_px=offsets[i]) for i in range(len(tilings)))
    return SheetLayout(spec, dpi, (sheet_width, y + shelf), panels)
