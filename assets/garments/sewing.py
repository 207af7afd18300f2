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

from assets.fileio import load_json, safe_name, save_json
from assets.polylines import first_crossing

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
#: no panel reaches further across than this (metres) unless the loader is told `max_panel_m`
MAX_PANEL_M = 3.0
#: the self-crossing check samples an outline with at most about this many points (plus one per edge)
_CHECK_POINTS = 20_000


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
    def from_dict(cls, data: Any, source: str = "pattern", max_panel_m: float = MAX_PANEL_M) -> "SewingPattern":
        """The pattern of a parsed JSON object; PatternError naming `source` and the field of any
        problem.  max_panel_m: the largest extent a panel may reach (`check_panel_size`)."""
        if not isinstance(data, dict):
            raise PatternError(f"{source}: expected a JSON object")
        name = pattern_name(data.get("name", Path(source).stem), f"{source}: name")
        raw_panels = data.get("panels")
        if not isinstance(raw_panels, list) or not raw_panels:
            raise PatternError(f"{source}: 'panels' must be a non-empty list")
        raw_seams = data.get("seams", [])
        if not isinstance(raw_seams, list):
            raise PatternError(f"{source}: 'seams' must be a list, got {type(raw_seams).__name__}")
        panels = tuple(_panel_from_dict(p, f"{source}: panel #{i}") for i, p in enumerate(raw_panels))
        seams = tuple(_seam_from_dict(s, f"{source}: seam #{i}") for i, s in enumerate(raw_seams))
        pattern = cls(name=name, panels=panels, seams=seams)
        validate(pattern, source, max_panel_m)
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
    def load(cls, path: str | Path, max_panel_m: float = MAX_PANEL_M) -> "SewingPattern":
        return cls.from_dict(load_json(path), str(path), max_panel_m)

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


def edge_hull(panel: Panel, k: int) -> np.ndarray:
    """(m, 2) points whose bounding box holds edge k, without sampling it: a Bezier lies in the hull of
    its control points; every point of an arc is within sqrt((chord / 2)^2 + sagitta^2) of the chord's
    midpoint (minor arcs stay in the chord-by-sagitta rectangle, major ones in their circle)."""
    start, end = panel.vertices[k], panel.vertices[(k + 1) % len(panel.vertices)]
    curve = panel.edges[k].curve
    if curve.type == "arc":
        reach = math.hypot(float(np.linalg.norm(end - start)) / 2, curve.sagitta)
        return (start + end) / 2 + reach * np.array([[-1.0, -1.0], [1.0, 1.0]])
    return np.concatenate([[start, end], np.reshape(curve.control, (-1, 2))])


def check_panel_size(panel: Panel, where: str, max_panel_m: float = MAX_PANEL_M) -> None:
    """Refuse a panel whose outline may reach more than `max_panel_m` across (an arc of a huge
    sagitta, a control point far away, vertices in the wrong unit) before anything samples it; the
    error names the edge reaching furthest."""
    hulls = [edge_hull(panel, k) for k in range(len(panel.edges))]
    size = float(np.ptp(np.concatenate(hulls), axis=0).max())
    if size <= max_panel_m:
        return
    widest = max(range(len(hulls)), key=lambda k: float(np.ptp(hulls[k], axis=0).max()))
    raise PatternError(f"{where}, edge '{panel.edges[widest].name}': the panel reaches up to {size:,.4g} m across, "
                       f"above the limit of {max_panel_m:g} m (check the edge's sagitta or control points and the "
                       "units); raise max_panel_m (--max-panel-m of python -m assets.garments build) if "
                       "this is intended")


def pattern_name(name: Any, source: str) -> str:
    """`name` if it can be part of a file name (`safe_name`), else PatternError naming `source`."""
    try:
        return safe_name(name, source)
    except ValueError as exc:
        raise PatternError(str(exc)) from None


# ---- validation --------------------------------------------------------------------------------
def validate(pattern: SewingPattern, source: str = "pattern", max_panel_m: float = MAX_PANEL_M) -> None:
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
        check_panel_size(panel, where, max_panel_m)
        length = sum(panel.edge_length(k) for k in range(len(panel.edges)))
        outline = panel.outline(max(1e-3, math.sqrt(abs(polygon_area(panel.vertices)) + 1e-12) / 200,
                                    length / _CHECK_POINTS))
        crossing = first_crossing(outline)
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
    """`value` as read from JSON, nested lists of JSON numbers (not strings, booleans or null), as a
    finite float64 array of `shape` (-1: any length); else PatternError naming `where`."""
    raw = np.asarray(value, dtype=object)  # ragged lists stay lists: refused by the shape test
    if raw.ndim != len(shape) or any(s != -1 and s != a for s, a in zip(shape, raw.shape)):
        raise PatternError(f"{where}: expected numbers of shape {shape}, got {_short(value)}")
    kinds = np.asarray(np.frompyfunc(type, 1, 1)(raw))
    if not ((kinds == int) | (kinds == float)).all():  # type(True) is bool, not int
        raise PatternError(f"{where}: expected numbers, got {_short(value)}")
    try:
        array = raw.astype(np.float64)
    except OverflowError:
        raise PatternError(f"{where}: number too large in {_short(value)}") from None
    if not np.isfinite(array).all():
        raise PatternError(f"{where}: not finite")
    return array


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


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
    pattern_name(data["name"], f"{where}: name")
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
    expected = '{"a": {"panel": name, "edge": name}, "b": {"panel": name, "edge": name}, "reverse": true or false}'
    if not isinstance(data, dict):
        raise PatternError(f"{where}: expected {expected}")
    sides = []
    for key in ("a", "b"):
        side = data.get(key)
        if not (isinstance(side, dict) and isinstance(side.get("panel"), str) and isinstance(side.get("edge"), str)):
            raise PatternError(f"{where}: '{key}' must be {{\"panel\": name, \"edge\": name}} (strings), got "
                               f"{_short(side)}; expected {expected}")
        sides.append(SeamSide(side["panel"], side["edge"]))
    reverse = data.get("reverse", True)
    if not isinstance(reverse, bool):  # "false" and 0 would read as true or be guessed at
        raise PatternError(f"{where}: 'reverse' must be true or false (a JSON boolean), got {reverse!r}")
    return Seam(sides[0], sides[1], reverse)
