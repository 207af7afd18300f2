"""Import GarmentCode pattern specifications (``*_specification.json``) as a `SewingPattern`.

    pattern = load_garmentcode("assets/data/garmentcode/shirt_mean_specification.json")
    python -m assets.garments.garmentcode IN_specification.json OUT.json

GarmentCode's conventions (Korosteleva & Sorkine-Hornung 2023, package `pygarment`; where each is
defined in github.com/maria-korosteleva/GarmentCode):

* Units: `properties.units_in_meter` (100 = centimetres) scales vertices, translations and radii.
* Panel: `vertices` [[x, y], ...] and `edges` [{endpoints [i, j], curvature?, label?}] forming one loop.
* Relative curve coordinates (`curvature_coords: 'relative'`; pattern/utils.py `rel_to_abs_2d`):
  control point (u, v) -> start + u * d + v * (-d_y, d_x) with d = end - start, i.e. u along the edge,
  v to the LEFT of start->end, both as fractions of the chord length.  'absolute' control points are
  panel coordinates.  A bare list `curvature: [u, v]` (older versions) is one quadratic control point.
* Circle `params: [radius, large_arc, right]` (garmentcode/edge.py `CircleEdge.as_radius_flag`, drawn by
  meshgen/boxmeshgen.py `Edge.init_curve` as an SVG arc with sweep = right in the y-up panel frame):
  right = 1 when the arc bulges to the right of start->end (its midpoint has relative v < 0);
  large_arc = 1 for the major arc (the midpoint lies beyond the centre).
* Placement (pattern/core.py `_point_in_3D`, pattern/rotation.py `euler_xyz_to_R`): a panel point goes
  to R @ (x, y, 0) + translation, rotating about the panel's 2D origin, R = Rz(c) Ry(b) Rx(a) for
  `rotation` [a, b, c] degrees (Maya's xyz order, scipy 'xyz').  The generator (garmentcode/panel.py)
  writes `as_euler('XYZ')` (Rx Ry Rz); the two agree when at most one angle is non-zero, as in every
  shipped file, and we follow the reader that the simulator uses.
* World: Y up, the body's front faces +Z, +X is the body's left (core.py `_panel_universal_transtation`
  takes max Y as the top; front panels have z > 0 and `left_*` panels x > 0).
* A counter-clockwise outline has normal R @ +Z; `Panel.autonorm` turns it away from the world origin,
  and stitches sew right side to right side (boxmeshgen `Seam.swap`: one edge's end meets the other's
  start), so on a well-formed garment every seam comes out `reverse=True`.

Conversion: world_ours = C @ world_gc with C = +90 degrees about X, (x, y, z) -> (x, -z, y), so Z is up
and the front faces -Y.  A panel's outside is the side its normal takes away from the garment's centre
(centre of the bounding box of all placed outlines).  A panel whose traversal runs clockwise seen from
outside has its loop reversed (vertex order and curve directions); then a panel whose outline is
clockwise in its own frame is mirrored (x -> -x, arc sagittas negated) and its placement composed with
180 degrees about the local Y axis.  Every 3D point stays where GarmentCode put it, except on arm panels
(`_straighten_arms`): GarmentCode places sleeves on its A-pose body's arms, about 50 degrees down, and
our hints are for the T-pose, so each arm's panels turn up about the sleeve's cap end.  Positions stay
those of GarmentCode's mean body (1.72 m tall; our default body 1.70 m): dressing on another body shape
moves each panel with its body part (`factory.dressing.placement_shifts`).  Edges keep their names
(the label if unique in the panel, else `e{index}` with GarmentCode's edge index) whatever their new
position in the loop.  Seam `reverse` follows GarmentCode's stitch meaning exactly: right side to
right side (one edge's end meets the other's start) unless the stitch is tagged 'right_wrong', then
flipped once for each of the two panels whose loop was reversed.  The 3D endpoints do not decide it:
GarmentCode places panels loosely (front and back 45 cm apart), so on short edges the two pairings
differ by less than 0.1 mm; a pairing that is clearly the farther one is logged as a warning.  Body
parts come from `_body_part`.
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from assets.cli import run_cli
from assets.fileio import load_json
from assets.garments.sewing import (
    Curve,
    Edge,
    MAX_PANEL_M,
    Panel,
    PatternError,
    Placement,
    Seam,
    SeamSide,
    SewingPattern,
    edge_hull,
    parse_floats,
    pattern_name,
    polygon_area,
    validate,
)

log = logging.getLogger(__name__)

#: GarmentCode world (Y up, front +Z) -> ours (Z up, front -Y): +90 degrees about X
C_GC_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
GC_EULER = "xyz"  # GarmentCode `rotation`: R = Rz Ry Rx (extrinsic x, then y, then z)
WORLD_EULER = "xyz"  # our Placement.rotation_deg: XYZ Euler about the world axes (Blender's XYZ mode)
_FLIP_Y = np.diag([-1.0, 1.0, -1.0])  # 180 degrees about the panel's local Y axis
_SPACING = 0.005  # metres between outline samples for normals and centres
#: (min, max) metres a whole garment may span: the default bodies stand 1.3 to 1.9 m tall, so a garment
#: outside this range was converted with the wrong `units_in_meter`
GARMENT_EXTENT_M = (0.1, 2.5)

#: a seam whose edges differ in length by more than this fraction of the longer is gathered: dressing
#: sews it evenly, so the gathers are spread, not pleated where the design puts them
GATHER_WARNING = 0.10
#: (keywords, body part or None if it depends on side/facing); the first matching row wins
_BODY_PART_RULES = (
    (("sleeve", "arm", "cuff"), "arm"),
    (("collar", "neck", "hood", "lapel"), "neck"),
    (("wb", "waist", "belt", "skirt"), "waist"),
    (("pant", "leg", "trouser", "shorts"), "leg"),
    (("torso", "front", "back", "bodice", "shirt", "top"), "torso"),
)


@dataclass
class _Draft:
    """A panel being converted: 2D outline in metres and its placement in our world frame."""

    name: str
    label: str
    vertices: np.ndarray  # (K, 2) float64, metres, panel frame
    edges: list[Edge]
    rotation: np.ndarray  # (3, 3) panel frame -> our world
    translation: np.ndarray  # (3,) metres, our world
    edge_names: list[str]  # by GarmentCode edge index
    reversed: bool = False  # the loop runs opposite to GarmentCode's

    def panel(self, placement: Placement | None = None) -> Panel:
        return Panel(self.name, self.vertices, tuple(self.edges), placement)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """(P, 2) panel points -> (P, 3) world points, metres."""
        return points @ self.rotation[:, :2].T + self.translation


def load_garmentcode(path: str | Path, extent_m: tuple[float, float] = GARMENT_EXTENT_M,
                     max_panel_m: float = MAX_PANEL_M) -> SewingPattern:
    """Read a GarmentCode specification JSON file as a validated SewingPattern (metres, Z up)."""
    try:
        data = load_json(path)
    except ValueError as exc:
        raise PatternError(str(exc)) from None
    return garmentcode_from_dict(data, str(path), extent_m, max_panel_m)


def garmentcode_from_dict(data: Any, source: str = "garmentcode", extent_m: tuple[float, float] = GARMENT_EXTENT_M,
                          max_panel_m: float = MAX_PANEL_M) -> SewingPattern:
    """Convert a parsed GarmentCode specification; errors name `source`, the panel and the edge.

    extent_m: (min, max) metres the converted garment may span (`GARMENT_EXTENT_M`: a wrong
    `units_in_meter` is refused, not converted 100 times too large); max_panel_m: `validate`'s."""
    if not isinstance(data, dict) or not isinstance(data.get("pattern"), dict):
        raise PatternError(f"{source}: not a GarmentCode specification (no 'pattern' object)")
    raw_panels = data["pattern"].get("panels")
    if not isinstance(raw_panels, dict) or not raw_panels:
        raise PatternError(f"{source}: 'pattern.panels' must be a non-empty object of panels by name")
    properties = data.get("properties") or {}
    if not isinstance(properties, dict):
        raise PatternError(f"{source}: 'properties' must be an object")
    units = properties.get("units_in_meter", 100)
    if "units_in_meter" not in properties:
        log.warning("%s: no properties.units_in_meter; assuming centimetres as GarmentCode does", source)
    if isinstance(units, bool) or not isinstance(units, (int, float)) or not units > 0:
        raise PatternError(f"{source}: properties.units_in_meter must be a positive number, got {units!r}")
    coords = properties.get("curvature_coords", "relative")
    if coords not in ("relative", "absolute"):
        raise PatternError(f"{source}: properties.curvature_coords must be 'relative' or 'absolute', got {coords!r}")

    panel_order = data["pattern"].get("panel_order") or []
    if not isinstance(panel_order, list):
        raise PatternError(f"{source}: 'pattern.panel_order' must be a list of panel names")
    order = [n for n in panel_order if isinstance(n, str) and n in raw_panels]
    order += [n for n in raw_panels if n not in order]
    for n in order:
        pattern_name(n, f"{source}: pattern.panels name")
    drafts = {n: _read_panel(raw_panels[n], float(units), coords, f"{source}: panel '{n}'", n) for n in order}
    _check_extent(drafts, units, extent_m, source)
    _straighten_arms(drafts)

    outlines = {n: d.to_world(d.panel().outline(_SPACING)) for n, d in drafts.items()}
    everything = np.concatenate(list(outlines.values()))
    centre = (everything.min(axis=0) + everything.max(axis=0)) / 2
    panels = []
    for n, draft in drafts.items():
        offset = outlines[n].mean(axis=0) - centre
        if np.dot(_normal(draft), offset) < 0:
            _reverse(draft)
        if polygon_area(draft.panel().outline(_SPACING)) < 0:
            _mirror(draft)
        rotation = _euler(draft.rotation)
        body_part = _body_part(n, draft.label, offset, _normal(draft))
        panels.append(draft.panel(Placement(body_part, rotation, tuple(draft.translation.tolist()))))

    raw_stitches = data["pattern"].get("stitches", [])
    if not isinstance(raw_stitches, list):
        raise PatternError(f"{source}: 'pattern.stitches' must be a list")
    seams = tuple(_read_stitch(s, drafts, f"{source}: stitch #{i}") for i, s in enumerate(raw_stitches))
    name = pattern_name(Path(source).stem.removesuffix("_specification"), f"{source}: file name")
    pattern = SewingPattern(name=name, panels=tuple(panels), seams=seams)
    validate(pattern, source, max_panel_m)
    _warn_gathered(pattern, source)
    return pattern


def _warn_gathered(pattern: SewingPattern, source: str) -> None:
    """Log a warning for each seam gathered by more than `GATHER_WARNING` (edge lengths differ)."""
    for i, seam in enumerate(pattern.seams):
        a, b = (pattern.panel(side.panel).edge_length(pattern.panel(side.panel).edge_index(side.edge))
                for side in (seam.a, seam.b))
        if abs(a - b) > GATHER_WARNING * max(a, b):
            log.warning("%s: stitch #%d (%s.%s %.3f m, %s.%s %.3f m) gathers %.0f%%, more than %.0f%%: dressing "
                        "spreads the gathers evenly along the seam", source, i, seam.a.panel, seam.a.edge, a,
                        seam.b.panel, seam.b.edge, b, 100 * abs(a - b) / max(a, b), 100 * GATHER_WARNING)


def _check_extent(drafts: dict[str, _Draft], units: float, extent_m: tuple[float, float], source: str) -> None:
    """Refuse a garment whose placed panels span less or more than `extent_m` (metres), before its
    outlines are sampled: the bounding box of every edge's hull (`edge_hull`) in world space."""
    hulls = [d.to_world(np.concatenate([edge_hull(d.panel(), k) for k in range(len(d.edges))]))
             for d in drafts.values()]
    size = float(np.ptp(np.concatenate(hulls), axis=0).max())
    low, high = extent_m
    if not low <= size <= high:
        verdict = "too small" if size < low else "too large"
        raise PatternError(
            f"{source}: properties.units_in_meter={units:g} makes the garment {size:,.4g} m across, {verdict} "
            f"for a body 1.3 to 1.9 m tall (expected {low:g} to {high:g} m; GarmentCode writes centimetres, "
            "units_in_meter 100); pass extent_m if this is intended")


# ---- panels ------------------------------------------------------------------------------------
def _read_panel(raw: Any, units: float, coords: str, where: str, name: str) -> _Draft:
    if not isinstance(raw, dict):
        raise PatternError(f"{where}: expected an object")
    vertices = parse_floats(raw.get("vertices"), (-1, 2), f"{where}: vertices") / units
    raw_edges = raw.get("edges")
    n = len(vertices)
    if not isinstance(raw_edges, list) or len(raw_edges) != n or n < 2:
        raise PatternError(f"{where}: needs one edge per vertex in a closed loop, got "
                           f"{len(raw_edges) if isinstance(raw_edges, list) else 'no'} edges for {n} vertices")
    loop = []
    for k, e in enumerate(raw_edges):
        ends = e.get("endpoints") if isinstance(e, dict) else None
        if not (isinstance(ends, list) and len(ends) == 2 and all(isinstance(i, int) and 0 <= i < n for i in ends)):
            raise PatternError(f"{where}, edge #{k}: 'endpoints' must be two vertex indices below {n}")
        loop.append(ends)
    for k in range(n):  # edge k must start where edge k - 1 ended, visiting every vertex once
        if loop[k][0] != loop[k - 1][1]:
            raise PatternError(f"{where}, edge #{k}: endpoints {loop[k]} do not continue the loop "
                               f"(edge #{(k - 1) % n} ends at vertex {loop[k - 1][1]})")
    starts = [ends[0] for ends in loop]
    if sorted(starts) != list(range(n)):
        raise PatternError(f"{where}: the edge loop does not visit every vertex exactly once")
    vertices = vertices[starts]  # our edge k runs vertex k -> k + 1
    labels = [e.get("label") if isinstance(e.get("label"), str) and e.get("label") else None for e in raw_edges]
    fallback = [f"e{k}" for k in range(n)]
    names = [label if label is not None and labels.count(label) == 1 and label not in fallback[:k] + fallback[k + 1:]
             else fallback[k] for k, label in enumerate(labels)]
    edges = [
        Edge(names[k], _curve(e.get("curvature"), vertices[k], vertices[(k + 1) % n], units, coords,
                              f"{where}, edge #{k}"))
        for k, e in enumerate(raw_edges)
    ]
    angles = parse_floats(raw.get("rotation", [0, 0, 0]), (3,), f"{where}: rotation")
    translation = parse_floats(raw.get("translation", [0, 0, 0]), (3,), f"{where}: translation") / units
    rotation = C_GC_TO_WORLD @ Rotation.from_euler(GC_EULER, angles, degrees=True).as_matrix()
    label = raw.get("label") if isinstance(raw.get("label"), str) else ""
    return _Draft(name, label, vertices, edges, rotation, C_GC_TO_WORLD @ translation, names)


def _curve(raw: Any, start: np.ndarray, end: np.ndarray, units: float, coords: str, where: str) -> Curve:
    """Our absolute Curve for a GarmentCode `curvature` between `start` and `end` (metres)."""
    if raw is None:
        return Curve()
    kind, params = ("quadratic", [raw]) if isinstance(raw, list) else (
        (raw.get("type"), raw.get("params")) if isinstance(raw, dict) else (None, None))
    if kind == "circle":
        radius, large_arc, right = parse_floats(params, (3,), f"{where}: circle params [radius, large_arc, right]")
        radius /= units
        half = float(np.linalg.norm(end - start)) / 2
        if radius < half * (1 - 1e-6):
            raise PatternError(f"{where}: circle radius {radius:.6g} m is below half the chord ({half:.6g} m)")
        rise = np.sqrt(max(radius * radius - half * half, 0.0))
        sagitta = radius + rise if large_arc else radius - rise
        return Curve("arc", sagitta=float(-sagitta if right else sagitta))
    if kind in ("quadratic", "cubic"):
        count = 1 if kind == "quadratic" else 2
        control = parse_floats(params, (count, 2), f"{where}: {kind} params")
        if coords == "absolute":
            control = control / units
        else:
            chord = end - start
            control = start + control[:, :1] * chord + control[:, 1:] * np.array([-chord[1], chord[0]])
        return Curve(kind, control=tuple(tuple(map(float, c)) for c in control))
    raise PatternError(f"{where}: unknown curvature {raw!r} (expected type circle, quadratic or cubic)")


def _normal(draft: _Draft) -> np.ndarray:
    """(3,) unit normal of the panel's traversal (right-hand rule), our world frame."""
    winding = np.sign(polygon_area(draft.panel().outline(_SPACING)))
    return draft.rotation[:, 2] * winding


def _reverse(draft: _Draft) -> None:
    """Traverse the loop the other way: new edge j is old edge n - 1 - j run backwards."""
    n = len(draft.vertices)
    draft.reversed = not draft.reversed
    draft.vertices = draft.vertices[(-np.arange(n)) % n]
    flipped = []
    for edge in reversed(draft.edges):
        curve = edge.curve
        if curve.type == "arc":
            curve = Curve("arc", sagitta=-curve.sagitta)
        elif curve.type is not None:
            curve = Curve(curve.type, control=curve.control[::-1])
        flipped.append(Edge(edge.name, curve))
    draft.edges = flipped


def _mirror(draft: _Draft) -> None:
    """Mirror the panel frame (x -> -x) and turn the placement 180 degrees about local Y: 3D unchanged."""
    draft.vertices = draft.vertices * np.array([-1.0, 1.0])
    mirrored = []
    for edge in draft.edges:
        curve = edge.curve
        if curve.type == "arc":
            curve = Curve("arc", sagitta=-curve.sagitta)
        elif curve.type is not None:
            curve = Curve(curve.type, control=tuple((-x, y) for x, y in curve.control))
        mirrored.append(Edge(edge.name, curve))
    draft.edges = mirrored
    draft.rotation = draft.rotation @ _FLIP_Y


def _euler(rotation: np.ndarray) -> tuple[float, float, float]:
    with warnings.catch_warnings():  # gimbal lock still gives a correct (non-unique) angle triple
        warnings.simplefilter("ignore", UserWarning)
        angles = Rotation.from_matrix(rotation).as_euler(WORLD_EULER, degrees=True)
    return tuple(float(a) for a in angles)


def _straighten_arms(drafts: dict[str, _Draft]) -> None:
    """Turn each arm's panels, in place, from GarmentCode's A-pose placement into ours.

    GarmentCode drafts a sleeve with its length along the panel's x axis and turns it about the front
    axis to the arm of its A-pose body (about 50 degrees down); our hints are for the T-pose (arms along
    +-X), which dressing then turns into its own pose.  The arm panels of one side (centre x > 0: left)
    that face front or back are turned together about the world Y axis so that their mean x axis lies
    along +-X, about the inner end of the sleeve (the cap end on the sleeve's centre line), where the
    sleeve meets the torso.  Each panel keeps its shape and its place relative to the others."""
    sides: dict[float, list[tuple[_Draft, np.ndarray]]] = {}
    for name, draft in drafts.items():
        if _part_kind(name, draft.label) != "arm" or abs(draft.rotation[1, 2]) < 0.9:
            continue
        outline = draft.to_world(draft.panel().outline(_SPACING))
        sides.setdefault(1.0 if outline[:, 0].mean() >= 0 else -1.0, []).append((draft, outline))
    for sign, members in sides.items():
        directions = np.array([d.rotation[[0, 2], 0] for d, _ in members])  # panel x in the world XZ plane
        directions *= np.where(directions[:, :1] * sign < 0, -1.0, 1.0)  # pointing away from the body
        tilt = float(np.arctan2(directions[:, 1], directions[:, 0] * sign).mean())
        if abs(tilt) < 1e-9:
            continue
        along = np.array([sign * np.cos(tilt), 0.0, np.sin(tilt)])
        points = np.concatenate([outline for _, outline in members])
        centre = points.mean(axis=0)
        pivot = centre + ((points @ along).min() - centre @ along) * along
        turn = Rotation.from_euler("y", sign * tilt).as_matrix()
        for draft, _ in members:
            draft.rotation = turn @ draft.rotation
            draft.translation = turn @ (draft.translation - pivot) + pivot


def _part_kind(name: str, label: str) -> str:
    """arm, neck, waist, leg or torso from keywords in the panel name, then its label (`_body_part`)."""
    for text in (name, label):
        words = [w for w in re.split(r"[^a-z]+", text.lower()) if w]
        hits = [part for keys, part in _BODY_PART_RULES if any(w.startswith(k) or w.endswith(k)
                                                               for w in words for k in keys)]
        if hits:
            return hits[0]
    return "torso"


def _body_part(name: str, label: str, offset: np.ndarray, normal: np.ndarray) -> str:
    """Body part from keywords in the panel name (then its label) and the panel's 3D position.

    Keywords match a word of the name (split at non-letters) as its prefix or suffix ("ftorso" ends
    with "torso", "waistband" starts with "waist"): sleeve/arm/cuff -> arm_*, collar/neck/hood/lapel ->
    neck, wb/waist/belt/skirt -> waist_* (a skirt hangs from the waist and spans both legs), pant/leg/
    trouser/shorts -> leg_*, torso/front/back/bodice/shirt/top or nothing -> torso_*.  Left/right is
    the sign of the panel centre's x (+X is the body's left); front/back is the outward normal along
    -Y (front), or the centre's offset from the garment centre for panels that face sideways.
    `offset`: (3,) panel centre minus garment centre, metres; `normal`: (3,) unit outward normal.
    """
    kind = _part_kind(name, label)
    if kind == "neck":
        return "neck"
    if kind in ("arm", "leg"):
        return f"{kind}_{'left' if offset[0] >= 0 else 'right'}"
    facing = -normal[1] if abs(normal[1]) >= 0.3 else -offset[1]
    return f"{kind}_{'front' if facing >= 0 else 'back'}"


# ---- seams and helpers -------------------------------------------------------------------------
def _read_stitch(raw: Any, drafts: dict[str, _Draft], where: str) -> Seam:
    """A stitch [{panel, edge}, {panel, edge}, optional 'right_wrong'] -> Seam."""
    if not isinstance(raw, list) or len(raw) < 2 or not all(isinstance(s, dict) for s in raw[:2]):
        raise PatternError(f'{where}: expected [{{"panel": name, "edge": index}}, {{"panel": name, "edge": index}}]')
    sides, ends, lengths = [], [], []
    reverse = not (len(raw) == 3 and raw[2] == "right_wrong")  # GarmentCode's Seam.swap
    for side in raw[:2]:
        panel, k = side.get("panel"), side.get("edge")
        if not isinstance(panel, str) or panel not in drafts:
            raise PatternError(f"{where}: no panel {panel!r}")
        draft = drafts[panel]
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < len(draft.edges):
            raise PatternError(f"{where}: panel '{panel}' has no edge {k!r} (it has edges 0..{len(draft.edges) - 1})")
        name = draft.edge_names[k]
        j = [e.name for e in draft.edges].index(name)
        ends.append(draft.to_world(draft.vertices[[j, (j + 1) % len(draft.vertices)]]))
        lengths.append(draft.panel().edge_length(j))
        sides.append(SeamSide(panel, name))
        reverse ^= draft.reversed
    (a0, a1), (b0, b1) = ends
    crossed = np.linalg.norm(a0 - b1) + np.linalg.norm(a1 - b0)
    straight = np.linalg.norm(a0 - b0) + np.linalg.norm(a1 - b1)
    if (crossed - straight if reverse else straight - crossed) > 0.25 * min(lengths):
        log.warning("%s: %s.%s and %s.%s are sewn the way their 3D placement does not suggest",
                    where, sides[0].panel, sides[0].edge, sides[1].panel, sides[1].edge)
    return Seam(sides[0], sides[1], bool(reverse))


# ---- CLI ---------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m assets.garments.garmentcode",
        description=(
            "Convert a GarmentCode sewing-pattern specification (*_specification.json: panels with "
            "vertices, curved edges, 3D translation/rotation, and stitches) into this project's "
            "sewing-pattern JSON: metres, world Z up with the body's front facing -Y, panels "
            "counter-clockwise seen from outside, seams with their direction, placement hints."
        ),
    )
    parser.add_argument("input", type=Path, metavar="IN.json", help="GarmentCode specification file")
    parser.add_argument("output", type=Path, metavar="OUT.json", help="sewing-pattern JSON to write")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def convert() -> None:
        pattern = load_garmentcode(args.input)
        pattern.save(args.output)
        print(f"{args.output}: {len(pattern.panels)} panels, {len(pattern.seams)} seams")

    return run_cli(convert)


if __name__ == "__main__":
    sys.exit(main())
