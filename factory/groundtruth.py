"""Ground truth for one rendered image: where every marker's points are, and which ones are seen.

Two steps.  `assets.garments.markers.MarkerSurface.build(template, level_mm)` (once per template
and level) finds every marker point on the garment mesh; `image_ground_truth(surface, positions, camera, depth)` (once per
image) projects them with the render's camera and decides visibility against the render's depth.
The result is an `assets.pattern.observation.ImageGroundTruth`, from which that module makes the
training targets of the three networks.

Conventions: metres; pixels are continuous image coordinates (x right, y down) with pixel centres at
integer + 0.5 (DESIGN.md); depth is the camera-frame z (distance along the view axis, as in Blender's
Z pass).  M markers (every marker of every panel, in panel order, then the panel's row-major marker
order), K = crosspoints_per_side (25), the five localization points in the order
`assets.pattern.LOCALIZATION_POINTS` (centre, TL, TR, BL, BR; each is also a crosspoint).
"""

from __future__ import annotations

import numpy as np

from assets.cameras import Camera
from assets.garments.markers import MarkerSurface, face_normals, interpolate, take
from assets.pattern.observation import ImageGroundTruth
from assets.pattern.table import localization_rc


def image_ground_truth(
    surface: MarkerSurface,
    positions: np.ndarray,
    camera: Camera,
    depth: np.ndarray,
    depth_tolerance: float = 0.005,
) -> ImageGroundTruth:
    """Project and test every marker point of `surface` in one rendered image.

    positions (V, 3): the sewn-mesh vertices in world coordinates as rendered, metres.
    camera: the render's camera.  depth (H, W): the renderer's depth along the view axis, metres,
    inf (or huge) on the background.  depth_tolerance: metres a point may lie behind the rendered
    depth of its pixel and still be seen (absorbs the depth change across one pixel)."""
    depth = np.asarray(depth)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"depth has shape {depth.shape}, expected (H, W) = {(camera.height, camera.width)} "
                         f"of camera {camera.name!r}")
    if not depth_tolerance >= 0:
        raise ValueError(f"depth_tolerance must be >= 0, got {depth_tolerance}")
    positions = surface.checked_positions(positions)
    face = surface.xp_face.reshape(-1)
    points = interpolate(positions, surface.sewn_faces, face, surface.xp_bary.reshape(-1, 3))
    normals = take(face_normals(positions, surface.sewn_faces), face)
    pixels, z = camera.project(points)
    with np.errstate(invalid="ignore"):
        seen = (face >= 0) & (z > 0) & (np.einsum("nd,nd->n", normals, camera.center - points) > 0)
        seen &= (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < camera.height)
    candidates = np.flatnonzero(seen)
    cols = np.floor(pixels[candidates, 0]).astype(np.int64)
    rows = np.floor(pixels[candidates, 1]).astype(np.int64)
    with np.errstate(invalid="ignore"):
        seen[candidates] = z[candidates] <= depth[rows, cols].astype(np.float64) + depth_tolerance

    m, k = surface.xp_face.shape[:2]
    on = (face >= 0).reshape(m, k, k)
    visible = seen.reshape(m, k, k)
    crosspoints_px = pixels.reshape(m, k, k, 2).astype(np.float32)
    crosspoints_z = np.where(face >= 0, z, np.nan).reshape(m, k, k).astype(np.float32)
    rc = localization_rc(surface.spec)
    point_visible = visible[:, rc[:, 0], rc[:, 1]]
    full = (visible == on).all(axis=(1, 2)) & point_visible.all(axis=1)
    status = np.where(full, 2, np.where(visible.any(axis=(1, 2)), 1, 0)).astype(np.int8)
    return ImageGroundTruth(
        width=camera.width,
        height=camera.height,
        marker_id=surface.marker_id.astype(np.int32),
        points_px=crosspoints_px[:, rc[:, 0], rc[:, 1]],
        points_depth=crosspoints_z[:, rc[:, 0], rc[:, 1]],
        point_visible=point_visible,
        crosspoints_px=crosspoints_px,
        crosspoint_visible=visible,
        status=status,
    )
