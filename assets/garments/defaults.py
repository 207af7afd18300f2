"""Default sewing patterns (shirt, skirt, pants, suit jacket) drafted from body measurements.

    python -m assets.garments.defaults --out assets/data/garments          # the shipped JSON files
    python -m assets.garments.defaults --out out/tall --measurements tall.json

Drafting approach
-----------------
Each garment is drafted the way a pattern maker drafts a basic block: girths are divided among the
panels (a quarter of chest or hip per half panel), ease is added to every girth, and heights come
from the body's landmarks (shoulder point, armpit, waist, hip, knee, crotch).  Panel frames are
metres with y up; a torso or leg panel's y = 0 is its hem, x = 0 its centre line.  Every outline is
counter-clockwise seen from the outside, so two sewn edges always run in opposite directions and
every seam has ``reverse=True``.  Left/right are the wearer's; mirrored pieces are exact reflections.

* Shirt (hip length, hem 5 cm below the hip line): chest ease 12 cm, hip ease 10 cm, shoulders
  1 cm wider per side, armhole 3 cm below the armpit, crew neckline 8 cm deep in front and 2 cm at
  the back (neck half-width = neck girth / 6 + 1 cm).  One-piece sleeves to the wrist + 3 cm, bicep
  ease 8 cm, wrist ease 8 cm, set-in cap 3 % longer than the armhole (cap height solved for that).
  Optional stand collar 3.5 cm high, in two pieces joined at the centre back, open at the front.
* Suit jacket (hem 15 cm below the hip line, covering the seat): chest ease 16 cm, hip ease 14 cm,
  shoulders 1.5 cm wider per side, neck half-width neck girth / 6 + 1.5 cm, armhole 4 cm below the
  armpit, two fronts with an unsewn edge at the centre front and a V neckline 30 cm deep,
  sleeves to the wrist + 1 cm with bicep ease 10 cm, wrist ease 12 cm, cap ease 5 %; optional 5 cm
  band collar along the V and the back neck.
* Skirt (hem 2 cm below the knee): a flared A-line of two annular sectors, 70 degrees of flare in
  all (more where the hips need it: hip ease at least 4 cm), waist ease 2 cm; its waist and hem are
  circular arcs.  Optional 4 cm waistband in two pieces.
* Pants (to the ankle, hem 8 cm above the floor): four leg panels; hip ease 6 cm and waist ease 2 cm
  split 1 cm narrower in front and 1 cm wider at the back; crotch extensions hip / 16 (front) and
  hip / 9 (back), crotch 2 cm below the body's; back waist raised 2 cm and moved 2.5 cm towards the
  side seam at the centre back; leg opening 42 cm.  The outseam is two edges (hip curve, leg).

Dressing placement: world right-handed, Z up, feet at z = 0, body centred on x = y = 0, facing -Y,
T-pose with the arms along +-X (the wearer's left is +X).  Front panels face -Y and back panels +Y,
`CLEARANCE` in front of or behind the torso; sleeves lie flat above the arms facing +Z; collar pieces
stand beside the neck facing +-X.  Pieces of one layer that would touch are `SIDE_GAP` apart.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from assets.cli import run_cli
from assets.fileio import check_json_object, load_json
from assets.garments.sewing import (
    Curve,
    Edge,
    Panel,
    Placement,
    Seam,
    SeamSide,
    SewingPattern,
    curve_length,
    validate,
)

log = logging.getLogger("assets.garments.defaults")

#: distance between the body's surface and a panel placed for dressing, metres
CLEARANCE = 0.12
#: gap between left and right pieces placed side by side in one plane, metres
SIDE_GAP = 0.01
#: rotations (XYZ Euler degrees) taking a panel's outside normal (local +z) to the world direction
FACING_FRONT = (90.0, 0.0, 0.0)  # local x -> +X, y -> +Z, outside -> -Y
FACING_BACK = (90.0, 0.0, 180.0)  # local x -> -X, y -> +Z, outside -> +Y
FACING_UP_LEFT = (0.0, 0.0, 90.0)  # local x -> +Y, y -> -X, outside -> +Z (left sleeve)
FACING_UP_RIGHT = (0.0, 0.0, -90.0)  # local x -> -Y, y -> +X, outside -> +Z (right sleeve)
FACING_LEFT = (90.0, 0.0, 90.0)  # local x -> +Y, y -> +Z, outside -> +X
FACING_RIGHT = (90.0, 0.0, -90.0)  # local x -> -Y, y -> +Z, outside -> -X


@dataclass(frozen=True)
class BodyMeasurements:
    """Body measurements in metres of an average adult; girths are taken around the body."""

    #: standing height, floor to the top of the head
    height: float = 1.70
    #: around the fullest part of the chest, under the arms
    chest_girth: float = 0.96
    #: around the natural waist (the narrowest part of the torso); 0.72 as measured on the default body
    #: (a waist drafted 10 cm wider let the skirt and pants fall onto the hips while dressing)
    waist_girth: float = 0.72
    #: around the widest part of hips and seat
    hip_girth: float = 0.98
    #: across the back from shoulder point (acromion) to shoulder point
    shoulder_width: float = 0.42
    #: shoulder point to wrist bone along the straight arm (0.47 as measured on the default body: with
    #: a longer arm the sleeves cover its hands and catch on the thumbs when dressed)
    arm_length: float = 0.47
    #: around the base of the neck
    neck_girth: float = 0.38
    #: floor to the natural waist (1.08 as measured on the default body, where its girth is least:
    #: pants drafted for 1.05 sat 3 cm below it, where the body is 5 cm wider, and stretched 25 %)
    waist_height: float = 1.08
    #: floor to the crotch (0.81 on the default body)
    inseam: float = 0.81
    #: floor to the shoulder point
    shoulder_height: float = 1.40
    #: natural waist down to the hip line (widest part of the hips; at 0.83 on the default body)
    waist_to_hip: float = 0.25
    #: floor to the middle of the knee
    knee_height: float = 0.48
    #: shoulder point down to the armpit
    armhole_depth: float = 0.18
    #: around the upper arm at its fullest
    bicep_girth: float = 0.30
    #: around the wrist
    wrist_girth: float = 0.17
    #: slope of the shoulder line from the side of the neck to the shoulder point, degrees
    shoulder_slope_deg: float = 20.0
    #: front-to-back depth of the torso at its deepest (chest or seat); sets the dressing placement
    body_depth: float = 0.26

    def __post_init__(self) -> None:
        problems = [f"{f.name} must be > 0, got {getattr(self, f.name)}"
                    for f in dataclasses.fields(self) if not getattr(self, f.name) > 0]
        heights = ["knee_height", "inseam", "hip_height", "waist_height", "shoulder_height", "height"]
        values = [getattr(self, name) for name in heights]
        if not problems and not all(a < b for a, b in zip(values, values[1:])):
            problems.append("heights must increase: " + " < ".join(f"{n} {v:.3f}" for n, v in zip(heights, values)))
        if problems:
            raise ValueError("invalid BodyMeasurements: " + "; ".join(problems))

    @property
    def hip_height(self) -> float:
        """Floor to the hip line."""
        return self.waist_height - self.waist_to_hip

    @classmethod
    def from_dict(cls, data: object, source: str = "BodyMeasurements") -> "BodyMeasurements":
        """Measurements from a JSON object of field -> metres; missing fields keep their defaults."""
        check_json_object(data, (f.name for f in dataclasses.fields(cls)), source)
        wrong = [name for name, value in data.items() if isinstance(value, bool) or not isinstance(value, (int, float))]
        if wrong:
            raise ValueError(f"{source}: field(s) {', '.join(wrong)} must be numbers")
        try:
            return cls(**{name: float(value) for name, value in data.items()})
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from exc

    @classmethod
    def load(cls, path: str | Path) -> "BodyMeasurements":
        return cls.from_dict(load_json(path), source=str(path))


@dataclass(frozen=True)
class _BodiceStyle:
    """Numbers that make a torso garment a shirt or a jacket (metres unless said)."""

    chest_ease: float
    hip_ease: float
    shoulder_ease: float  # added to each half of the shoulder width
    neck_ease: float  # added to the neck half-width, neck girth / 6
    front_neck_depth: float  # side neck point down to the centre-front neck point
    neck_roundness: float  # 0.55: quarter ellipse, 0: straight
    armhole_drop: float  # underarm below the armpit
    hem_below_hip: float
    bicep_ease: float
    wrist_ease: float
    sleeve_extra: float  # sleeve beyond the wrist
    cap_ease: float  # fraction the sleeve cap is longer than the armhole
    collar_height: float
    open_front: bool  # two fronts with an unsewn centre-front edge instead of one front


_ROUND = 0.55  # cubic control distance of a quarter ellipse, as a fraction of its semi-axes
_SHIRT = _BodiceStyle(chest_ease=0.12, hip_ease=0.10, shoulder_ease=0.01, neck_ease=0.01, front_neck_depth=0.08,
                      neck_roundness=_ROUND, armhole_drop=0.03, hem_below_hip=0.05, bicep_ease=0.08, wrist_ease=0.08,
                      sleeve_extra=0.03, cap_ease=0.03, collar_height=0.035, open_front=False)
_JACKET = _BodiceStyle(chest_ease=0.16, hip_ease=0.14, shoulder_ease=0.015, neck_ease=0.015, front_neck_depth=0.30,
                       neck_roundness=0.15, armhole_drop=0.04, hem_below_hip=0.15, bicep_ease=0.10, wrist_ease=0.12,
                       sleeve_extra=0.01, cap_ease=0.05, collar_height=0.05, open_front=True)
_BACK_NECK_DEPTH = 0.02
_ARMHOLE_HOLLOW = 0.015  # across chest/back inside the shoulder point
_SKIRT_FLARE_DEG = 70.0
_SKIRT_WAIST_EASE = 0.02
_SKIRT_HIP_EASE = 0.04  # the least hip ease a flare must give
_SKIRT_BELOW_KNEE = 0.02
_BAND_HEIGHT = 0.04
_PANTS_HEM_HEIGHT = 0.08  # above the floor; at 3 cm the hems caught on the feet while dressing (50 % strain)
_PANTS_HIP_EASE = 0.06
_PANTS_WAIST_EASE = 0.02
_PANTS_CROTCH_DROP = 0.02
_PANTS_BALANCE = 0.01  # front panels this much narrower than a quarter girth, back panels wider
_PANTS_SEAT_SHIFT, _PANTS_SEAT_RISE = 0.025, 0.02  # centre-back waist point: towards the side, up


# ---- panel helpers -----------------------------------------------------------------------------
def _panel(name: str, vertices: list[tuple[float, float]], edges: list[Edge]) -> Panel:
    """A panel with vertices rounded to micrometres (readable JSON; -0.0 becomes 0.0)."""
    return Panel(name, np.round(np.asarray(vertices, np.float64), 6) + 0.0, tuple(edges))


def _cubic(c1: tuple[float, float], c2: tuple[float, float]) -> Curve:
    return Curve("cubic", control=tuple((round(float(x), 6) + 0.0, round(float(y), 6) + 0.0) for x, y in (c1, c2)))


def _mirror_edge(edge: Edge, name: str) -> Edge:
    """`edge` reflected across the y axis and run backwards (as it is in a mirrored outline)."""
    control = tuple((-x + 0.0, y) for x, y in reversed(edge.curve.control))
    # mirroring and reversing each swap the sides of the edge, so an arc's sagitta keeps its sign
    return Edge(name, dataclasses.replace(edge.curve, control=control))


def _mirrored(panel: Panel, name: str) -> Panel:
    """`panel` reflected across its y axis (the other body side), still counter-clockwise; edge k is
    the mirror image of the original edge k, so the outline starts with the same edge."""
    k = len(panel.edges)
    order = (1 - np.arange(k)) % k  # new vertex j is old vertex 1 - j, new edge j old edge -j reversed
    edges = tuple(_mirror_edge(panel.edges[-j % k], panel.edges[-j % k].name) for j in range(k))
    return Panel(name, panel.vertices[order] * (-1.0, 1.0) + 0.0, edges, panel.placement)


def _joined(half: Panel, name: str, plus: str, minus: str) -> Panel:
    """Whole symmetric panel from its x >= 0 half, whose outline starts and ends on x = 0 and whose
    last edge (on x = 0) is dropped; edges of the half get suffix `_{plus}`, mirrored ones `_{minus}`."""
    edges = [Edge(f"{e.name}_{plus}", e.curve) for e in half.edges[:-1]]
    edges += [_mirror_edge(e, f"{e.name}_{minus}") for e in reversed(half.edges[:-1])]
    mirrored = half.vertices[-2:0:-1] * (-1.0, 1.0) + 0.0
    return Panel(name, np.concatenate([half.vertices, mirrored]), tuple(edges))


def _placed(panel: Panel, body_part: str, rotation_deg: tuple[float, float, float],
            local_xy: tuple[float, float], world_xyz: tuple[float, float, float]) -> Panel:
    """`panel` with a placement that rotates it by `rotation_deg` and puts `local_xy` at `world_xyz`."""
    rotated = Rotation.from_euler("xyz", rotation_deg, degrees=True).apply([local_xy[0], local_xy[1], 0.0])
    translation = np.round(np.asarray(world_xyz) - rotated, 6) + 0.0
    return dataclasses.replace(panel, placement=Placement(body_part, rotation_deg, tuple(translation.tolist())))


def _checked(pattern: SewingPattern) -> SewingPattern:
    validate(pattern, f"default pattern '{pattern.name}'")
    return pattern


def _seam(a_panel: str, a_edge: str, b_panel: str, b_edge: str) -> Seam:
    # every outline is counter-clockwise from the outside, so a's start always meets b's end
    return Seam(SeamSide(a_panel, a_edge), SeamSide(b_panel, b_edge), reverse=True)


# ---- shirt and jacket --------------------------------------------------------------------------
def _bodice_half(m: BodyMeasurements, style: _BodiceStyle, neck_depth: float, roundness: float) -> Panel:
    """Wearer's-left half of a front (x >= 0) from the centre of the hem, counter-clockwise: hem, side,
    armhole, shoulder, neck, centre.  The back half is the same shape with a shallower neck."""
    z_hem = m.hip_height - style.hem_below_hip
    y_shoulder = m.shoulder_height - z_hem
    y_underarm = y_shoulder - m.armhole_depth - style.armhole_drop
    chest, hip = (m.chest_girth + style.chest_ease) / 4, (m.hip_girth + style.hip_ease) / 4
    shoulder = m.shoulder_width / 2 + style.shoulder_ease
    neck = m.neck_girth / 6 + style.neck_ease
    y_neck = y_shoulder + (shoulder - neck) * math.tan(math.radians(m.shoulder_slope_deg))
    across = shoulder - _ARMHOLE_HOLLOW
    vertices = [(0.0, 0.0), (hip, 0.0), (chest, y_underarm), (shoulder, y_shoulder), (neck, y_neck),
                (0.0, y_neck - neck_depth)]
    edges = [
        Edge("hem"),
        Edge("side"),
        Edge("armhole", _cubic((across, y_underarm), (across, y_underarm + 0.45 * (y_shoulder - y_underarm)))),
        Edge("shoulder"),
        Edge("neck", _cubic((neck, y_neck - roundness * neck_depth), (roundness * neck, y_neck - neck_depth))),
        Edge("centre"),
    ]
    return _panel("half", vertices, edges)


def _sleeve(m: BodyMeasurements, style: _BodiceStyle, armhole_length: float) -> Panel:
    """Left one-piece sleeve: hem at y = 0, cap top at the shoulder; the back half is x > 0 (it faces
    +Y when the sleeve lies above the left arm).  The cap height makes each half of the cap
    `cap_ease` longer than the armhole it is sewn to."""
    bicep, wrist = (m.bicep_girth + style.bicep_ease) / 2, (m.wrist_girth + style.wrist_ease) / 2
    length = m.arm_length + style.sleeve_extra
    target = armhole_length * (1 + style.cap_ease)

    def cap(height: float, base: float) -> Curve:  # bell-shaped half cap from the underarm to the top
        return _cubic((0.55 * bicep, base), (0.45 * bicep, base + height))

    def excess(height: float) -> float:
        return curve_length(np.array([bicep, 0.0]), np.array([0.0, height]), cap(height, 0.0)) - target

    if not excess(1e-3) < 0 < excess(0.8 * length):
        raise ValueError(f"sleeve: no cap of a {2 * bicep:.3f} m wide, {length:.3f} m long sleeve fits a "
                         f"{armhole_length:.3f} m armhole")
    height = brentq(excess, 1e-3, 0.8 * length, xtol=1e-9)
    base = length - height
    vertices = [(-wrist, 0.0), (wrist, 0.0), (bicep, base), (0.0, length), (-bicep, base)]
    back = cap(height, base)
    front = _cubic(*[(-x, y) for x, y in reversed(back.control)])
    edges = [Edge("hem"), Edge("underarm_back"), Edge("cap_back", back), Edge("cap_front", front),
             Edge("underarm_front")]
    return _panel("sleeve_left", vertices, edges)


def _collar(front_length: float, back_length: float, height: float) -> Panel:
    """Left collar piece: bottom edges sewn to the front and back necklines, from the centre front
    (x = 0) towards the centre back (+x)."""
    end = front_length + back_length
    vertices = [(0.0, 0.0), (front_length, 0.0), (end, 0.0), (end, height), (0.0, height)]
    edges = [Edge("neck_front"), Edge("neck_back"), Edge("centre_back"), Edge("top"), Edge("centre_front")]
    return _panel("collar_left", vertices, edges)


def _bodice(name: str, m: BodyMeasurements, style: _BodiceStyle, collar: bool) -> SewingPattern:
    z_hem = m.hip_height - style.hem_below_hip
    front_half = _bodice_half(m, style, style.front_neck_depth, style.neck_roundness)
    back = _joined(_bodice_half(m, style, _BACK_NECK_DEPTH, _ROUND), "back", "right", "left")
    front_y, back_y = -(m.body_depth / 2 + CLEARANCE), m.body_depth / 2 + CLEARANCE
    if style.open_front:
        left = dataclasses.replace(front_half, name="front_left", edges=front_half.edges[:-1] + (Edge("opening"),))
        fronts = [_placed(left, "torso_front", FACING_FRONT, (0, 0), (SIDE_GAP / 2, front_y, z_hem)),
                  _placed(_mirrored(left, "front_right"), "torso_front", FACING_FRONT, (0, 0),
                          (-SIDE_GAP / 2, front_y, z_hem))]
    else:
        fronts = [_placed(_joined(front_half, "front", "left", "right"), "torso_front", FACING_FRONT, (0, 0),
                          (0, front_y, z_hem))]
    panels = [*fronts, _placed(back, "torso_back", FACING_BACK, (0, 0), (0, back_y, z_hem))]

    armhole = front_half.edge_length(front_half.edge_index("armhole"))
    sleeve = _sleeve(m, style, armhole)
    top, shoulder_x = sleeve.vertices[:, 1].max(), front_half.vertices[3, 0]  # vertex 3: shoulder point
    arm_z = m.shoulder_height + CLEARANCE
    panels += [_placed(sleeve, "arm_left", FACING_UP_LEFT, (0, top), (shoulder_x, 0, arm_z)),
               _placed(_mirrored(sleeve, "sleeve_right"), "arm_right", FACING_UP_RIGHT, (0, top),
                       (-shoulder_x, 0, arm_z))]

    def front(side: str, edge: str) -> tuple[str, str]:
        return (f"front_{side}", edge) if style.open_front else ("front", f"{edge}_{side}")

    seams = []
    for side in ("left", "right"):
        sleeve_name = f"sleeve_{side}"
        seams += [
            _seam(*front(side, "side"), "back", f"side_{side}"),
            _seam(*front(side, "shoulder"), "back", f"shoulder_{side}"),
            _seam(*front(side, "armhole"), sleeve_name, "cap_front"),
            _seam("back", f"armhole_{side}", sleeve_name, "cap_back"),
            _seam(sleeve_name, "underarm_front", sleeve_name, "underarm_back"),
        ]
    if collar:
        neck = front_half.edge_index("neck")
        piece = _collar(front_half.edge_length(neck), back.edge_length(back.edge_index("neck_left")),
                        style.collar_height)
        neck_x = m.neck_girth / (2 * math.pi) + CLEARANCE
        collar_z = front_half.vertices[4, 1] + z_hem + CLEARANCE  # vertex 4: side neck point
        bottom = piece.vertices[1]
        panels += [_placed(piece, "neck", FACING_LEFT, bottom, (neck_x, 0, collar_z)),
                   _placed(_mirrored(piece, "collar_right"), "neck", FACING_RIGHT, bottom * (-1, 1),
                           (-neck_x, 0, collar_z))]
        for side in ("left", "right"):
            seams += [_seam(*front(side, "neck"), f"collar_{side}", "neck_front"),
                      _seam("back", f"neck_{side}", f"collar_{side}", "neck_back")]
        seams.append(_seam("collar_left", "centre_back", "collar_right", "centre_back"))
    return _checked(SewingPattern(name, tuple(panels), tuple(seams)))


def shirt(m: BodyMeasurements = BodyMeasurements(), collar: bool = True) -> SewingPattern:
    """Hip-length shirt: front, back, left and right sleeves, optional two-piece stand collar."""
    return _bodice("shirt", m, _SHIRT, collar)


def suit(m: BodyMeasurements = BodyMeasurements(), collar: bool = True) -> SewingPattern:
    """Suit jacket: two fronts open at the centre front, back, sleeves, optional band collar."""
    return _bodice("suit", m, _JACKET, collar)


# ---- skirt -------------------------------------------------------------------------------------
def _skirt_panel(name: str, waist_radius: float, hem_radius: float, angle: float, plus: str, minus: str) -> Panel:
    """Annular sector of `angle` radians; the circle's centre is above the panel at (0, hem_radius),
    so the hem's middle is at y = 0 and the waist's middle at y = hem_radius - waist_radius."""
    s, c = math.sin(angle / 2), math.cos(angle / 2)
    vertices = [(-hem_radius * s, hem_radius * (1 - c)), (hem_radius * s, hem_radius * (1 - c)),
                (waist_radius * s, hem_radius - waist_radius * c), (-waist_radius * s, hem_radius - waist_radius * c)]
    edges = [Edge("hem", Curve("arc", sagitta=-round(hem_radius * (1 - c), 6))),  # bulges down, right of +x
             Edge(f"side_{plus}"),
             Edge("waist", Curve("arc", sagitta=round(waist_radius * (1 - c), 6))),  # dips down, left of -x
             Edge(f"side_{minus}")]
    return _panel(name, vertices, edges)


def _band(name: str, width: float, height: float, plus: str, minus: str) -> Panel:
    vertices = [(-width / 2, 0.0), (width / 2, 0.0), (width / 2, height), (-width / 2, height)]
    return _panel(name, vertices, [Edge("waist"), Edge(f"side_{plus}"), Edge("top"), Edge(f"side_{minus}")])


def skirt(m: BodyMeasurements = BodyMeasurements(), flare_deg: float | None = None,
          waistband: bool = True) -> SewingPattern:
    """Knee-length A-line skirt: front and back sectors of `flare_deg` / 2 each, optional waistband.
    `flare_deg` None is 70 degrees, or the least flare that passes over the hips where that is more."""
    waist = m.waist_girth + _SKIRT_WAIST_EASE
    least = math.degrees((m.hip_girth + _SKIRT_HIP_EASE - waist) / m.waist_to_hip)
    if flare_deg is None:
        flare_deg = max(_SKIRT_FLARE_DEG, least)
    elif not least <= flare_deg < 360:
        raise ValueError(f"skirt: flare_deg must be in [{least:.1f}, 360) to pass over the hips, got {flare_deg}")
    flare = math.radians(flare_deg)
    waist_radius = waist / flare
    hem_radius = waist_radius + m.waist_height - m.knee_height + _SKIRT_BELOW_KNEE
    y = m.body_depth / 2 + CLEARANCE
    waist_mid = (0.0, hem_radius - waist_radius)
    panels = [
        _placed(_skirt_panel("front", waist_radius, hem_radius, flare / 2, "left", "right"), "waist_front",
                FACING_FRONT, waist_mid, (0, -y, m.waist_height)),
        _placed(_skirt_panel("back", waist_radius, hem_radius, flare / 2, "right", "left"), "waist_back",
                FACING_BACK, waist_mid, (0, y, m.waist_height)),
    ]
    seams = [_seam("front", "side_left", "back", "side_left"), _seam("front", "side_right", "back", "side_right")]
    if waistband:
        band_z = m.waist_height + waist_radius * (1 - math.cos(flare / 4)) + 0.03  # 3 cm above the skirt's top
        panels += [_placed(_band("waistband_front", waist / 2, _BAND_HEIGHT, "left", "right"), "waist_front",
                           FACING_FRONT, (0, 0), (0, -y, band_z)),
                   _placed(_band("waistband_back", waist / 2, _BAND_HEIGHT, "right", "left"), "waist_back",
                           FACING_BACK, (0, 0), (0, y, band_z))]
        seams += [_seam("waistband_front", "waist", "front", "waist"), _seam("waistband_back", "waist", "back", "waist"),
                  _seam("waistband_front", "side_left", "waistband_back", "side_left"),
                  _seam("waistband_front", "side_right", "waistband_back", "side_right")]
    return _checked(SewingPattern("skirt", tuple(panels), tuple(seams)))


# ---- pants -------------------------------------------------------------------------------------
def _leg(m: BodyMeasurements, name: str, hip: float, waist: float, crotch: float, opening: float,
         centre_shift: float, centre_rise: float) -> Panel:
    """Leg panel with its side seam at +x (the left front, or the right back), counter-clockwise from the
    hem: hem, outseam_lower (hem to hip), outseam_upper (hip to waist), waist, crotch, inseam.  x = 0 is
    the centre front/back line, the crotch extension reaches to x = -`crotch`."""
    y_waist, y_hip = m.waist_height - _PANTS_HEM_HEIGHT, m.hip_height - _PANTS_HEM_HEIGHT
    y_crotch = m.inseam - _PANTS_HEM_HEIGHT - _PANTS_CROTCH_DROP
    crease = (hip - crotch) / 2
    vertices = [(crease - opening / 2, 0.0), (crease + opening / 2, 0.0), (hip, y_hip),
                (centre_shift + waist, y_waist), (centre_shift, y_waist + centre_rise), (-crotch, y_crotch)]
    edges = [Edge("hem"), Edge("outseam_lower"),
             Edge("outseam_upper", Curve("quadratic", control=((round(hip, 6), round((y_hip + y_waist) / 2, 6)),))),
             Edge("waist"), Edge("crotch", _cubic((0.0, y_hip), (0.0, y_crotch))), Edge("inseam")]
    return _panel(name, vertices, edges)


def pants(m: BodyMeasurements = BodyMeasurements(), leg_opening: float = 0.42) -> SewingPattern:
    """Full-length trousers: front and back panels of each leg, `leg_opening` the hem's girth."""
    hip, waist = (m.hip_girth + _PANTS_HIP_EASE) / 4, (m.waist_girth + _PANTS_WAIST_EASE) / 4
    front_crotch, back_crotch = m.hip_girth / 16, m.hip_girth / 9
    b = _PANTS_BALANCE
    front = _leg(m, "front_left", hip - b, waist - b, front_crotch, leg_opening / 2 - b, 0.0, 0.0)
    back = _leg(m, "back_right", hip + b, waist + b, back_crotch, leg_opening / 2 + b, _PANTS_SEAT_SHIFT,
                _PANTS_SEAT_RISE)
    y, z, gap = m.body_depth / 2 + CLEARANCE, _PANTS_HEM_HEIGHT, SIDE_GAP / 2
    panels = [
        _placed(front, "leg_left", FACING_FRONT, (-front_crotch, 0), (gap, -y, z)),
        _placed(_mirrored(front, "front_right"), "leg_right", FACING_FRONT, (front_crotch, 0), (-gap, -y, z)),
        _placed(_mirrored(back, "back_left"), "leg_left", FACING_BACK, (back_crotch, 0), (gap, y, z)),
        _placed(back, "leg_right", FACING_BACK, (-back_crotch, 0), (-gap, y, z)),
    ]
    seams = [_seam(f"front_{side}", edge, f"back_{side}", edge)
             for side in ("left", "right") for edge in ("outseam_lower", "outseam_upper", "inseam")]
    seams += [_seam("front_left", "crotch", "front_right", "crotch"), _seam("back_left", "crotch", "back_right", "crotch")]
    return _checked(SewingPattern("pants", tuple(panels), tuple(seams)))


# ---- registry and CLI --------------------------------------------------------------------------
DEFAULT_GARMENTS: dict[str, Callable[[BodyMeasurements], SewingPattern]] = {
    "shirt": shirt, "skirt": skirt, "pants": pants, "suit": suit,
}


#: Per default garment, the default body's shapes (`assets.body.default`: gender 0 male .. 1 female,
#: weight, height, each 0 .. 1) it is known to dress on, drafted as it is for the default shape
#: (0.5, 0.5, 0.65; 1.70 m): `benchmarks/body_range.py`, RESULTS.md "Issue 48: the body's shape range"
#: (not every corner of every box was run; the table says which were).  Beyond them: on a 1.9 m man
#: the skirt's waist stays 1-3 cm open and the shirt's and the suit's sleeve caps 9-11 cm short of the
#: armholes; the pants' hips stay 1-3 cm open on men from 1.75 m or of weight 0.5 up (drafted around
#: the default body's hips, gender 0.5) and on a heavy 1.9 m woman; on a 1.3 m slim woman the skirt
#: slides off.  A body outside needs its garment drafted for its measurements
#: (``python -m assets.garments.defaults --measurements``).
DEFAULT_BODY_FIT: dict[str, dict[str, tuple[float, float]]] = {
    "shirt": {"gender": (0.0, 1.0), "weight": (0.0, 1.0), "height": (0.25, 0.75)},
    "skirt": {"gender": (0.0, 1.0), "weight": (0.0, 1.0), "height": (0.25, 0.75)},
    "pants": {"gender": (0.5, 1.0), "weight": (0.0, 0.75), "height": (0.25, 0.75)},
    "suit": {"gender": (0.0, 1.0), "weight": (0.0, 1.0), "height": (0.25, 0.75)},
}


def default_body_misfit(pattern: SewingPattern, body_name: str, shape_names: tuple[str, ...], betas) -> str | None:
    """Why the default garment `pattern` (as drafted by default) may not fit the default body of shape
    `betas` (outside its `DEFAULT_BODY_FIT`), or None when it fits, or when either is not the default
    (another body, a garment drafted for other measurements, a pattern of a file)."""
    fit = DEFAULT_BODY_FIT.get(pattern.name)
    if body_name != "default" or fit is None or tuple(shape_names) != tuple(fit):
        return None
    outside = [f"{name}={float(value):g}" for (name, (lo, hi)), value in zip(fit.items(), betas)
               if not lo - 1e-9 <= float(value) <= hi + 1e-9]
    if not outside or pattern.to_dict() != default_pattern(pattern.name).to_dict():
        return None
    ranges = ", ".join(f"{name} {lo:g} .. {hi:g}" for name, (lo, hi) in fit.items())
    return (f"the default {pattern.name} is drafted for the default body's default shape and known to dress on "
            f"{ranges} (benchmarks/body_range.py), not on {', '.join(outside)}; draft it for this body's measurements "
            "(python -m assets.garments.defaults --measurements FILE) or choose a shape inside that range")


def default_pattern(name: str, measurements: BodyMeasurements = BodyMeasurements()) -> SewingPattern:
    """The default garment `name` (one of DEFAULT_GARMENTS) drafted for `measurements`."""
    if name not in DEFAULT_GARMENTS:
        raise ValueError(f"unknown garment '{name}'; expected one of {', '.join(DEFAULT_GARMENTS)}")
    return DEFAULT_GARMENTS[name](measurements)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m assets.garments.defaults",
        description="Draft the default sewing patterns (shirt, skirt, pants, suit jacket) from body "
        "measurements and write each as <OUT>/<garment>.json.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument("--measurements", type=Path,
                        help="JSON object of BodyMeasurements fields in metres (e.g. {\"chest_girth\": 1.02}); "
                        "fields left out keep the average-adult defaults")
    args = parser.parse_args(argv)

    def write_all() -> None:
        measurements = BodyMeasurements.load(args.measurements) if args.measurements else BodyMeasurements()
        for name in DEFAULT_GARMENTS:
            path = args.out / f"{name}.json"
            default_pattern(name, measurements).save(path)
            log.info("wrote %s", path)

    return run_cli(write_all)


if __name__ == "__main__":
    sys.exit(main())
