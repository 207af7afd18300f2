"""A garment whose exact 3D shape is known without simulation: two rectangular panels sewn along both
sides into a cylinder (an isometric wrap of the sewing pattern, so its rest shape is free of strain and
of intersections), and captured points made from any shape of it, for the refine tests."""

from __future__ import annotations

import numpy as np

from assets.garments.sewing import SewingPattern
from assets.garments.template import Template
from reconstruction.anchors import LevelAnchoring
from reconstruction.points import CapturedPoints

WIDTH, HEIGHT = 0.24, 0.30  # m, each panel
RADIUS = WIDTH / np.pi  # the two panels make one circumference


def _panel(name: str, rotation: list[float], translation: list[float]) -> dict:
    return {"name": name, "vertices": [[0, 0], [WIDTH, 0], [WIDTH, HEIGHT], [0, HEIGHT]],
            "edges": [{"name": "hem"}, {"name": "right"}, {"name": "top"}, {"name": "left"}],
            "placement": {"body_part": "torso_front", "rotation_deg": rotation, "translation": translation}}


CYLINDER = {
    "name": "cylinder",
    "panels": [_panel("front", [90, 0, 0], [-WIDTH / 2, -0.1, 1.0]), _panel("back", [90, 0, 180], [WIDTH / 2, 0.1, 1.0])],
    "seams": [
        {"a": {"panel": "front", "edge": "right"}, "b": {"panel": "back", "edge": "left"}, "reverse": True},
        {"a": {"panel": "front", "edge": "left"}, "b": {"panel": "back", "edge": "right"}, "reverse": True},
    ],
}


def cylinder_template() -> Template:
    return Template.build(SewingPattern.from_dict(CYLINDER, "CYLINDER"))


def wrapped(template: Template, level_mm: int) -> np.ndarray:
    """(V, 3) the sewn level rolled onto the cylinder of axis z (front: angles 0..pi, back: pi..2 pi),
    its hem at z = 1 m."""
    level = template.level(level_mm)
    x, y = level.pattern_xy[:, 0], level.pattern_xy[:, 1]
    theta = np.pi * x / WIDTH + np.pi * level.panel
    return level.sew(np.stack([RADIUS * np.cos(theta), RADIUS * np.sin(theta), 1.0 + y], axis=1))


def bent(shape: np.ndarray, amount: float, shift: tuple[float, float, float]) -> np.ndarray:
    """The shape bent sideways (x grows with the squared height above the hem) and moved (m)."""
    out = np.array(shape, dtype=np.float64)
    height = out[:, 2] - 1.0
    out[:, 0] += amount * height**2 / HEIGHT
    return out + np.asarray(shift)


def sewn_pattern_xy(template: Template, level_mm: int) -> tuple[np.ndarray, np.ndarray]:
    """Each sewn vertex's panel (V,) and pattern position (V, 2) (a seam vertex: one of its copies)."""
    level = template.level(level_mm)
    panel = np.zeros(level.num_sewn_vertices, np.int64)
    xy = np.zeros((level.num_sewn_vertices, 2))
    panel[level.sewn_index], xy[level.sewn_index] = level.panel, level.pattern_xy
    return panel, xy


def every_key(anchoring: LevelAnchoring) -> np.ndarray:
    """(N, 2) keys (panel, crosspoint index) of every crosspoint on the level's fabric."""
    flat = np.flatnonzero(anchoring.lookup >= 0)
    panel = np.searchsorted(anchoring.first_crosspoint, flat, side="right") - 1
    return np.stack([panel, flat - anchoring.first_crosspoint[panel]], axis=1)


def key_pattern_xy(template: Template, anchoring: LevelAnchoring, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Panel (N,) and pattern position (N, 2) of crosspoints `key`."""
    level = template.level(anchoring.level_mm)
    rows = anchoring.rows(key)
    corners = level.faces[anchoring.face[rows]]
    return level.panel[corners[:, 0]].astype(np.int64), np.einsum("pkd,pk->pd", level.pattern_xy[corners],
                                                                     anchoring.bary[rows])


def captured_points(anchoring: LevelAnchoring, shape: np.ndarray, key: np.ndarray, frame: int = 0,
                    noise: float = 0.0, rng: np.random.Generator | None = None) -> CapturedPoints:
    """The crosspoints `key` on `shape` (a shape of the anchoring's level) as one frame's capture, seen by
    two cameras, with Gaussian noise of `noise` m per coordinate."""
    xyz = anchoring.points_on(shape, key)
    if noise:
        xyz = xyz + rng.normal(0.0, noise, xyz.shape)
    rows = anchoring.rows(key)
    n = len(key)
    return CapturedPoints(level_mm=anchoring.level_mm, key=np.asarray(key, np.int64), xyz=xyz,
                          face=anchoring.face[rows], bary=anchoring.bary[rows], views=np.ones((n, 2), bool),
                          reprojection_px=np.zeros(n), confidence=np.ones(n), frame=frame, source="test")
