"""Dressing: the flat panels of a sewing pattern -> one sewn garment mesh at rest on a body.

    garment = dress(template, body)                      # default: the 12 mm training level
    garment.save("shirt_dressed.npz")

Steps (all on the body standing on z = 0 with its pelvis on the Z axis, the frame the patterns'
placement hints are written in, in the dressing pose: A by default, arms lowered 45 degrees, because
set-in sleeves with a tall cap do not fit a T-pose: the arm pokes through the sleeve top):

1. Place: every panel is moved by its placement hint (`assets.garments.export.placed_positions`);
   a panel without one cannot be dressed (`DressingError` names it).  Hints are written for the
   T-pose of the body's default shape; on another shape each panel moves with the joint its body
   part hangs from (`placement_shifts`).  Arm panels turn with the arm about the shoulder into the
   dressing pose.
2. Curve: the panels of one body part (torso, waist, neck, each arm) are rolled onto a cylinder around
   that part's axis (from its joints), length-preserving around the axis.  The radius at each height
   is the larger of the body's radius there plus `clearance` and what the panels' width needs so
   that panels facing different ways do not overlap.  Trouser legs are rolled around the pelvis above
   the crotch and around their own leg below it (`_wrap_legs`).  Vertices still inside the body are
   moved out along its normal.
3. Sew: quasi-static projective dynamics (`factory.cloth`; every step starts at rest) with
   zero-length springs between seam pairs, body contact and no gravity.  The springs start soft and stiffen whenever the widest gap stops closing,
   until every gap is under `gap_tolerance` (1 mm) and no vertex is inside the body.  Sewing gives up
   when the gap stops shrinking at the stiffest seams allowed (`stall_steps`): the `DressingError`
   names the widest open seams with their gaps and holds where it stuck (`save_stuck`: npz and PNG).
4. Merge the seam pairs into one mesh (`Level.sew`) and let it settle under gravity for
   `settle_seconds`, so it hangs on the body: the garment at rest, ready for motion.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from assets.body.model import BodyModel
from assets.fileio import load_npz, save_npz
from assets.garments.defaults import default_body_misfit
from assets.garments.export import placed_positions
from assets.garments.template import Template
from assets.motion.motion import dressing_pose
from assets.rotations import align_vectors
from factory.cloth import ClothModel, ClothParams, ClothState, MeshCollider, ProjectiveDynamics

log = logging.getLogger(__name__)

#: The training level: the reference simulates a separate low-resolution mesh for training data.
TRAINING_LEVEL_MM = 12

#: body part -> (cylinder group, axis start joint, axis end joint or None for vertical, the joints
#: whose skin the cylinder must clear).  Groups share one cylinder; None means the panel stays flat.
_PARTS: dict[str, tuple[str | None, str, str | None, tuple[str, ...]]] = {
    "torso_front": ("torso", "spine3", None, ("pelvis", "spine1", "spine2", "spine3", "left_collar", "right_collar")),
    "torso_back": ("torso", "spine3", None, ("pelvis", "spine1", "spine2", "spine3", "left_collar", "right_collar")),
    "waist_front": ("waist", "pelvis", None, ("pelvis", "spine1", "left_hip", "right_hip")),
    "waist_back": ("waist", "pelvis", None, ("pelvis", "spine1", "left_hip", "right_hip")),
    "neck": ("neck", "neck", None, ("neck",)),
    "arm_left": ("arm_left", "left_shoulder", "left_wrist", ("left_shoulder", "left_elbow", "left_wrist", "left_hand")),
    "arm_right": ("arm_right", "right_shoulder", "right_wrist",
                  ("right_shoulder", "right_elbow", "right_wrist", "right_hand")),
    "leg_left": (None, "left_hip", "left_ankle", ()),
    "leg_right": (None, "right_hip", "right_ankle", ()),
}


class DressingError(RuntimeError):
    """A pattern that cannot be dressed, or sewing that did not close.  `stuck`: the garment where
    dressing stopped (the unsewn panels when sewing failed, the sewn mesh when it slid off while
    settling), to save and look at (`save_stuck`); None when dressing never started."""

    def __init__(self, message: str, stuck: "DressedGarment | None" = None):
        super().__init__(message)
        self.stuck = stuck


@dataclass(frozen=True)
class DressingParams:
    level_mm: int = TRAINING_LEVEL_MM
    #: dressing pose, 'A' or 'T' (`assets.motion.dressing_pose`); simulation starts from it
    pose: str = "A"
    #: space (m) between the skin and the cylinders the panels are rolled onto
    clearance: float = 0.015
    #: initial seam spring stiffness per unit vertex area (N/m^3, like the contact weight)
    seam_weight: float = 1.0e7
    #: factor the seam stiffness grows by when the widest gap stops closing, and its ceiling
    seam_growth: float = 4.0
    max_seam_weight: float = 1.0e10
    #: the seams stiffen past this (N/m^3) only once every gap is under `near_gap`: stiff springs
    #: over wide gaps would pull cloth through thin body parts in one step
    far_seam_weight: float = 1.0e8
    near_gap: float = 0.01
    gap_tolerance: float = 1.0e-3
    max_sew_steps: int = 1500
    #: sewing gives up when the widest gap has not shrunk 5 % in this many steps at the stiffest
    #: seams allowed: stiffer springs cannot close it (a panel caught on the wrong side of a limb)
    stall_steps: int = 200
    #: how many of the widest open seams a failure names
    worst_seams: int = 5
    settle_seconds: float = 0.5
    #: contact weight (N/m^3) while settling, a tenth of the simulation's: at 1e8 the penalty is 70x
    #: stiffer than inertia (k h^2 / m), ten local-global iterations do not converge, and the
    #: unconverged steps feed energy into the cloth: the skirt's waist stretched 30 % over the hips
    #: and slid to the floor.  At 1e7 it settles at the waist.
    settle_contact_weight: float = 1.0e7
    #: the garment fails to dress when its mean height drops more than this (m) while settling
    max_settle_drop: float = 0.15
    cloth: ClothParams = field(default_factory=ClothParams)


@dataclass(frozen=True, eq=False)
class DressedGarment:
    """A garment sewn and at rest on a body in the dressing pose (sewn mesh of one template level)."""

    garment: str
    level_mm: int
    faces: np.ndarray  # (F, 3) int32, the sewn mesh
    rest_corners: np.ndarray  # (F, 3, 2) float64, each triangle on its flat panel (metres)
    positions: np.ndarray  # (V, 3) float64, metres
    body_betas: np.ndarray  # the body shape it was dressed on
    body_trans: np.ndarray  # (3,) pelvis position of the body in the dressing pose
    dressing_pose: str
    report: dict = field(default_factory=dict)

    def save(self, path: str | Path) -> None:
        save_npz(path, {
            "faces": self.faces, "rest_corners": self.rest_corners, "positions": self.positions,
            "body_betas": self.body_betas, "body_trans": self.body_trans,
            "meta": np.array(json.dumps({"garment": self.garment, "level_mm": self.level_mm,
                                         "dressing_pose": self.dressing_pose, "report": self.report})),
        })

    @classmethod
    def load(cls, path: str | Path) -> "DressedGarment":
        """Read a dressed garment written by `save`; a ValueError names the file and the field it lacks."""
        arrays = load_npz(path, required=("faces", "rest_corners", "positions", "body_betas", "body_trans", "meta"))
        try:
            meta = json.loads(str(arrays["meta"]))
            fields = (str(meta["garment"]), int(meta["level_mm"]), str(meta["dressing_pose"]),
                      dict(meta.get("report", {})))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: meta is not a dressed garment's record (garment, level_mm, dressing_pose, "
                             f"report): {type(exc).__name__} {exc}") from exc
        faces, rest, positions = arrays["faces"], arrays["rest_corners"], arrays["positions"]
        if faces.ndim != 2 or faces.shape[1:] != (3,) or not np.issubdtype(faces.dtype, np.integer) \
                or rest.shape != (len(faces), 3, 2) or positions.ndim != 2 or positions.shape[1:] != (3,) \
                or len(faces) and not 0 <= faces.min() <= faces.max() < len(positions):
            raise ValueError(f"{path}: faces {faces.shape}, rest_corners {rest.shape} and positions {positions.shape} "
                             "are not a mesh (expected (F, 3) indices into (V, 3) positions and (F, 3, 2) corners)")
        garment, level_mm, pose, report = fields
        return cls(garment, level_mm, faces, rest, positions, arrays["body_betas"], arrays["body_trans"], pose, report)


@dataclass(frozen=True)
class DressingBody:
    """The body in a dressing pose where placement hints expect it: soles on z = 0, pelvis on the Z
    axis.  `trans` is the pelvis position (a motion's root translation for this pose)."""

    pose: str
    vertices: np.ndarray  # (V, 3)
    joints: np.ndarray  # (24, 3) posed
    rest_joints: np.ndarray  # (24, 3) in the T-pose, same placement
    trans: np.ndarray  # (3,)


def dressing_body(body: BodyModel, betas: np.ndarray | None = None, pose: str = "A") -> DressingBody:
    rest_joints = standing_joints(body, betas)
    trans = rest_joints[0]
    posed = body.pose(dressing_pose(pose)[None], trans[None], betas)
    return DressingBody(pose.upper(), posed.vertices[0].astype(np.float64), posed.joints[0].astype(np.float64),
                        rest_joints, trans)


def standing_joints(body: BodyModel, betas: np.ndarray | None = None) -> np.ndarray:
    """(J, 3) joints of the body in the T-pose, soles on z = 0 and pelvis on the Z axis (metres)."""
    vertices, joints = body.rest(betas)
    return joints - joints[0] + np.array([0.0, 0.0, joints[0, 2] - vertices[:, 2].min()])


def placement_shifts(template: Template, body: BodyModel, dressed: DressingBody) -> np.ndarray:
    """(P, 3) metres: how far step 1 moves each panel of `template` from its placement hint.

    Hints are written for the body's default shape (`body.default_betas`: the default garments are
    drafted for it, 1.70 m tall; GarmentCode places panels for its mean body, 1.72 m).  On the shape
    of `dressed` each panel moves with the joint its body part hangs from (the start joint in
    `_PARTS`: spine3 for the torso, the pelvis for the waist, the neck, each shoulder, each hip),
    T-pose to T-pose, so the panel keeps its offset from that joint; the panels keep their shapes.
    Zero on the default shape.
    Every panel needs a placement with a body part dressing knows."""
    reference = dict(zip(body.joint_names, standing_joints(body, body.default_betas)))
    target = dict(zip(body.joint_names, dressed.rest_joints))
    anchors = [_PARTS[panel.placement.body_part][1] for panel in template.pattern.panels]
    return np.array([target[joint] - reference[joint] for joint in anchors]).reshape(-1, 3)


def curve_onto_body(template: Template, level_mm: int, body: BodyModel, dressed: DressingBody,
                    clearance: float) -> np.ndarray:
    """Steps 1 and 2 of the module docstring: (V, 3) unsewn positions around the body."""
    try:
        positions = placed_positions(template, level_mm)
    except ValueError as exc:
        raise DressingError(f"cannot dress '{template.name}': {exc}") from exc
    level = template.level(level_mm)
    body_vertices = dressed.vertices
    joints = dict(zip(body.joint_names, dressed.joints))
    rest = dict(zip(body.joint_names, dressed.rest_joints))
    dominant = np.asarray(body.joint_names)[np.argmax(body.weights, axis=1)]
    panels = template.pattern.panels
    groups: dict[str, list[int]] = {}
    for p, panel in enumerate(panels):
        part = panel.placement.body_part
        if part not in _PARTS:
            raise DressingError(f"cannot dress '{template.name}': panel '{panel.name}' has body part '{part}', "
                                f"which dressing does not know ({', '.join(_PARTS)})")
        group = _PARTS[part][0]
        if group is not None:
            groups.setdefault(group, []).append(p)
    positions += placement_shifts(template, body, dressed)[level.panel]
    for group, members in groups.items():
        _, start, end, skin_joints = _PARTS[panels[members[0]].placement.body_part]
        origin = joints[start]
        axis = np.array([0.0, 0.0, 1.0]) if end is None else joints[end] - origin
        axis /= np.linalg.norm(axis)
        # hints are for the T-pose: turn the panels with the limb into the dressing pose
        turn = np.eye(3) if end is None else align_vectors(rest[end] - rest[start], axis)
        skin = body_vertices[np.isin(dominant, skin_joints)] - origin
        mask = np.isin(level.panel, members)
        rel = (positions[mask] - rest[start]) @ turn.T
        along = rel @ axis
        # each panel's outward direction: its placed normal, made perpendicular to the axis
        normals = np.zeros_like(rel)
        for p in members:
            n = turn @ Rotation.from_euler("xyz", panels[p].placement.rotation_deg, degrees=True).apply([0.0, 0.0, 1.0])
            n -= (n @ axis) * axis
            if np.linalg.norm(n) < 1e-6:
                raise DressingError(f"cannot dress '{template.name}': panel '{panels[p].name}' lies across the "
                                    f"axis of '{group}' (its placement must face away from the body part)")
            normals[level.panel[mask] == p] = n / np.linalg.norm(n)
        tangents = np.cross(axis, normals)
        s = np.einsum("vk,vk->v", rel, tangents)
        facing = np.unique(np.round(normals, 3), axis=0)
        max_angle = 0.95 * np.pi / len(facing)
        # the radius per height: body radius there (+ clearance) or what the panels' width needs
        bins = np.linspace(along.min() - 1e-6, along.max() + 1e-6, max(2, int(np.ptp(along) / 0.02) + 1))
        which = np.clip(np.digitize(along, bins) - 1, 0, len(bins) - 2)
        skin_along = skin @ axis
        skin_radius = np.linalg.norm(skin - skin_along[:, None] * axis, axis=1)
        radius = np.zeros(len(bins) - 1)
        for b in range(len(bins) - 1):
            near = (skin_along > bins[b] - 0.03) & (skin_along < bins[b + 1] + 0.03)
            body_r = skin_radius[near].max() if near.any() else 0.0
            width = np.abs(s[which == b]).max() if np.any(which == b) else 0.0
            radius[b] = max(body_r + clearance, width / max_angle)
        radius = np.convolve(np.pad(radius, 2, mode="edge"), np.ones(5) / 5, mode="valid")  # smooth over 10 cm
        r = radius[which]
        angle = s / r
        positions[mask] = origin + along[:, None] * axis + r[:, None] * (
            np.cos(angle)[:, None] * normals + np.sin(angle)[:, None] * tangents)
    legs = [p for p, panel in enumerate(panels) if panel.placement.body_part in ("leg_left", "leg_right")]
    if legs:
        _wrap_legs(positions, level.panel, panels, legs, body, dressed, clearance)
    # anything still inside the body (armpits, the crotch) steps outside it
    collider = MeshCollider(body_vertices, body.faces)
    d, n = collider.signed_distance(positions)
    inside = d < clearance / 2
    positions[inside] += (clearance / 2 - d[inside])[:, None] * n[inside]
    return positions


def _wrap_legs(positions: np.ndarray, panel_of: np.ndarray, panels, legs: list[int], body: BodyModel,
               dressed: DressingBody, clearance: float, bin_height: float = 0.02, blend: float = 0.15) -> None:
    """Step 2 for trouser legs, in place: each leg panel is rolled around the pelvis's vertical axis
    above the crotch (its inner edge at the centre front or back, like a skirt panel) and around its
    leg's axis below (its middle in front of or behind the leg), blended over `blend` (m) above the
    pattern's crotch point.  Flat panels sew their inseams through the legs."""
    joints = dict(zip(body.joint_names, dressed.joints))
    dominant = np.asarray(body.joint_names)[np.argmax(body.weights, axis=1)]
    pelvis = joints["pelvis"]
    up = np.array([0.0, 0.0, 1.0])
    lower_body = ("pelvis", "spine1", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle")
    hips = np.isin(dominant, lower_body)
    for p in legs:
        _, start, end, _ = _PARTS[panels[p].placement.body_part]
        hip, ankle = joints[start], joints[end]
        side = start.split("_")[0]
        leg_skin = np.isin(dominant, [start, f"{side}_knee", end])
        normal = Rotation.from_euler("xyz", panels[p].placement.rotation_deg, degrees=True).apply([0.0, 0.0, 1.0])
        normal[2] = 0.0
        normal /= np.linalg.norm(normal)
        tangent = np.cross(up, normal)
        mask = panel_of == p
        x = positions[mask]
        u = x @ tangent
        z = x[:, 2]
        # the panel's inner edge is its crotch seam: at the waist, the side nearer the pelvis axis
        top = u[z > np.quantile(z, 0.95)] - pelvis @ tangent
        inner_sign = -1.0 if abs(top.min()) < abs(top.max()) else 1.0
        crotch_z = z[np.argmax(inner_sign * u)]  # the crotch point: the panel's innermost
        w = np.clip((crotch_z + blend - z) / blend, 0.0, 1.0)
        w = w * w * (3.0 - 2.0 * w)  # smoothstep: 0 around the pelvis, 1 around the leg
        # per-height panel extent and cylinder radius, interpolated between 2 cm rows
        rows = np.arange(z.min(), z.max() + bin_height, bin_height)
        which = np.clip(np.rint((z - rows[0]) / bin_height).astype(int), 0, len(rows) - 1)
        lo = np.full(len(rows), np.inf)
        hi = np.full(len(rows), -np.inf)
        np.minimum.at(lo, which, u)
        np.maximum.at(hi, which, u)
        filled = np.isfinite(lo)
        lo = np.interp(z, rows[filled], lo[filled])
        hi = np.interp(z, rows[filled], hi[filled])
        inner = lo if inner_sign < 0 else hi
        # tangential arc length from the centre seam (pelvis) or the panel's middle (leg)
        s = (1.0 - w) * (u - inner) + w * (u - 0.5 * (lo + hi))
        leg_axis = hip + np.outer((hip[2] - z) / (hip[2] - ankle[2]), ankle - hip)
        centre = (1.0 - w)[:, None] * pelvis + w[:, None] * leg_axis
        centre[:, 2] = 0.0
        # radius: clear the skin (around whichever axis) and turn no panel more than a quarter turn
        # either way from where it starts
        row_radius = np.zeros(len(rows))
        for b in range(len(rows)):
            near = np.abs(dressed.vertices[:, 2] - rows[b]) < bin_height
            axis_b = hip + (hip[2] - rows[b]) / (hip[2] - ankle[2]) * (ankle - hip)
            top_r = np.linalg.norm((dressed.vertices[near & hips] - pelvis)[:, :2], axis=1).max(initial=0.0)
            leg_r = np.linalg.norm((dressed.vertices[near & leg_skin] - axis_b)[:, :2], axis=1).max(initial=0.0)
            here = which == b
            wb = w[here].mean() if here.any() else 0.0
            need = np.abs(s[here]).max(initial=0.0) / (0.95 * np.pi / 2)
            row_radius[b] = max((1.0 - wb) * top_r + wb * leg_r + clearance, need)
        row_radius = np.convolve(np.pad(row_radius, 2, mode="edge"), np.ones(5) / 5, mode="valid")
        radius = np.interp(z, rows, row_radius)
        angle = s / radius
        positions[mask] = centre + radius[:, None] * (np.cos(angle)[:, None] * normal + np.sin(angle)[:, None] * tangent)
        positions[mask, 2] = z


def dress(template: Template, body: BodyModel, betas: np.ndarray | None = None,
          params: DressingParams = DressingParams(), progress: bool = True) -> DressedGarment:
    """Steps 1-4 of the module docstring; raises `DressingError` when the pattern cannot be dressed."""
    started = time.perf_counter()
    betas = body.default_betas if betas is None else np.asarray(betas, np.float64)
    # outside the shapes a default garment is known to fit, try anyway (it may well dress), but say
    # why if it does not
    misfit = default_body_misfit(template.pattern, body.name, body.shape_names, betas)
    if misfit is not None:
        log.warning("dressing '%s' on a shape it may not fit: %s", template.name, misfit)
    misfit = "" if misfit is None else f"; {misfit}"
    level = template.level(params.level_mm)
    if len(level.seam_pairs) == 0:
        raise DressingError(f"cannot dress '{template.name}': the pattern has no seams")
    dressed = dressing_body(body, betas, params.pose)
    collider = MeshCollider(dressed.vertices, body.faces)
    positions = curve_onto_body(template, params.level_mm, body, dressed, params.clearance)

    # 3. sew
    rest_corners = level.pattern_xy[level.faces]
    sew_params = replace(params.cloth, gravity=(0.0, 0.0, 0.0), contact_margin=max(params.cloth.contact_margin, 0.02))
    model = ClothModel.build(level.faces, rest_corners, sew_params)
    pairs = level.seam_pairs.astype(np.int64)
    pair_area = 0.5 * (model.vertex_areas[pairs[:, 0]] + model.vertex_areas[pairs[:, 1]])
    weight = params.seam_weight
    solver = ProjectiveDynamics(model, springs=pairs, spring_stiffness=weight * pair_area)
    state = ClothState(positions, np.zeros_like(positions))
    best, since_best, steps, stalled = np.inf, 0, 0, 0
    bar = tqdm(total=params.max_sew_steps, desc=f"sewing {template.name}", unit="step", disable=not progress,
               leave=False)
    for steps in range(1, params.max_sew_steps + 1):
        # quasi-static: every step starts at rest.  With velocities carried over, vertices the
        # placement left inside the buttocks were shot out by the contact penalty, tore the back
        # crotch 19 cm apart and dragged the pants' waist 5 cm down onto the hips, where it could
        # not close; at rest, the inertia term only limits how far a step moves the cloth.
        state = solver.step(ClothState(state.positions, np.zeros_like(state.positions)), collider)
        gap = solver.spring_lengths(state.positions).max()
        depth = -collider.signed_distance(state.positions)[0].min()
        bar.update()
        bar.set_postfix(gap_mm=f"{gap * 1e3:.1f}", k=f"{weight:.0e}")
        if gap < params.gap_tolerance and depth <= 0.0:
            break
        if gap < 0.95 * best:
            best, since_best, stalled = gap, 0, 0
        else:
            since_best += 1
            stalled += 1
        ceiling = params.max_seam_weight if gap < params.near_gap else params.far_seam_weight
        if since_best >= 20 and gap >= params.gap_tolerance and weight < ceiling:
            weight = min(weight * params.seam_growth, ceiling)
            solver.set_spring_stiffness(weight * pair_area)
            best, since_best = gap, 0
        if stalled >= params.stall_steps and weight >= ceiling:
            break
    bar.close()
    if not (gap < params.gap_tolerance and depth <= 0.0):
        stuck = DressedGarment(template.name, params.level_mm, level.faces.copy(), rest_corners, state.positions,
                               np.asarray(betas, np.float64), dressed.trans, dressed.pose)
        how = "its widest gap stopped shrinking" if steps < params.max_sew_steps else "it ran out of steps"
        raise DressingError(
            f"cannot dress '{template.name}': sewing stopped after {steps} steps ({how}) with the widest seam gap "
            f"{gap * 1e3:.1f} mm (tolerance {params.gap_tolerance * 1e3:.1f} mm) and the deepest vertex "
            f"{max(depth, 0) * 1e3:.1f} mm inside the body; widest open seams: "
            f"{_worst_seams(template, level.seam, solver.spring_lengths(state.positions), params)}{misfit}", stuck)
    sew_gap = float(gap)

    # 4. merge and settle under gravity
    sewn = level.sew(state.positions)
    sewn_model = ClothModel.build(level.sewn_faces, rest_corners,
                                  replace(params.cloth, contact_weight=params.settle_contact_weight))
    settle = ProjectiveDynamics(sewn_model)
    state = ClothState(sewn, np.zeros_like(sewn))
    for _ in range(int(round(params.settle_seconds / params.cloth.timestep))):
        state = settle.step(state, collider)
    depth = float(max(0.0, -collider.signed_distance(state.positions)[0].min()))
    drop = float(sewn[:, 2].mean() - state.positions[:, 2].mean())
    if drop > params.max_settle_drop:
        raise DressingError(
            f"cannot dress '{template.name}': the sewn garment does not hold on the body (it slid "
            f"{drop * 100:.0f} cm down while settling: its panels closed around the wrong side of a body "
            f"part){misfit}",
            DressedGarment(template.name, params.level_mm, level.sewn_faces.copy(), rest_corners, state.positions,
                           np.asarray(betas, np.float64), dressed.trans, dressed.pose))
    report = {
        "sew_steps": steps, "seam_gap_mm": sew_gap * 1e3, "final_seam_weight": weight,
        "max_penetration_mm": depth * 1e3,
        "max_strain": float(np.abs(sewn_model.edge_length_strain(state.positions)).max()),
        "seconds": time.perf_counter() - started, "params": asdict(params),
    }
    log.info("dressed %s (%d mm level): %d sewing steps, gap %.2f mm, penetration %.2f mm, %.1f s", template.name,
             params.level_mm, steps, sew_gap * 1e3, depth * 1e3, report["seconds"])
    return DressedGarment(template.name, params.level_mm, level.sewn_faces.copy(), rest_corners, state.positions,
                          np.asarray(betas, np.float64), dressed.trans, dressed.pose, report)


def _worst_seams(template: Template, seam_of_pair: np.ndarray, gaps: np.ndarray, params: DressingParams) -> str:
    """'panel.edge-panel.edge 89.1 mm, ...' for the `params.worst_seams` seams with the widest gap
    (metres per seam pair in `gaps`, the seam of each pair in `seam_of_pair`) over the tolerance."""
    widest = np.zeros(len(template.pattern.seams))
    np.maximum.at(widest, seam_of_pair, gaps)
    open_seams = [i for i in np.argsort(-widest, kind="stable") if widest[i] >= params.gap_tolerance]
    named = [f"{s.a.panel}.{s.a.edge}-{s.b.panel}.{s.b.edge} {widest[i] * 1e3:.1f} mm"
             for i in open_seams[:params.worst_seams] for s in [template.pattern.seams[i]]]
    more = len(open_seams) - len(named)
    return (", ".join(named) or "none") + (f" (and {more} more open)" if more > 0 else "")


def save_stuck(error: DressingError, body: BodyModel, out: str | Path) -> list[Path]:
    """Write where a failed dressing stopped, OUT/NAME_stuck.npz (`DressedGarment.save`) and
    OUT/NAME_stuck.png (`write_preview`); returns the paths, none when `error` holds no garment."""
    if error.stuck is None:
        return []
    out = Path(out)
    paths = [out / f"{error.stuck.garment}_stuck.npz", out / f"{error.stuck.garment}_stuck.png"]
    error.stuck.save(paths[0])
    write_preview(error.stuck, body, paths[1], title=f"{error.stuck.garment}: dressing stopped here")
    return paths


def write_preview(garment: DressedGarment, body: BodyModel, png: str | Path, title: str | None = None) -> None:
    """Body and dressed garment from four sides, into a PNG (`title` default: 'NAME dressed (L mm)')."""
    from assets.body.model import PosedBody
    from assets.motion.export import render_preview
    from assets.rotations import rotvec_to_matrix

    body_vertices = body.pose(dressing_pose(garment.dressing_pose)[None], garment.body_trans[None],
                              garment.body_betas).vertices[0]
    turns = [rotvec_to_matrix(np.array([0.0, 0.0, np.deg2rad(a)])) for a in (0, 90, 180, 270)]
    posed = PosedBody(vertices=np.stack([body_vertices @ r.T for r in turns]), joints=np.zeros((4, body.num_joints, 3)),
                      faces=body.faces)
    render_preview(png, posed, frames=np.arange(4), labels=["front", "side", "back", "side"],
                   title=title or f"{garment.garment} dressed ({garment.level_mm} mm)",
                   extra=((np.stack([garment.positions @ r.T for r in turns]), garment.faces, (0.25, 0.45, 0.85)),))


def main(argv: list[str] | None = None) -> int:
    import argparse

    from assets.body import load_body
    from assets.cli import add_out, add_progress, progress, run_cli

    parser = argparse.ArgumentParser(prog="python -m factory.dressing", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("garments", nargs="+", help="default garment names, pattern JSONs or template .npz files")
    parser.add_argument("--body", default="default")
    parser.add_argument("--betas", help="body shape, comma-separated")
    parser.add_argument("--level", type=int, default=TRAINING_LEVEL_MM)
    parser.add_argument("--pose", choices=("A", "T"), default="A")
    add_out(parser, "folder for <garment>_dressed.npz and its preview PNG")
    add_progress(parser)
    args = parser.parse_args(argv)
    args.out = Path(args.out)

    def action() -> None:
        from assets.garments.loading import load_template

        args.out.mkdir(parents=True, exist_ok=True)
        body = load_body(args.body)
        betas = None if not args.betas else np.array([float(v) for v in args.betas.split(",")])
        rows = []
        for spec in args.garments:
            template = load_template(spec)
            try:
                garment = dress(template, body, betas, DressingParams(level_mm=args.level, pose=args.pose),
                                progress=progress(args))
            except DressingError as exc:
                saved = save_stuck(exc, body, args.out)
                raise DressingError(f"{exc}" + (f"; where it stopped: {', '.join(map(str, saved))}" if saved
                                                  else "")) from exc
            garment.save(args.out / f"{template.name}_dressed.npz")
            write_preview(garment, body, args.out / f"{template.name}_dressed.png")
            r = garment.report
            rows.append(f"| {template.name} | {args.level} | {len(garment.positions)} | {r['sew_steps']} | "
                        f"{r['seam_gap_mm']:.2f} | {r['max_penetration_mm']:.2f} | {r['seconds']:.0f} |")
        print("| garment | level (mm) | vertices | sewing steps | widest seam gap (mm) | max penetration (mm) | seconds |")
        print("|---|---|---|---|---|---|---|")
        print("\n".join(rows))

    return run_cli(action, failures=(DressingError,))


if __name__ == "__main__":
    import sys

    sys.exit(main())
