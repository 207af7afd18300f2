"""Triangulation: every crosspoint seen in at least two views -> a 3D point with its views.

Per frame (`triangulate_frame`):

1. **Gather** (`gather_views`): each view's detections become crosspoint observations keyed by
   crosspoint (`reconstruction.correspondence`), undistorted to the pinhole model
   (`reconstruction.cameras.undistort_pixels`).  A crosspoint seen twice in one view (a border
   crosspoint of two neighbouring markers) keeps the most confident observation, averaged
   (confidence-weighted) with the others that agree with it within `duplicate_px`.
2. **Solve** (`triangulate_points`), vectorised over points: linear DLT in normalised camera
   coordinates over all observed views, then Levenberg-Marquardt (Gauss-Newton with the analytic
   Jacobian and a per-point damping) on the reprojection error in pixels.  Views whose error
   exceeds `threshold_px` make the point suspect; a suspect point runs **RANSAC over views**: every
   pair of its views (or `max_hypotheses` random pairs) gives a two-view DLT hypothesis, the one
   with the most views within `threshold_px` wins (ties: the smaller truncated squared error), and
   the point is refitted on those inlier views until they no longer change.  Wrong marker IDs and
   gross detection errors thus fall out as outlier views.  A point is kept with at least
   `min_views` inlier views, all in front of their cameras, and two inlier rays at least
   `min_angle_deg` from parallel (or antiparallel).
3. Each point keeps its inlier views, the RMS reprojection error over them, and a **confidence**

       confidence = detection x support x geometry x fit,   in [0, 1]:
         detection = mean detection confidence of the inlier views
         support   = 1 - 2^-(n - 1)                for n inlier views (2: 0.5, 3: 0.75, 8: 0.99)
         geometry  = sin(angle)                    angle: between the two inlier rays that fix the
                                                   point best (closest to 90 degrees)
         fit       = exp(-(rms / threshold_px)^2 / 2)

4. **Neighbour check** (`reconstruction.consistency`, `TriangulationConfig.neighbours`): points
   that no crosspoint of another marker confirms in 3D (within the cloth's stretch of their rest
   distance on the pattern) are dropped: a marker read with a wrong ID in one view gives points
   that reproject well at a wrong depth when only two views see them.

Reprojection errors are measured in the pinhole (undistorted) image of each camera, pixels.
C cameras, N points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from itertools import combinations
from typing import Mapping, Sequence

import numpy as np
from tqdm import tqdm

from assets.cameras import Camera
from networks.detections import Detections
from reconstruction.cameras import undistort_pixels
from reconstruction.consistency import NeighbourConfig, consistent_points
from reconstruction.correspondence import CrosspointMap
from reconstruction.points import CapturedPoints

log = logging.getLogger(__name__)

#: points solved per batch (bounds memory: hypotheses take about 2 kB per point and camera pair)
_BATCH = 8192


@dataclass(frozen=True)
class TriangulationConfig:
    """Triangulation settings.

    threshold_px: largest reprojection error (pixels) of an inlier view (RANSAC threshold).
    min_views: fewest inlier views of a kept point.
    iterations: Levenberg-Marquardt iterations of each refinement.
    max_hypotheses: camera pairs RANSAC tries per point (all of them when it has fewer).
    min_angle_deg: a kept point has two inlier rays at least this far (degrees) from parallel or
        antiparallel.
    duplicate_px: two observations of one crosspoint in one view within this many pixels are
        averaged; otherwise the more confident is kept (default: `threshold_px`).
    seed: seeds the choice of pairs when a point has more than `max_hypotheses`.
    neighbours: the pattern-neighbour check of the frame's points (`reconstruction.consistency`), or
        None to keep every point the views accept."""

    threshold_px: float = 2.0
    min_views: int = 2
    iterations: int = 10
    max_hypotheses: int = 64
    min_angle_deg: float = 1.0
    duplicate_px: float | None = None
    seed: int = 0
    neighbours: NeighbourConfig | None = NeighbourConfig()

    def __post_init__(self) -> None:
        if not self.threshold_px > 0:
            raise ValueError(f"TriangulationConfig.threshold_px must be > 0, got {self.threshold_px}")
        if self.min_views < 2:
            raise ValueError(f"TriangulationConfig.min_views must be >= 2, got {self.min_views}")
        if self.iterations < 1 or self.max_hypotheses < 1:
            raise ValueError(f"TriangulationConfig.iterations and max_hypotheses must be >= 1, got "
                             f"{self.iterations}, {self.max_hypotheses}")
        if not 0 <= self.min_angle_deg < 90:
            raise ValueError(f"TriangulationConfig.min_angle_deg must be in [0, 90), got {self.min_angle_deg}")
        if self.duplicate_px is not None and not self.duplicate_px >= 0:
            raise ValueError(f"TriangulationConfig.duplicate_px must be >= 0, got {self.duplicate_px}")

    @property
    def duplicate_tolerance_px(self) -> float:
        return self.threshold_px if self.duplicate_px is None else self.duplicate_px


@dataclass(frozen=True, eq=False)
class Triangulation:
    """The solution for N candidate points.

      xyz (N, 3) float64             world metres (NaN where not valid)
      inliers (N, C) bool            views within the threshold of the final point
      reprojection_px (N,) float64   RMS reprojection error over the inliers, pinhole pixels
      angle_deg (N,) float64         angle in [0, 90] between the two inlier rays closest to
                                     perpendicular (an angle a beyond 90 counts as 180 - a)
      confidence (N,) float64        in [0, 1] (module docstring), 0 where not valid
      valid (N,) bool                kept: enough inliers, in front of them, wide enough angle
    """

    xyz: np.ndarray
    inliers: np.ndarray
    reprojection_px: np.ndarray
    angle_deg: np.ndarray
    confidence: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True, eq=False)
class GatheredViews:
    """One frame's observations of N crosspoints in C views.

      flat (N,) int64               garment-wide crosspoint numbers (`CrosspointMap.flat`), sorted
      pixels (N, C, 2) float64      undistorted (pinhole) pixels, NaN where not observed
      observed (N, C) bool
      confidence (N, C) float64     detection confidence, 0 where not observed
    """

    flat: np.ndarray
    pixels: np.ndarray
    observed: np.ndarray
    confidence: np.ndarray


# ---- gathering -----------------------------------------------------------------------------------

def merge_duplicates(flat: np.ndarray, pixels: np.ndarray, confidence: np.ndarray,
                     tolerance_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One view's observations (n,) keys `flat`, (n, 2) pixels, (n,) confidence -> one observation
    per key, sorted by key: the most confident, averaged (weighted by confidence) with those within
    `tolerance_px` of it; its confidence is the largest."""
    order = np.lexsort((-confidence, flat))
    flat, pixels, confidence = flat[order], pixels[order], confidence[order]
    unique, first, group = np.unique(flat, return_index=True, return_inverse=True)
    agree = np.linalg.norm(pixels - pixels[first][group], axis=1) <= tolerance_px
    weight = np.where(agree, confidence + 1e-12, 0.0)
    total = np.bincount(group, weight, minlength=len(unique))
    merged = np.stack([np.bincount(group, weight * pixels[:, i], minlength=len(unique)) for i in range(2)], axis=1)
    return unique, merged / total[:, None], confidence[first]


def gather_views(crosspoints: CrosspointMap, cameras: Sequence[Camera], detections: Sequence[Detections],
                 config: TriangulationConfig = TriangulationConfig()) -> GatheredViews:
    """Every view's detections (in camera order) -> their crosspoint observations side by side."""
    if len(detections) != len(cameras):
        raise ValueError(f"{len(detections)} views of detections for {len(cameras)} cameras")
    per_view = []
    for camera, found in zip(cameras, detections):
        observations, _ = crosspoints.observations(found, where=f"camera {camera.name!r}")
        pixels = undistort_pixels(camera, observations.pixels)
        per_view.append(merge_duplicates(crosspoints.flat(observations.key), pixels, observations.confidence,
                                         config.duplicate_tolerance_px))
    flat = np.unique(np.concatenate([v[0] for v in per_view])) if per_view else np.zeros(0, np.int64)
    n, c = len(flat), len(cameras)
    pixels = np.full((n, c, 2), np.nan)
    observed = np.zeros((n, c), dtype=bool)
    confidence = np.zeros((n, c))
    for view, (keys, px, conf) in enumerate(per_view):
        rows = np.searchsorted(flat, keys)
        pixels[rows, view], observed[rows, view], confidence[rows, view] = px, True, conf
    return GatheredViews(flat=flat.astype(np.int64), pixels=pixels, observed=observed, confidence=confidence)


# ---- geometry (vectorised) -----------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class _Rig:
    """Pinhole cameras as stacked arrays: K, R (C, 3, 3), t (C, 3), Kinv (C, 3, 3), Rt (C, 3, 4),
    centres (C, 3)."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    @classmethod
    def of(cls, cameras: Sequence[Camera]) -> "_Rig":
        return cls(np.stack([c.K for c in cameras]), np.stack([c.R for c in cameras]), np.stack([c.t for c in cameras]))

    @property
    def Rt(self) -> np.ndarray:
        return np.concatenate([self.R, self.t[:, :, None]], axis=2)

    @property
    def centres(self) -> np.ndarray:
        return -np.einsum("cji,cj->ci", self.R, self.t)

    def normalised(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (..., C, 2) -> normalised camera coordinates (..., C, 2)."""
        homogeneous = np.concatenate([pixels, np.ones(pixels.shape[:-1] + (1,))], axis=-1)
        rays = np.einsum("cij,...cj->...ci", np.linalg.inv(self.K), homogeneous)
        return rays[..., :2] / rays[..., 2:]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World points (..., 3) -> (pixels (..., C, 2), camera-frame points (..., C, 3), depth (..., C))."""
        c = len(self.R)
        # one matrix product for every camera at once: (M, 3) @ (3, 3C)
        xc = (points.reshape(-1, 3) @ self.R.reshape(3 * c, 3).T).reshape(points.shape[:-1] + (c, 3)) + self.t
        depth = xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = xc[..., 0] / depth, xc[..., 1] / depth
        k = self.K
        pixels = np.stack([k[:, 0, 0] * x + k[:, 0, 1] * y + k[:, 0, 2], k[:, 1, 1] * y + k[:, 1, 2]], axis=-1)
        return pixels, xc, depth

    def errors(self, points: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """Reprojection errors (..., C) in pixels of points (..., 3) against pixels (..., C, 2);
        inf behind a camera, NaN where pixels are NaN."""
        projected, _, depth = self.project(points)
        with np.errstate(invalid="ignore"):
            error = np.sqrt(np.square(projected - pixels).sum(axis=-1))
            return np.where(depth > 0, error, np.inf)


def dlt(Rt: np.ndarray, normalised: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Linear triangulation: cameras Rt (..., V, 3, 4) (world -> camera, normalised coordinates),
    observations (..., V, 2) in normalised coordinates, weights (..., V) (0 leaves a view out)
    -> points (..., 3) (inf or NaN where the views do not fix a point).

    The null vector of the stacked DLT rows is the eigenvector of their 4 x 4 normal matrix with the
    smallest eigenvalue (the refinement that follows removes the normal matrix's rounding)."""
    observed = np.where(weight[..., None] > 0, normalised, 0.0)
    rows_x = observed[..., 0:1] * Rt[..., 2, :] - Rt[..., 0, :]
    rows_y = observed[..., 1:2] * Rt[..., 2, :] - Rt[..., 1, :]
    a = np.concatenate([rows_x, rows_y], axis=-2) * np.concatenate([weight, weight], axis=-1)[..., None]
    homogeneous = np.linalg.eigh(np.swapaxes(a, -1, -2) @ a)[1][..., :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return homogeneous[..., :3] / homogeneous[..., 3:]


#: a point whose Levenberg-Marquardt step is below this many metres has converged (rounding keeps
#: steps of about 1e-12 m going at a minimum)
_STEP_TOLERANCE = 1e-10


def refine_points(rig: _Rig, points: np.ndarray, pixels: np.ndarray, views: np.ndarray, iterations: int) -> np.ndarray:
    """Levenberg-Marquardt on the squared reprojection error: points (N, 3), pixels (N, C, 2),
    views (N, C) bool (the views each point is fitted to) -> refined points (N, 3).  A step is kept
    only where it lowers a point's error (so a point never moves behind one of its views); points
    stop when their step falls below `_STEP_TOLERANCE`."""
    points = np.array(points, dtype=np.float64)
    target = np.where(views[..., None], pixels, 0.0)

    def cost(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        error = rig.errors(x, target[rows])
        with np.errstate(invalid="ignore"):
            return np.square(np.where(views[rows], error, 0.0)).sum(axis=1)

    current = cost(points, slice(None))
    damping = np.full(len(points), 1e-4)
    active = np.flatnonzero(np.isfinite(points).all(axis=1) & np.isfinite(current))
    k = rig.K
    for _ in range(iterations):
        if not len(active):
            break
        x, used = points[active], views[active]
        projected, xc, depth = rig.project(x)
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = np.where(used, 1.0 / depth, 0.0)
        xn, yn = xc[..., 0] * inverse, xc[..., 1] * inverse
        # rows of d(x/z, y/z)/d(world point): (R0 - x/z R2) / z and (R1 - y/z R2) / z, (n, C, 3)
        a = (rig.R[:, 0] - xn[..., None] * rig.R[:, 2]) * inverse[..., None]
        b = (rig.R[:, 1] - yn[..., None] * rig.R[:, 2]) * inverse[..., None]
        jacobian = np.concatenate([k[:, 0, 0, None] * a + k[:, 0, 1, None] * b, k[:, 1, 1, None] * b], axis=1)
        residual = np.where(used[..., None], projected - target[active], 0.0)
        residual = np.concatenate([residual[..., 0], residual[..., 1]], axis=1)[..., None]  # (n, 2C, 1)
        transposed = jacobian.transpose(0, 2, 1)
        hessian = transposed @ jacobian
        gradient = (transposed @ residual)[:, :, 0]
        diagonal = np.einsum("nii->ni", hessian)
        damped = hessian + (damping[active, None] * diagonal + 1e-30)[:, :, None] * np.eye(3)
        ok = np.isfinite(damped).all(axis=(1, 2)) & np.isfinite(gradient).all(axis=1)
        step = np.zeros_like(x)
        step[ok] = np.linalg.solve(damped[ok], -gradient[ok][:, :, None])[:, :, 0]
        trial = cost(x + step, active)
        better = ok & (trial < current[active])
        moved = active[better]
        points[moved] += step[better]
        current[moved] = trial[better]
        damping[active] = np.where(better, np.maximum(damping[active] * 0.1, 1e-12),
                                   np.minimum(damping[active] * 10.0, 1e12))
        active = active[ok & (damping[active] < 1e12) & (np.abs(step).max(axis=1) > _STEP_TOLERANCE)]
    return points


def _fit(rig: _Rig, normalised: np.ndarray, pixels: np.ndarray, views: np.ndarray, iterations: int) -> np.ndarray:
    return refine_points(rig, dlt(rig.Rt, normalised, views.astype(np.float64)), pixels, views, iterations)


def _ransac(rig: _Rig, normalised: np.ndarray, pixels: np.ndarray, observed: np.ndarray,
            config: TriangulationConfig, rng: np.random.Generator) -> np.ndarray:
    """Best inlier views (S, C) of suspect points from two-view hypotheses (module docstring)."""
    c = observed.shape[1]
    pairs = np.array(list(combinations(range(c), 2)), dtype=np.int64)  # (H, 2)
    both = observed[:, pairs[:, 0]] & observed[:, pairs[:, 1]]  # (S, H)
    if len(pairs) > config.max_hypotheses:  # pairs both views observed first, in random order
        chosen = np.argsort(rng.random(both.shape) - both, axis=1)[:, :config.max_hypotheses]
    else:
        chosen = np.broadcast_to(np.arange(len(pairs)), both.shape)
    rows = np.arange(len(observed))[:, None]
    valid = both[rows, chosen]  # (S, Hm)
    views = pairs[chosen]  # (S, Hm, 2)
    hypotheses = dlt(rig.Rt[views], normalised[rows[:, :, None], views], np.ones(views.shape))  # (S, Hm, 3)
    with np.errstate(invalid="ignore"):
        error = rig.errors(hypotheses, pixels[:, None])  # (S, Hm, C)
        inside = observed[:, None] & (error <= config.threshold_px)
    truncated = np.where(observed[:, None], np.minimum(np.nan_to_num(error, nan=np.inf), config.threshold_px), 0.0)
    score = inside.sum(axis=2) - (truncated**2).sum(axis=2) / (config.threshold_px**2 * (c + 1))
    score = np.where(valid & np.isfinite(hypotheses).all(axis=2), score, -np.inf)
    best = score.argmax(axis=1)
    return inside[np.arange(len(observed)), best] & np.isfinite(score[np.arange(len(observed)), best])[:, None]


def triangulate_points(cameras: Sequence[Camera], pixels: np.ndarray, observed: np.ndarray,
                       config: TriangulationConfig = TriangulationConfig(),
                       confidence: np.ndarray | None = None) -> Triangulation:
    """Triangulate N points seen by C pinhole cameras (module docstring).

    pixels (N, C, 2): observations in each camera's pinhole (undistorted) image, continuous pixels;
    observed (N, C) bool; confidence (N, C) detection confidences in [0, 1] (default 1).  Lens
    distortion of `cameras` is ignored: undistort observations first (`undistort_pixels`)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    observed = np.asarray(observed, dtype=bool)
    c = len(cameras)
    if pixels.ndim != 3 or pixels.shape[1:] != (c, 2) or observed.shape != pixels.shape[:2]:
        raise ValueError(f"triangulate_points: pixels must be (N, {c}, 2) and observed (N, {c}), got "
                         f"{pixels.shape} and {observed.shape}")
    observed = observed & np.isfinite(pixels).all(axis=2)
    confidence = np.ones(observed.shape) if confidence is None else np.asarray(confidence, dtype=np.float64)
    if confidence.shape != observed.shape:
        raise ValueError(f"triangulate_points: confidence must be (N, {c}) like observed, got {confidence.shape}")
    rig = _Rig.of(cameras)
    rng = np.random.default_rng(config.seed)
    parts = []
    for start in range(0, len(pixels), _BATCH):
        part = slice(start, start + _BATCH)
        xyz, inliers = _solve_batch(rig, pixels[part], observed[part], config, rng)
        parts.append(_summarise(rig, xyz, inliers, pixels[part], confidence[part], config))
    if not parts:
        return _summarise(rig, np.zeros((0, 3)), np.zeros((0, c), bool), pixels, confidence, config)
    return Triangulation(**{name: np.concatenate([getattr(p, name) for p in parts])
                            for name in ("xyz", "inliers", "reprojection_px", "angle_deg", "confidence", "valid")})


def _solve_batch(rig: _Rig, pixels: np.ndarray, observed: np.ndarray, config: TriangulationConfig,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) (NaN where unsolved) and inlier views (N, C) of one batch (module docstring)."""
    enough = observed.sum(axis=1) >= config.min_views
    pixels, seen = pixels[enough], observed[enough]
    normalised = rig.normalised(np.where(seen[..., None], pixels, 0.0))
    points = _fit(rig, normalised, pixels, seen, config.iterations)
    with np.errstate(invalid="ignore"):
        inliers = seen & (rig.errors(points, pixels) <= config.threshold_px)
    suspect = np.flatnonzero((inliers != seen).any(axis=1) | ~np.isfinite(points).all(axis=1))
    if len(suspect):
        chosen = _ransac(rig, normalised[suspect], pixels[suspect], seen[suspect], config, rng)
        for _ in range(3):  # refit on the inliers until they settle
            fitted = np.full((len(suspect), 3), np.nan)
            usable = chosen.sum(axis=1) >= config.min_views
            fitted[usable] = _fit(rig, normalised[suspect][usable], pixels[suspect][usable], chosen[usable],
                                  config.iterations)
            with np.errstate(invalid="ignore"):
                settled = seen[suspect] & (rig.errors(fitted, pixels[suspect]) <= config.threshold_px)
            stable = (settled == chosen).all()
            chosen = settled
            if stable:
                break
        points[suspect], inliers[suspect] = fitted, chosen
    xyz = np.full((len(enough), 3), np.nan)
    views = np.zeros(observed.shape, dtype=bool)
    xyz[enough], views[enough] = points, inliers
    return xyz, views


def _summarise(rig: _Rig, xyz: np.ndarray, inliers: np.ndarray, pixels: np.ndarray, confidence: np.ndarray,
               config: TriangulationConfig) -> Triangulation:
    count = inliers.sum(axis=1)
    with np.errstate(invalid="ignore"):
        error = np.where(inliers, rig.errors(xyz, pixels), 0.0)
        rms = np.sqrt((error**2).sum(axis=1) / np.maximum(count, 1))
    rays = xyz[:, None, :] - rig.centres  # (N, C, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        rays /= np.linalg.norm(rays, axis=2, keepdims=True)
        cosine = np.einsum("nad,nbd->nab", rays, rays)
    pair = inliers[:, :, None] & inliers[:, None, :]
    # opposite rays (180 degrees) fix a point as badly as parallel ones: sin measures both
    sine = np.sqrt(np.maximum(1.0 - np.square(np.where(pair, cosine, 1.0)), 0.0)).max(axis=(1, 2))
    angle = np.degrees(np.arcsin(np.minimum(sine, 1.0)))
    valid = (count >= config.min_views) & np.isfinite(xyz).all(axis=1) & np.isfinite(rms)
    valid &= angle >= config.min_angle_deg
    detection = np.where(inliers, confidence, 0.0).sum(axis=1) / np.maximum(count, 1)
    support = 1.0 - 0.5 ** np.maximum(count - 1, 0)
    geometry = sine
    fit = np.exp(-0.5 * (rms / config.threshold_px) ** 2)
    score = np.where(valid, np.clip(detection * support * geometry * fit, 0.0, 1.0), 0.0)
    xyz = np.where(valid[:, None], xyz, np.nan)
    return Triangulation(xyz=xyz, inliers=inliers & valid[:, None], reprojection_px=np.where(valid, rms, np.nan),
                         angle_deg=np.where(valid, angle, np.nan), confidence=score, valid=valid)


# ---- frames --------------------------------------------------------------------------------------

def triangulate_frame(crosspoints: CrosspointMap, cameras: Sequence[Camera], detections: Sequence[Detections],
                      config: TriangulationConfig = TriangulationConfig(), frame: int = -1,
                      source: str = "detector") -> CapturedPoints:
    """One frame's detections (one `Detections` per camera, in camera order) -> its captured points
    on `crosspoints`' template level; `source` names where the detections came from."""
    gathered = gather_views(crosspoints, cameras, detections, config)
    solved = triangulate_points(cameras, gathered.pixels, gathered.observed, config, gathered.confidence)
    keep = solved.valid.copy()
    triangulated = int(keep.sum())
    if config.neighbours is not None:
        rows = np.flatnonzero(keep)
        keep[rows] = consistent_points(crosspoints, gathered.flat[rows], solved.xyz[rows], config.neighbours).kept
    key = crosspoints.unflat(gathered.flat[keep])
    face, bary = crosspoints.locate(key)
    log.info("frame %d: %d crosspoints observed, %d in >= %d views, %d triangulated, %d of them dropped by the "
             "neighbour check", frame, len(gathered.flat),
             int((gathered.observed.sum(axis=1) >= config.min_views).sum()), config.min_views, triangulated,
             triangulated - int(keep.sum()))
    return CapturedPoints(level_mm=crosspoints.level_mm, key=key, xyz=solved.xyz[keep], face=face, bary=bary,
                          views=solved.inliers[keep], reprojection_px=solved.reprojection_px[keep],
                          confidence=solved.confidence[keep], frame=frame, source=source)


def triangulate_sequence(crosspoints: CrosspointMap, cameras: Sequence[Camera],
                         detections: Mapping[int, Sequence[Detections]],
                         config: TriangulationConfig = TriangulationConfig(), source: str = "detector",
                         progress: bool = True) -> list[CapturedPoints]:
    """Frame number -> every camera's detections  =>  captured points per frame, in frame order."""
    return [triangulate_frame(crosspoints, cameras, detections[frame], config, frame, source)
            for frame in tqdm(sorted(detections), desc="triangulate", unit="frame", disable=not progress)]
