"""Self-calibration from the garment: bundle adjustment of the cameras over crosspoint correspondences.

A calibration that is a little off (a camera knocked by a degree, a rig that drifted a centimetre, a
focal length read from the lens barrel) costs millimetres in every triangulated point.  The garment's
crosspoints give thousands of exact correspondences per frame, so a few frames are enough to refine
the cameras themselves before triangulation (`self_calibrate`):

1. **Points**: every crosspoint row seen by at least `min_views` cameras in the given frames (each
   frame's crosspoints are points of their own: the cloth moves) is triangulated with the given
   cameras over all its views (no RANSAC: a rig that is off by a degree puts every view tens of
   pixels away; the robust loss below takes care of the outliers).  At most `max_points` of them,
   drawn at random (seeded), take part.
2. **Adjustment** (scipy ``least_squares``, ``trf``, finite differences over the sparse Jacobian that
   the observations' structure gives, robust loss `loss` with scale `f_scale_px` pixels): the 3D
   points and every camera's rotation (axis-angle, a change of the given rotation) and centre, and
   with `focal` its focal length (fx and fy by one factor), with `distortion` its k1 and k2, minimise
   the reprojection errors in the detected (distorted) pixels.  The gauge is held by the reference
   camera's pose and the distance from it to the camera farthest from it (that camera's centre moves
   on a sphere around the reference's).  Observations still over `outlier_px` after the first round
   are dropped and the adjustment is run again.
3. **World frame** (`keep`): "rig", the default, maps the refined rig onto the given one by the
   similarity transform that best fits the camera centres (least squares), so that the world frame
   and scale stay the given calibration's on average rather than one camera's; "reference" keeps the
   reference camera's pose and its distance to the farthest camera exactly (use it when that camera
   is trusted, e.g. it defines the floor).

Observations are detected pixels (continuous, pixel centres at +0.5), in each camera's own distorted
image; projection follows OpenCV's model with all of a camera's coefficients (`cv2.projectPoints`).
C cameras, N crosspoint rows, M observations.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, replace
from typing import Mapping, Sequence

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from assets.cameras import Camera
from networks.detections import Detections
from reconstruction.cameras import pinhole, undistort_pixels
from reconstruction.correspondence import CrosspointMap
from reconstruction.triangulation import TriangulationConfig, gather_views, triangulate_points

log = logging.getLogger(__name__)

LOSSES = ("huber", "soft_l1", "cauchy", "linear")
KEEPS = ("rig", "reference")


@dataclass(frozen=True)
class SelfCalibrationConfig:
    """Self-calibration settings (module docstring).

    focal: also refine each camera's focal length (fx, fy by one factor; cx, cy stay).
    distortion: also refine each camera's k1 and k2 (its other coefficients stay).
    reference: the camera (name) whose pose holds the gauge; None: the first.
    keep: "rig" (the refined rig fitted onto the given camera centres by a similarity transform) or
        "reference" (the reference camera's pose and one distance kept exactly).
    loss, f_scale_px: ``least_squares``' robust loss and its scale, pixels.
    outlier_px: observations farther than this (pixels) after the first round are dropped.
    min_views: cameras a crosspoint row needs to take part.
    min_points: fewest points the adjustment accepts; min_observations: fewest observations a camera
        needs to be refined.
    max_points: points taken at most (drawn with `seed`); max_nfev: function evaluations per round."""

    focal: bool = False
    distortion: bool = False
    reference: str | None = None
    keep: str = "rig"
    loss: str = "soft_l1"
    f_scale_px: float = 1.0
    outlier_px: float = 8.0
    min_views: int = 2
    min_points: int = 20
    min_observations: int = 20
    max_points: int = 20000
    max_nfev: int = 100
    seed: int = 0

    def __post_init__(self) -> None:
        if self.loss not in LOSSES:
            raise ValueError(f"SelfCalibrationConfig.loss must be one of {LOSSES}, got {self.loss!r}")
        if self.keep not in KEEPS:
            raise ValueError(f"SelfCalibrationConfig.keep must be one of {KEEPS}, got {self.keep!r}")
        for name in ("f_scale_px", "outlier_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SelfCalibrationConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.min_views < 2:
            raise ValueError(f"SelfCalibrationConfig.min_views must be >= 2, got {self.min_views}")
        for name in ("min_points", "min_observations", "max_points", "max_nfev"):
            if getattr(self, name) < 1:
                raise ValueError(f"SelfCalibrationConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.max_points < self.min_points:
            raise ValueError(f"SelfCalibrationConfig.max_points ({self.max_points}) must be >= min_points "
                             f"({self.min_points})")


@dataclass(frozen=True)
class CameraChange:
    """One camera's self-calibration: its observations, its RMS reprojection error (pixels) with the
    given and the refined cameras, and how far it moved (rotation degrees, centre millimetres, focal
    length percent, k1 and k2 changes)."""

    name: str
    observations: int
    rms_before_px: float
    rms_after_px: float
    rotation_deg: float
    centre_mm: float
    focal_pct: float
    k1_change: float
    k2_change: float


@dataclass(frozen=True)
class SelfCalibrationReport:
    """What a self-calibration did: points and observations used (after the outliers were dropped),
    RMS reprojection error (pixels) over them before (given cameras, points triangulated with them)
    and after, per camera, the outliers dropped, function evaluations, seconds and the solver's
    message."""

    points: int
    observations: int
    outliers: int
    rms_before_px: float
    rms_after_px: float
    cameras: tuple[CameraChange, ...]
    evaluations: int
    seconds: float
    message: str

    def to_dict(self) -> dict:
        return asdict(self)

    def table(self) -> str:
        """A text table, one camera a row, then the rig."""
        lines = [f"{'camera':<16} {'obs':>7} {'RMS before px':>13} {'RMS after px':>12} {'rot deg':>8} "
                 f"{'centre mm':>9} {'focal %':>8}"]
        lines += [f"{c.name:<16} {c.observations:>7} {c.rms_before_px:>13.3f} {c.rms_after_px:>12.3f} "
                  f"{c.rotation_deg:>8.3f} {c.centre_mm:>9.2f} {c.focal_pct:>8.3f}" for c in self.cameras]
        lines.append(f"{'all':<16} {self.observations:>7} {self.rms_before_px:>13.3f} {self.rms_after_px:>12.3f}"
                     f"   ({self.points} points, {self.outliers} outlier observations dropped, "
                     f"{self.evaluations} evaluations, {self.seconds:.1f} s)")
        return "\n".join(lines)


# ---- observations --------------------------------------------------------------------------------

def detection_pixels(crosspoints: CrosspointMap, cameras: Sequence[Camera], detections: Sequence[Detections],
                     duplicate_px: float = TriangulationConfig().duplicate_tolerance_px) -> np.ndarray:
    """One frame's detections (one `Detections` per camera, in camera order) -> pixels (N, C, 2) of
    the N crosspoints any camera saw, as detected (distorted), NaN where a camera did not see one; a
    crosspoint seen twice in one view is merged as triangulation merges it."""
    gathered = gather_views(crosspoints, [pinhole(c) for c in cameras], detections,
                            TriangulationConfig(duplicate_px=duplicate_px))
    return gathered.pixels


def self_calibrate_detections(crosspoints: CrosspointMap, cameras: Sequence[Camera],
                              detections: Mapping[int, Sequence[Detections]],
                              config: SelfCalibrationConfig = SelfCalibrationConfig()
                              ) -> tuple[list[Camera], SelfCalibrationReport]:
    """Frame number -> every camera's detections (a few frames)  =>  `self_calibrate` over them."""
    if not detections:
        raise ValueError("self-calibration needs the detections of at least one frame")
    pixels = [detection_pixels(crosspoints, cameras, detections[f]) for f in sorted(detections)]
    return self_calibrate(cameras, pixels, config, frames=sorted(detections))


# ---- the adjustment ------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class _Problem:
    """The adjustment's fixed data: observations sorted by camera, `start` (C + 1,) their slices;
    point (M,) rows into the points, pixels (M, 2); the given cameras; the gauge's reference and
    scale cameras, the scale distance; which intrinsics are free."""

    cameras: tuple[Camera, ...]
    point: np.ndarray
    pixels: np.ndarray
    start: np.ndarray
    reference: int
    scale_camera: int
    distance: float
    focal: bool
    distortion: bool

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    def block(self, c: int) -> int:
        """Parameters of camera c: its pose's (0 for the reference, 5 for the scale camera, else 6),
        then 1 with focal, then 2 with distortion."""
        pose = 0 if c == self.reference else 5 if c == self.scale_camera else 6
        return pose + int(self.focal) + 2 * int(self.distortion)

    @property
    def offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([self.block(c) for c in range(self.num_cameras)])])

    def sphere_basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scale camera's direction u from the reference camera and two unit vectors normal to it."""
        u = self.cameras[self.scale_camera].center - self.cameras[self.reference].center
        u = u / np.linalg.norm(u)
        e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        return u, e1, np.cross(u, e1)

    def unpack(self, x: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Parameters -> each camera's (R, t, K, dist) (the points are the parameters after the cameras')."""
        offsets, out = self.offsets, []
        u, e1, e2 = self.sphere_basis()
        for c, given in enumerate(self.cameras):
            p = x[offsets[c]:offsets[c + 1]]
            R, centre = given.R, given.center
            if c == self.scale_camera:
                R = Rotation.from_rotvec(p[:3]).as_matrix() @ R
                direction = u + p[3] * e1 + p[4] * e2
                centre = self.cameras[self.reference].center + self.distance * direction / np.linalg.norm(direction)
                p = p[5:]
            elif c != self.reference:
                R = Rotation.from_rotvec(p[:3]).as_matrix() @ R
                centre = centre + p[3:6]
                p = p[6:]
            K, dist = given.K.copy(), given.dist.copy()
            if self.focal:  # a log factor: the focal length stays positive whatever the step
                K[0, :2] *= np.exp(p[0])  # fx and the skew with it
                K[1, 1] *= np.exp(p[0])
                p = p[1:]
            if self.distortion:
                dist[:2] += p[:2]
            out.append((R, -R @ centre, K, dist))
        return out

    def refined(self, x: np.ndarray) -> list[Camera]:
        """The cameras of parameters x."""
        return [Camera(K=K, R=_orthonormal(R), t=t, width=given.width, height=given.height, dist=dist, name=given.name)
                for given, (R, t, K, dist) in zip(self.cameras, self.unpack(x))]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(2M,) reprojection residuals, pixels, of parameters x."""
        points = x[self.offsets[-1]:].reshape(-1, 3)
        projected = np.empty_like(self.pixels)
        for c, (R, t, K, dist) in enumerate(self.unpack(x)):
            rows = slice(self.start[c], self.start[c + 1])
            projected[rows] = _project(R, t, K, dist, points[self.point[rows]])
        return (projected - self.pixels).reshape(-1)

    def sparsity(self, num_points: int) -> coo_matrix:
        """Which parameters each residual depends on: its camera's block and its point's three."""
        offsets = self.offsets
        camera = np.repeat(np.arange(self.num_cameras), np.diff(self.start))
        widths = np.diff(offsets)[camera]
        span = np.arange(max(int(widths.max()) if len(widths) else 0, 1))
        inside = np.repeat(span[None] < widths[:, None], 2, axis=0)  # (2M, W): one row per residual
        cols_cam = np.repeat(offsets[camera][:, None] + span, 2, axis=0)[inside]
        rows_cam = np.broadcast_to(np.arange(2 * len(camera))[:, None], inside.shape)[inside]
        rows_pt = np.repeat(np.arange(2 * len(camera)), 3)
        cols_pt = (offsets[-1] + 3 * np.repeat(self.point, 2)[:, None] + np.arange(3)).reshape(-1)
        rows, cols = np.concatenate([rows_cam, rows_pt]), np.concatenate([cols_cam, cols_pt])
        return coo_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)),
                          (2 * len(camera), offsets[-1] + 3 * num_points))


def _orthonormal(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def project(camera: Camera, points: np.ndarray) -> np.ndarray:
    """World points (n, 3) -> detected pixels (n, 2) of `camera` with its distortion (`cv2.projectPoints`,
    whose numbers do not depend on the pixel-centre convention)."""
    return _project(camera.R, camera.t, camera.K, camera.dist, points)


def _project(R: np.ndarray, t: np.ndarray, K: np.ndarray, dist: np.ndarray, points: np.ndarray) -> np.ndarray:
    if not len(points):
        return np.zeros((0, 2))
    return cv2.projectPoints(np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 1, 3), cv2.Rodrigues(R)[0],
                             np.asarray(t, dtype=np.float64), K, dist)[0].reshape(-1, 2)


def self_calibrate(cameras: Sequence[Camera], pixels: Sequence[np.ndarray],
                   config: SelfCalibrationConfig = SelfCalibrationConfig(),
                   frames: Sequence[int] | None = None) -> tuple[list[Camera], SelfCalibrationReport]:
    """Refine `cameras` (module docstring) from observations of a few frames: pixels, one (N_f, C, 2)
    array per frame, each row one crosspoint in every camera's detected (distorted) image, NaN where
    a camera did not see it.  `frames` names the frames in errors.  Returns the refined cameras (same
    names, sizes and order) and the report.  ValueError, naming the camera, when a camera observes
    fewer than `config.min_observations` of the usable crosspoints, or naming the frames when fewer
    than `config.min_points` points are usable."""
    started = time.perf_counter()
    cameras = tuple(cameras)
    c = len(cameras)
    if c < 2:
        raise ValueError(f"self-calibration needs at least two cameras, got {c}")
    frames = list(range(len(pixels))) if frames is None else list(frames)
    stacked = []
    for frame, array in zip(frames, pixels):
        array = np.asarray(array, dtype=np.float64)
        if array.ndim != 3 or array.shape[1:] != (c, 2):
            raise ValueError(f"self-calibration: frame {frame}'s pixels must be (N, {c}, 2), got {array.shape}")
        stacked.append(array)
    if not stacked:
        raise ValueError("self-calibration needs the observations of at least one frame")
    where = f"frames {frames}"
    observed_pixels = np.concatenate(stacked)
    observed = np.isfinite(observed_pixels).all(axis=2)
    rows = np.flatnonzero(observed.sum(axis=1) >= config.min_views)
    _check_coverage(cameras, observed[rows], config, where, f"seen by >= {config.min_views} cameras")
    rng = np.random.default_rng(config.seed)
    if len(rows) > config.max_points:
        rows = np.sort(rng.choice(rows, config.max_points, replace=False))
    observed_pixels, observed = observed_pixels[rows], observed[rows]

    reference = _reference(cameras, config.reference)
    centres = np.stack([cam.center for cam in cameras])
    distances = np.linalg.norm(centres - centres[reference], axis=1)
    scale_camera = int(np.argmax(distances))
    if not distances[scale_camera] > 0:
        raise ValueError("self-calibration: every camera has the same centre; the rig's scale is undefined")

    # the start: points triangulated with the given cameras over all their views
    undistorted = np.stack([undistort_pixels(cam, observed_pixels[:, i]) for i, cam in enumerate(cameras)], axis=1)
    solved = triangulate_points([pinhole(cam) for cam in cameras], undistorted, observed,
                                TriangulationConfig(threshold_px=np.inf, min_views=config.min_views, neighbours=None))
    keep = solved.valid
    points0, observed, observed_pixels = solved.xyz[keep], observed[keep], observed_pixels[keep]
    _check_coverage(cameras, observed, config, where, "triangulated")

    def problem_of(seen: np.ndarray) -> _Problem:
        point, camera = np.nonzero(seen)
        order = np.argsort(camera, kind="stable")
        point, camera = point[order], camera[order]
        start = np.searchsorted(camera, np.arange(c + 1))
        return _Problem(cameras=cameras, point=point, pixels=observed_pixels[point, camera], start=start,
                        reference=reference, scale_camera=scale_camera, distance=float(distances[scale_camera]),
                        focal=config.focal, distortion=config.distortion)

    problem = problem_of(observed)
    x0 = np.concatenate([np.zeros(problem.offsets[-1]), points0.reshape(-1)])
    before = _errors(problem, x0)
    # a first round with the loss scaled to the start's typical error: with a rig that is tens of pixels
    # off, a 1 px scale makes every observation an "outlier" and the trust region crawls
    coarse = replace(config, f_scale_px=max(config.f_scale_px, float(np.median(before))))
    x, evaluations, _ = _adjust(problem, x0, len(points0), coarse)
    x, more, message = _adjust(problem, x, len(points0), config)
    evaluations += more
    # then drop the observations it could not explain, and the points left with too few views
    error = _errors(problem, x)
    seen = observed.copy()
    seen[problem.point, np.repeat(np.arange(c), np.diff(problem.start))] = error <= config.outlier_px
    usable = seen.sum(axis=1) >= config.min_views
    outliers = int(observed[usable].sum() - seen[usable].sum() + observed[~usable].sum())
    if outliers:
        _check_coverage(cameras, seen[usable], config, where, f"within {config.outlier_px} px after the first rounds")
        points = x[problem.offsets[-1]:].reshape(-1, 3)[usable]
        observed_pixels = observed_pixels[usable]
        problem = problem_of(seen[usable])
        before = _errors(problem, np.concatenate([np.zeros(problem.offsets[-1]), points0[usable].reshape(-1)]))
        x, more, message = _adjust(problem, np.concatenate([x[:problem.offsets[-1]], points.reshape(-1)]),
                                   len(points), config)
        evaluations += more
    after = _errors(problem, x)
    refined = problem.refined(x)
    if config.keep == "rig":
        refined = _fit_onto(refined, cameras)
    camera_of = np.repeat(np.arange(c), np.diff(problem.start))
    changes = tuple(_change(given, new, before[camera_of == i], after[camera_of == i])
                    for i, (given, new) in enumerate(zip(cameras, refined)))
    report = SelfCalibrationReport(points=len(x[problem.offsets[-1]:]) // 3,
                                   observations=len(problem.point), outliers=outliers,
                                   rms_before_px=_rms(before), rms_after_px=_rms(after), cameras=changes,
                                   evaluations=evaluations, seconds=time.perf_counter() - started, message=message)
    log.info("self-calibration over %s: RMS %.3f -> %.3f px (%d points, %d observations)", where,
             report.rms_before_px, report.rms_after_px, report.points, report.observations)
    return refined, report


def _reference(cameras: Sequence[Camera], name: str | None) -> int:
    if name is None:
        return 0
    names = [cam.name for cam in cameras]
    if name not in names:
        raise ValueError(f"self-calibration: reference camera {name!r} is not one of the cameras {names}")
    return names.index(name)


def _check_coverage(cameras: Sequence[Camera], seen: np.ndarray, config: SelfCalibrationConfig, where: str,
                    what: str) -> None:
    """Refuse observations (N, C) bool with too few points, or with a camera observing too few of them."""
    counts = seen.sum(axis=0)
    starved = [f"{cam.name!r} ({int(n)})" for cam, n in zip(cameras, counts) if n < config.min_observations]
    if starved:
        raise ValueError(f"self-calibration over {where}: camera(s) {', '.join(starved)} observe fewer than "
                         f"{config.min_observations} of the crosspoints {what}: they cannot be refined from these "
                         "frames (choose frames where they see the garment, or leave them out)")
    if len(seen) < config.min_points:
        raise ValueError(f"self-calibration over {where}: {len(seen)} crosspoints {what}, fewer than the "
                         f"{config.min_points} needed")


def _adjust(problem: _Problem, x0: np.ndarray, num_points: int, config: SelfCalibrationConfig
            ) -> tuple[np.ndarray, int, str]:
    """One ``least_squares`` round from x0: (parameters, evaluations, message)."""
    result = least_squares(problem.residuals, x0, jac_sparsity=problem.sparsity(num_points), method="trf",
                           loss=config.loss, f_scale=config.f_scale_px, x_scale="jac", max_nfev=config.max_nfev,
                           tr_solver="lsmr", tr_options={"atol": 1e-10, "btol": 1e-10}, ftol=1e-10, xtol=1e-10)
    return result.x, int(result.nfev), str(result.message)


def _errors(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """(M,) reprojection error of each observation, pixels."""
    return np.linalg.norm(problem.residuals(x).reshape(-1, 2), axis=1)


def _rms(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(errors)))) if len(errors) else float("nan")


def similarity_fit(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity transform X -> s Q X + d that best maps points `source` (n, 3) onto `target`
    (n, 3) in least squares (Umeyama): (scale s, rotation Q (3, 3), shift d (3,))."""
    source, target = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    a, b = source - ms, target - mt
    u, singular, vt = np.linalg.svd(b.T @ a)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    Q = u @ sign @ vt
    s = float(np.trace(np.diag(singular) @ sign) / np.square(a).sum())
    return s, Q, mt - s * Q @ ms


def _fit_onto(refined: Sequence[Camera], given: Sequence[Camera]) -> list[Camera]:
    """`refined` moved by the `similarity_fit` of its camera centres onto `given`'s."""
    s, Q, d = similarity_fit(np.stack([cam.center for cam in refined]), np.stack([cam.center for cam in given]))
    out = []
    for cam in refined:
        R = _orthonormal(cam.R @ Q.T)
        out.append(replace(cam, R=R, t=-R @ (s * Q @ cam.center + d)))
    return out


def perturb_cameras(cameras: Sequence[Camera], rng: np.random.Generator, degrees: float = 1.0, mm: float = 10.0,
                    focal: float = 0.01) -> list[Camera]:
    """A rig that is off by a known amount (to measure self-calibration): each camera turned by
    `degrees` about its centre around a random axis, its centre moved `mm` millimetres in a random
    direction, its focal length (fx, fy) scaled by 1 + `focal` or 1 - `focal` (a random sign)."""
    out = []
    for camera in cameras:
        axis, move = rng.normal(size=3), rng.normal(size=3)
        R = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix() @ camera.R
        centre = camera.center + mm / 1000.0 * move / np.linalg.norm(move)
        K = camera.K.copy()
        K[[0, 1], [0, 1]] *= 1.0 + focal * rng.choice([-1.0, 1.0])
        out.append(replace(camera, K=K, R=_orthonormal(R), t=-_orthonormal(R) @ centre))
    return out


def _change(given: Camera, refined: Camera, before: np.ndarray, after: np.ndarray) -> CameraChange:
    relative = refined.R @ given.R.T
    angle = float(np.degrees(np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0))))
    k_given, k_refined = np.zeros(2), np.zeros(2)
    k_given[:min(2, given.dist.size)] = given.dist[:2]
    k_refined[:min(2, refined.dist.size)] = refined.dist[:2]
    return CameraChange(name=given.name, observations=len(before), rms_before_px=_rms(before),
                        rms_after_px=_rms(after), rotation_deg=angle,
                        centre_mm=float(np.linalg.norm(refined.center - given.center) * 1000.0),
                        focal_pct=float((refined.K[0, 0] / given.K[0, 0] - 1.0) * 100.0),
                        k1_change=float(k_refined[0] - k_given[0]), k2_change=float(k_refined[1] - k_given[1]))
