"""Sewing patterns: flat panels with named, possibly curved edges, seams between edges, placement hints.

JSON format (metres, panel frames as seen from the outside, i.e. the printed side)::

    {
      "name": "shirt",
      "panels": [
        {
          "name": "front",
          "vertices": [[x, y], ...],                      # corners of the outline, counter-clockwise
          "edges": [                                     # edge k runs vertex k -> vertex k+1 (cyclic)
            {"name": "hem"},                                               # straight
            {"name": "side_r", "curve": {"type": "arc", "sagitta": 0.01}},  # circular arc
            {"name": "armhole_r", "curve": {"type": "quadratic", "control": [[x, y]]}},
            {"name": "neck", "curve": {"type": "cubic", "control": [[x, y], [x, y]]}}
          ],
          "placement": {"body_part": "torso_front",      # optional; dressing needs it
                        "rotation_deg": [rx, ry, rz],    # extrinsic XYZ: R = Rz Ry Rx (scipy "xyz")
                        "translation": [x, y, z]}        # where the panel frame's origin goes
        }
      ],
      "seams": [{"a": {"panel": "front", "edge": "side_r"},
                 "b": {"panel": "back", "edge": "side_l"},
                 "reverse": true}]                      # true: a's start meets b's end
    }

`sagitta` is the signed distance from the chord's midpoint to the arc's midpoint, positive to the left
of the edge's direction; |sagitta| > chord / 2 is a major arc.  Bezier control points are absolute
panel coordinates.  Validation names the panel and edge of any problem.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from assets.fileio import load_json, save_json

log = logging.getLogger(__name__)

CURVE_TYPES = ("arc", "quadratic", "cubic")
BODY_PARTS = (
    "torso_front",
    "torso_back",
    "arm_left",
    "arm_right",
    "leg_left",
    "leg_right",
    "waist_front",
    "waist_back",
    "neck",
)
#: seams whose two edges differ in length by more than this fraction are rejected (ease is a few %)
SEAM_LENGTH_TOLERANCE = 0.25
_SAMPLES_PER_CURVE = 256
#: outline points closer than this fraction of the panel's size to a segment's line are on it
_ON_LINE = 1e-9


class PatternError(ValueError):
    """A sewing pattern is malformed; the message names the pattern, panel and edge."""


@dataclass(frozen=True)
class Curve:
    """Shape of an edge between its two end vertices; `type` None is a straight line."""

    type: str | None = None
    sagitta: float = 0.0
    control: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class Edge:
    name: str
    curve: Curve = field(default_factory=Curve)


@dataclass(frozen=True)
class Placement:
    """Dressing hint: which body part the panel wraps and its initial rigid placement."""

    body_part: str
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Panel:
    name: str
    vertices: np.ndarray  # (K, 2) float64, metres
    edges: tuple[Edge, ...]
    placement: Placement | None = None

    def edge_index(self, name: str) -> int:
        for k, edge in enumerate(self.edges):
            if edge.name == name:
                return k
        raise KeyError(name)

    def edge_points(self, k: int, segments: int) -> np.ndarray:
        """(segments + 1, 2) points along edge k, equally spaced in arc length, both ends included."""
        start, end = self.vertices[k], self.vertices[(k + 1) % len(self.vertices)]
        return sample_curve(start, end, self.edges[k].curve, segments)

    def edge_length(self, k: int) -> float:
        start, end = self.vertices[k], self.vertices[(k + 1) % len(self.vertices)]
        return curve_length(start, end, self.edges[k].curve)

    def outline(self, spacing: float) -> np.ndarray:
        """(P, 2) closed outline (last point not repeated) with segments of about `spacing`."""
        parts = []
        for k in range(len(self.edges)):
            n = max(1, math.ceil(self.edge_length(k) / spacing - 1e-9))
            parts.append(self.edge_points(k, n)[:-1])
        return np.concatenate(parts)

    def area(self) -> float:
        """Area enclosed by the exact outline (curves sampled densely), m^2."""
        return polygon_area(self.outline(1e-4))


@dataclass(frozen=True)
class SeamSide:
    panel: str
    edge: str


@dataclass(frozen=True)
class Seam:
    a: SeamSide
    b: SeamSide
    reverse: bool = True


@dataclass(frozen=True)
class SewingPattern:
    name: str
    panels: tuple[Panel, ...]
    seams: tuple[Seam, ...] = ()

    def panel(self, name: str) -> Panel:
        for panel in self.panels:
            if panel.name == name:
                return panel
        raise KeyError(name)

    def panel_index(self, name: str) -> int:
        return [p.name for p in self.panels].index(name)

    # ---- JSON ----------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Any, source: str = "pattern") -> "SewingPattern":
        if not isinstance(data, dict):
            raise PatternError(f"{source}: expected a JSON object")
        name = str(data.get("name", Path(source).stem))
        raw_panels = data.get("panels")
        if not isinstance(raw_panels, list) or not raw_panels:
            raise PatternError(f"{source}: 'panels' must be a non-empty list")
        panels = tuple(_panel_from_dict(p, f"{source}: panel #{i}") for i, p in enumerate(raw_panels))
        seams = tuple(_seam_from_dict(s, f"{source}: seam #{i}") for i, s in enumerate(data.get("seams", [])))
        pattern = cls(name=name, panels=panels, seams=seams)
        validate(pattern, source)
        return pattern

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "panels": [_panel_to_dict(p) for p in self.panels],
            "seams": [
                {"a": {"panel": s.a.panel, "edge": s.a.edge}, "b": {"panel": s.b.panel, "edge": s.b.edge},
                 "reverse": s.reverse}
                for s in self.seams
            ],
        }

    @classmethod
    def load(cls, path: str | Path) -> "SewingPattern":
        return cls.from_dict(load_json(path), source=str(path))

    def save(self, path: str | Path) -> None:
        save_json(path, self.to_dict())


# ---- geometry ----------------------------------------------------------------------------------
def polygon_area(points: np.ndarray) -> float:
    """Signed area of a closed polygon (P, 2); positive when counter-clockwise."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def curve_length(start: np.ndarray, end: np.ndarray, curve: Curve) -> float:
    """Arc length of `curve` from `start` to `end` (curves sampled densely), metres."""
    dense = sample_curve(start, end, curve, _SAMPLES_PER_CURVE if curve.type else 1)
    return float(np.linalg.norm(np.diff(dense, axis=0), axis=1).sum())


def sample_curve(start: np.ndarray, end: np.ndarray, curve: Curve, segments: int) -> np.ndarray:
    """(segments + 1, 2) points from `start` to `end` along `curve`, equally spaced in arc length."""
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    t = np.linspace(0.0, 1.0, segments + 1)
    if curve.type is None:
        return start + t[:, None] * (end - start)
    if curve.type == "arc":
        centre, radius, a0, sweep = arc_geometry(start, end, curve.sagitta)
        angles = a0 + t * sweep
        points = centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        points[0], points[-1] = start, end
        return points
    dense_t = np.linspace(0.0, 1.0, _SAMPLES_PER_CURVE * 4 + 1)
    dense = _bezier(start, end, np.asarray(curve.control, np.float64), dense_t)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    wanted = t * arc[-1]
    param = np.interp(wanted, arc, dense_t)
    points = _bezier(start, end, np.asarray(curve.control, np.float64), param)
    points[0], points[-1] = start, end
    return points


def arc_geometry(start: np.ndarray, end: np.ndarray, sagitta: float) -> tuple[np.ndarray, float, float, float]:
    """Centre (2,), radius, start angle and signed sweep (radians) of the arc start -> end whose
    midpoint is `sagitta` to the left of the chord."""
    chord = end - start
    c = float(np.linalg.norm(chord))
    half = c / 2
    radius = (half * half + sagitta * sagitta) / (2 * abs(sagitta))
    left = np.array([-chord[1], chord[0]]) / c
    mid = (start + end) / 2
    # the centre is on the opposite side of the chord from the arc's midpoint, at distance r - |s|
    centre = mid + left * (np.sign(sagitta) * (abs(sagitta) - radius))
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
    # arc bulging left of start->end turns clockwise around the centre
    sweep = (a1 - a0) % (2 * math.pi)
    if sagitta > 0:
        sweep -= 2 * math.pi
    return centre, radius, a0, sweep


def _bezier(p0: np.ndarray, p3: np.ndarray, control: np.ndarray, t: np.ndarray) -> np.ndarray:
    t = t[:, None]
    if len(control) == 1:
        q = control[0]
        return (1 - t) ** 2 * p0 + 2 * (1 - t) * t * q + t**2 * p3
    c1, c2 = control
    return (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * c1 + 3 * (1 - t) * t**2 * c2 + t**3 * p3


def _segments_cross(points: np.ndarray) -> tuple[int, int] | None:
    """First pair (i, j), i < j, of non-adjacent segments of the closed polyline (P, 2) that cross or
    touch, or None; segment i runs points[i] -> points[i + 1].  A point within `_ON_LINE` of the
    polyline's size from a segment's line counts as on it: the orientation of exactly collinear samples
    (two pieces of one straight edge) is float rounding, about 1e-17 m to either side of the line, and
    no evidence of a crossing."""
    n = len(points)
    a, b = points, np.roll(points, -1, axis=0)
    tolerance = _ON_LINE * float(np.ptp(points, axis=0).max())
    # only segments whose bounding boxes overlap can meet: a few per segment instead of all n^2 pairs
    low, high = np.minimum(a, b) - tolerance, np.maximum(a, b) + tolerance
    (low_x, low_y), (high_x, high_y) = low.T, high.T
    overlap = ((low_x[:, None] <= high_x) & (low_x <= high_x[:, None])
               & (low_y[:, None] <= high_y) & (low_y <= high_y[:, None]))
    i, j = np.nonzero(np.triu(overlap, k=2))  # j >= i + 2: neither the segment itself nor the next one
    keep = ~((i == 0) & (j == n - 1))  # the last segment is adjacent to the first
    i, j = i[keep], j[keep]

    def side_and_on(k: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Side of segment k's line each point p is on (-1, 0 on the line, 1), and whether p is on the
        segment itself; k (m,), p (m, 2)."""
        direction, offset = b[k] - a[k], p - a[k]
        length = np.linalg.norm(direction, axis=1)
        distance = (direction[:, 0] * offset[:, 1] - direction[:, 1] * offset[:, 0]) / length
        along = np.einsum("md,md->m", direction, offset) / length
        side = np.where(np.abs(distance) <= tolerance, 0.0, np.sign(distance))
        return side, (side == 0) & (along >= -tolerance) & (along <= length + tolerance)

    (side_ja, on_ja), (side_jb, on_jb) = side_and_on(i, a[j]), side_and_on(i, b[j])
    (side_ia, on_ia), (side_ib, on_ib) = side_and_on(j, a[i]), side_and_on(j, b[i])
    hit = ((side_ja * side_jb < 0) & (side_ia * side_ib < 0)) | on_ja | on_jb | on_ia | on_ib
    first = np.flatnonzero(hit)
    return (int(i[first[0]]), int(j[first[0]])) if len(first) else None


# ---- validation --------------------------------------------------------------------------------
def validate(pattern: SewingPattern, source: str = "pattern") -> None:
    """Raise PatternError naming the panel and edge of the first problem found."""
    names = [p.name for p in pattern.panels]
    if len(set(names)) != len(names):
        raise PatternError(f"{source}: duplicate panel names {sorted({n for n in names if names.count(n) > 1})}")
    for panel in pattern.panels:
        where = f"{source}: panel '{panel.name}'"
        edge_names = [e.name for e in panel.edges]
        if len(set(edge_names)) != len(edge_names):
            raise PatternError(f"{where}: duplicate edge names")
        for k, edge in enumerate(panel.edges):
            start, end = panel.vertices[k], panel.vertices[(k + 1) % len(panel.vertices)]
            chord = float(np.linalg.norm(end - start))
            if chord < 1e-6:
                raise PatternError(f"{where}, edge '{edge.name}': zero length (vertices {k} and {k + 1} coincide)")
            curve = edge.curve
            if curve.type == "arc" and not abs(curve.sagitta) > 1e-9:
                raise PatternError(f"{where}, edge '{edge.name}': arc needs a non-zero sagitta")
        outline = panel.outline(max(1e-3, math.sqrt(abs(polygon_area(panel.vertices)) + 1e-12) / 200))
        crossing = _segments_cross(outline)
        if crossing is not None:
            raise PatternError(f"{where}: outline crosses or touches itself (near {outline[crossing[0]].round(4).tolist()})")
        if polygon_area(outline) <= 0:
            raise PatternError(
                f"{where}: outline is clockwise; list vertices counter-clockwise as seen from the outside"
            )
        if panel.placement is not None and panel.placement.body_part not in BODY_PARTS:
            raise PatternError(
                f"{where}: placement.body_part '{panel.placement.body_part}' is not one of {', '.join(BODY_PARTS)}"
            )
    used: dict[tuple[str, str], int] = {}
    for i, seam in enumerate(pattern.seams):
        lengths = []
        for side in (seam.a, seam.b):
            where = f"{source}: seam #{i}"
            if side.panel not in names:
                raise PatternError(f"{where}: no panel '{side.panel}'")
            panel = pattern.panel(side.panel)
            try:
                k = panel.edge_index(side.edge)
            except KeyError:
                raise PatternError(f"{where}: panel '{side.panel}' has no edge '{side.edge}'") from None
            if (side.panel, side.edge) in used:
                raise PatternError(
                    f"{where}: panel '{side.panel}', edge '{side.edge}' is already sewn by seam #{used[(side.panel, side.edge)]}"
                )
            used[(side.panel, side.edge)] = i
            lengths.append(panel.edge_length(k))
        if abs(lengths[0] - lengths[1]) > SEAM_LENGTH_TOLERANCE * max(lengths):
            raise PatternError(
                f"{source}: seam #{i} ({seam.a.panel}.{seam.a.edge} {lengths[0]:.3f} m, "
                f"{seam.b.panel}.{seam.b.edge} {lengths[1]:.3f} m): lengths differ by more than "
                f"{SEAM_LENGTH_TOLERANCE:.0%}"
            )


# ---- dict conversion ---------------------------------------------------------------------------
def parse_floats(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    """`value` as a finite float64 array of `shape` (-1: any length), or PatternError naming `where`."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PatternError(f"{where}: expected numbers, got {value!r}") from None
    if array.ndim != len(shape) or any(s != -1 and s != a for s, a in zip(shape, array.shape)):
        raise PatternError(f"{where}: expected shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise PatternError(f"{where}: not finite")
    return array


def _curve_from_dict(data: Any, where: str) -> Curve:
    if data is None:
        return Curve()
    if not isinstance(data, dict) or data.get("type") not in CURVE_TYPES:
        raise PatternError(f"{where}: curve must be an object with type one of {', '.join(CURVE_TYPES)}")
    kind = data["type"]
    if kind == "arc":
        return Curve("arc", sagitta=float(parse_floats(data.get("sagitta"), (), f"{where}: sagitta")))
    count = 1 if kind == "quadratic" else 2
    control = parse_floats(data.get("control"), (count, 2), f"{where}: control")
    return Curve(kind, control=tuple(tuple(map(float, c)) for c in control))


def _panel_from_dict(data: Any, where: str) -> Panel:
    if not isinstance(data, dict) or not isinstance(data.get("name"), str):
        raise PatternError(f"{where}: needs a string 'name'")
    where = where.split(": panel #")[0] + f": panel '{data['name']}'"
    vertices = parse_floats(data.get("vertices"), (-1, 2), f"{where}: vertices")
    raw_edges = data.get("edges")
    if not isinstance(raw_edges, list) or len(raw_edges) != len(vertices) or len(vertices) < 2:
        raise PatternError(f"{where}: needs one edge per vertex (edge k runs vertex k -> k+1), got "
                           f"{len(raw_edges) if isinstance(raw_edges, list) else 'none'} for {len(vertices)} vertices")
    edges = []
    for k, e in enumerate(raw_edges):
        if not isinstance(e, dict) or not isinstance(e.get("name"), str):
            raise PatternError(f"{where}, edge #{k}: needs a string 'name'")
        edges.append(Edge(e["name"], _curve_from_dict(e.get("curve"), f"{where}, edge '{e['name']}'")))
    placement = None
    if data.get("placement") is not None:
        p = data["placement"]
        if not isinstance(p, dict) or not isinstance(p.get("body_part"), str):
            raise PatternError(f"{where}: placement needs a string 'body_part'")
        placement = Placement(
            p["body_part"],
            tuple(parse_floats(p.get("rotation_deg", [0, 0, 0]), (3,), f"{where}: placement.rotation_deg").tolist()),
            tuple(parse_floats(p.get("translation", [0, 0, 0]), (3,), f"{where}: placement.translation").tolist()),
        )
    return Panel(data["name"], vertices, tuple(edges), placement)


def _panel_to_dict(panel: Panel) -> dict[str, Any]:
    edges = []
    for edge in panel.edges:
        entry: dict[str, Any] = {"name": edge.name}
        if edge.curve.type == "arc":
            entry["curve"] = {"type": "arc", "sagitta": edge.curve.sagitta}
        elif edge.curve.type is not None:
            entry["curve"] = {"type": edge.curve.type, "control": [list(c) for c in edge.curve.control]}
        edges.append(entry)
    out: dict[str, Any] = {"name": panel.name, "vertices": panel.vertices.tolist(), "edges": edges}
    if panel.placement is not None:
        out["placement"] = {
            "body_part": panel.placement.body_part,
            "rotation_deg": list(panel.placement.rotation_deg),
            "translation": list(panel.placement.translation),
        }
    return out


def _seam_from_dict(data: Any, where: str) -> Seam:
    try:
        a, b = data["a"], data["b"]
        return Seam(SeamSide(str(a["panel"]), str(a["edge"])), SeamSide(str(b["panel"]), str(b["edge"])),
                    bool(data.get("reverse", True)))
    except (KeyError, TypeError):
        raise PatternError(f'{where}: expected {{"a": {{"panel", "edge"}}, "b": {{"panel", "edge"}}, "reverse"}}') from None
