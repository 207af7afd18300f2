"""Calibrate a camera rig from ChArUco board images: intrinsics per camera, then extrinsics through
the board views that cameras share.

Images: one folder per camera under one root (``root/<camera name>/<frame>.png``); images with the
same file name (stem) in several folders show the board at the same instant.  The board is an
OpenCV ChArUco board (`CharucoBoard`, e.g. ``9x7,0.05,0.037,DICT_4X4_50``).

Steps (`calibrate_rig`):

1. Detection: `cv2.aruco.CharucoDetector` finds the board's inner corners in each image; views with
   fewer than `RigCalibrationConfig.min_corners` corners are dropped.
2. Intrinsics: `cv2.calibrateCamera` per camera over its views (OpenCV's k1, k2, p1, p2, and k3 when
   asked), which also gives the board's pose in each view.
3. Extrinsics: cameras are joined where they saw the board at the same instant.  Each pair's relative
   pose is the rotation average (chordal mean) and translation median of its shared views; a
   maximum spanning tree over the number of shared views chains every camera to the reference
   camera, whose frame is the world (``R = I, t = 0``) unless a board view defines it
   (`RigCalibrationConfig.origin_frame`: the board on the floor, Z up).  A camera sharing no view is
   an error.
4. Refinement (optional, on by default): bundle adjustment of every camera's pose and intrinsics
   (fx, fy, cx, cy and the distortion) together with every board pose, on the detected pixels (scipy
   ``least_squares``, sparse Jacobian, Huber loss at 1 px): board poses seen by several cameras tie
   their focal lengths to the rig's geometry, which one camera's views leave loose.

Each camera's reprojection error (RMS, pixels) is reported twice: its intrinsic calibration's, and
the rig's (board poses shared by all cameras that saw them).  Returned cameras follow this project's
convention (pixel centres at +0.5, metres: the board's square length sets the scale).
"""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from assets.cameras import Camera
from reconstruction.views import IMAGE_SUFFIXES

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board: `squares_x` x `squares_y` chessboard squares of `square_m` metres, ArUco
    markers of `marker_m` metres from OpenCV's predefined `dictionary`; `legacy` for boards made
    with OpenCV before 4.6 with an even number of rows (their first square is white)."""

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"
    legacy: bool = False

    def __post_init__(self) -> None:
        if not (self.squares_x >= 2 and self.squares_y >= 2):
            raise ValueError(f"ChArUco board: needs at least 2 x 2 squares, got {self.squares_x} x {self.squares_y}")
        if not 0 < self.marker_m < self.square_m:
            raise ValueError(f"ChArUco board: the marker ({self.marker_m} m) must be smaller than the square "
                             f"({self.square_m} m) and positive")
        if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"ChArUco board: unknown ArUco dictionary {self.dictionary!r} (OpenCV's names, "
                             "e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250)")
        needed = self.squares_x * self.squares_y // 2
        available = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
        if needed > available:
            raise ValueError(f"ChArUco board: {self.squares_x} x {self.squares_y} squares need {needed} markers; "
                             f"{self.dictionary} has {available}")

    @classmethod
    def parse(cls, spec: str) -> "CharucoBoard":
        """``COLSxROWS,SQUARE_M,MARKER_M[,DICTIONARY][,legacy]``, e.g. ``9x7,0.05,0.037,DICT_4X4_50``."""
        parts = [p.strip() for p in spec.split(",")]
        legacy = parts[-1].lower() == "legacy"
        if legacy:
            parts = parts[:-1]
        try:
            cols, rows = (int(v) for v in parts[0].lower().split("x"))
            square, marker = float(parts[1]), float(parts[2])
        except (ValueError, IndexError):
            raise ValueError(f"board {spec!r}: expected COLSxROWS,SQUARE_M,MARKER_M[,DICTIONARY][,legacy], "
                             "e.g. 9x7,0.05,0.037,DICT_4X4_50") from None
        if len(parts) > 4:
            raise ValueError(f"board {spec!r}: unexpected {parts[4:]}")
        return cls(cols, rows, square, marker, parts[3] if len(parts) == 4 else cls.dictionary, legacy)

    def opencv(self) -> "cv2.aruco.CharucoBoard":
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)
        board.setLegacyPattern(self.legacy)
        return board

    @property
    def corners(self) -> np.ndarray:
        """(N, 3) float64 the inner chessboard corners in the board's frame, metres (z = 0), by corner id."""
        return np.asarray(self.opencv().getChessboardCorners(), dtype=np.float64)


@dataclass(frozen=True)
class RigCalibrationConfig:
    """min_corners: a view counts with at least this many corners; min_views: of a camera, for its
    intrinsics; k3: also estimate OpenCV's sixth-order radial coefficient (off: it overfits board
    views that do not reach the image's corners, trading principal point for distortion); refine:
    bundle-adjust poses and intrinsics after chaining; reference: the camera chained from (default:
    the one sharing most views), whose frame is the world unless `origin_frame` names the image (file
    stem) whose board defines it: the board lying printed side up, origin at its outer corner next to
    corner 0, x along its first row of corners, Z up (this project's world)."""

    min_corners: int = 8
    min_views: int = 4
    k3: bool = False
    refine: bool = True
    reference: str | None = None
    origin_frame: str | None = None


@dataclass(frozen=True)
class CameraReport:
    """A calibrated camera's numbers: views used, corners, reprojection RMS (px) of its intrinsic
    calibration and of the rig, and the camera it was chained from (None: the reference)."""

    name: str
    views: int
    corners: int
    intrinsic_rms_px: float
    rig_rms_px: float
    chained_from: str | None


def find_images(root: str | Path) -> dict[str, dict[str, Path]]:
    """camera name (sub-folder of `root`) -> {frame (file stem) -> image path}, sorted."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder of board images")
    images = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        frames = {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES}
        if frames:
            images[folder.name] = frames
    if len(images) < 1:
        raise ValueError(f"{root}: no camera folders with images (expected {root}/<camera>/<frame>.png)")
    return images


def detect_corners(board: CharucoBoard, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The board's inner corners in an (H, W) or (H, W, 3) uint8 image: (ids (n,) int, pixels (n, 2)
    float64 in OpenCV's convention, pixel centres at integers)."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.opencv()).detectBoard(gray)
    if ids is None or len(ids) == 0:
        return np.zeros(0, dtype=int), np.zeros((0, 2))
    return ids.reshape(-1).astype(int), corners.reshape(-1, 2).astype(np.float64)


def calibrate_rig(board: CharucoBoard, images: Mapping[str, Mapping[str, str | Path | np.ndarray]],
                  config: RigCalibrationConfig = RigCalibrationConfig()) -> tuple[list[Camera], list[CameraReport]]:
    """Cameras (in `images`' order) and their reports from board images: camera name -> {frame ->
    image path or (H, W[, 3]) uint8 array}.  Errors name the camera that cannot be calibrated."""
    object_points = board.corners
    detections: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    sizes: dict[str, tuple[int, int]] = {}
    for name, frames in images.items():
        detections[name] = {}
        for frame, source in frames.items():
            image = _load(source)
            size = (image.shape[1], image.shape[0])
            if sizes.setdefault(name, size) != size:
                raise ValueError(f"camera {name!r}: frame {frame!r} is {size[0]} x {size[1]} pixels, its first "
                                 f"{sizes[name][0]} x {sizes[name][1]}")
            ids, pixels = detect_corners(board, image)
            if len(ids) >= config.min_corners:
                detections[name][frame] = (ids, pixels)
        log.info("camera %s: the board in %d of %d images", name, len(detections[name]), len(frames))
        if len(detections[name]) < config.min_views:
            raise ValueError(f"camera {name!r}: the board was found (>= {config.min_corners} corners) in "
                             f"{len(detections[name])} of {len(frames)} images; at least {config.min_views} needed")

    intrinsics, board_poses, intrinsic_rms = {}, {}, {}
    for name, views in detections.items():
        frames = list(views)
        rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
            [object_points[views[f][0]].astype(np.float32) for f in frames],
            [views[f][1].astype(np.float32) for f in frames], sizes[name], None, None,
            flags=0 if config.k3 else cv2.CALIB_FIX_K3)
        intrinsics[name] = (K, dist.reshape(-1))
        intrinsic_rms[name] = float(rms)
        board_poses[name] = {f: _matrix(cv2.Rodrigues(r)[0], t.reshape(3)) for f, r, t in zip(frames, rvecs, tvecs)}

    poses, parents = _chain(board_poses, config.reference)
    names = list(images)
    observations = [(c, frame, ids, pixels) for c, name in enumerate(names)
                    for frame, (ids, pixels) in detections[name].items()]
    # each board pose in the world from the camera that saw it with the most corners
    world_boards = {}
    for frame in sorted({frame for _, frame, _, _ in observations}):
        best = names[max((o for o in observations if o[1] == frame), key=lambda o: len(o[2]))[0]]
        world_boards[frame] = np.linalg.inv(poses[best]) @ board_poses[best][frame]
    if config.refine:
        reference = next(n for n, parent in parents.items() if parent is None)
        poses, world_boards, intrinsics = _bundle_adjust(names, reference, intrinsics, poses, world_boards,
                                                         observations, object_points, config.k3)
    if config.origin_frame is not None:
        if config.origin_frame not in world_boards:
            raise ValueError(f"origin frame {config.origin_frame!r}: no camera found the board in it "
                             f"(frames with the board: {sorted(world_boards)})")
        # the board's frame has y along its columns and z into the board: Z up is its -z
        world_to_reference = world_boards[config.origin_frame] @ np.diag([1.0, -1.0, -1.0, 1.0])
        poses = {name: pose @ world_to_reference for name, pose in poses.items()}
        world_boards = {f: np.linalg.inv(world_to_reference) @ pose for f, pose in world_boards.items()}

    rig_errors: dict[str, list[np.ndarray]] = defaultdict(list)
    for c, frame, ids, pixels in observations:
        name = names[c]
        pose = poses[name] @ world_boards[frame]
        K, dist = intrinsics[name]
        projected = cv2.projectPoints(object_points[ids], cv2.Rodrigues(pose[:3, :3])[0], pose[:3, 3], K, dist)[0]
        rig_errors[name].append(np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1))
    cameras, reports = [], []
    for name in names:
        K, dist = intrinsics[name]
        K = K.copy()
        K[:2, 2] += 0.5  # OpenCV's pixel centres at integers -> ours at +0.5
        cameras.append(Camera(K=K, R=poses[name][:3, :3], t=poses[name][:3, 3], width=sizes[name][0],
                              height=sizes[name][1], dist=dist, name=name))
        errors = np.concatenate(rig_errors[name])
        reports.append(CameraReport(name, len(detections[name]), int(errors.size), intrinsic_rms[name],
                                    float(np.sqrt(np.mean(errors ** 2))), parents[name]))
    return cameras, reports


def _load(source: str | Path | np.ndarray) -> np.ndarray:
    if isinstance(source, np.ndarray):
        return source
    image = cv2.imread(str(source), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"{source}: not a readable image")
    return image


def _matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = R, t
    return matrix


def _chain(board_poses: dict[str, dict[str, np.ndarray]], reference: str | None
           ) -> tuple[dict[str, np.ndarray], dict[str, str | None]]:
    """World -> camera poses (4, 4) with the reference camera's frame as the world, chained over a
    maximum spanning tree of shared views, and each camera's parent in that tree."""
    names = list(board_poses)
    shared = {(a, b): sorted(set(board_poses[a]) & set(board_poses[b])) for a in names for b in names if a != b}
    if reference is None:
        reference = max(names, key=lambda n: sum(len(shared[(n, m)]) for m in names if m != n))
    elif reference not in board_poses:
        raise ValueError(f"reference camera {reference!r} is not among the cameras {names}")
    poses, parents = {reference: np.eye(4)}, {reference: None}
    while len(poses) < len(names):  # Prim's algorithm, the edge of most shared views first
        edges = [(len(shared[(a, b)]), a, b) for a in poses for b in names if b not in poses and shared[(a, b)]]
        if not edges:
            lonely = [n for n in names if n not in poses]
            raise ValueError(f"cameras {lonely} share no board view with cameras {sorted(poses)}: show the board to "
                             "both groups at once")
        _, a, b = max(edges)
        poses[b] = _relative(board_poses[a], board_poses[b], shared[(a, b)]) @ poses[a]
        parents[b] = a
    return poses, parents


def _relative(poses_a: dict[str, np.ndarray], poses_b: dict[str, np.ndarray], frames: list[str]) -> np.ndarray:
    """Camera a -> camera b (4, 4) from the board poses both saw: the chordal mean of the rotations
    and the median of the translations."""
    relatives = np.stack([poses_b[f] @ np.linalg.inv(poses_a[f]) for f in frames])
    u, _, vt = np.linalg.svd(relatives[:, :3, :3].sum(axis=0))
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    # t_b = R t_a + t: the median of each view's t_b - R t_a
    t = np.median(np.stack([poses_b[f][:3, 3] - R @ poses_a[f][:3, 3] for f in frames]), axis=0)
    return _matrix(R, t)


def _bundle_adjust(names: list[str], reference: str, intrinsics: dict[str, tuple[np.ndarray, np.ndarray]],
                   poses: dict[str, np.ndarray], boards: dict[str, np.ndarray], observations: list,
                   object_points: np.ndarray, k3: bool) -> tuple[dict, dict, dict]:
    """Refine every camera's pose and intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, and k3 when asked)
    and every board pose together, on the detected pixels: board poses seen by several cameras tie
    their focal lengths and poses together, which single-camera calibrations leave loose.  The
    reference camera's pose (the world) stays fixed.  Returns (poses, board poses, intrinsics)."""
    frames = list(boards)
    frame_index = {f: i for i, f in enumerate(frames)}
    # per observed corner: its camera, its board pose, its board point, its pixel (OpenCV convention)
    cam = np.concatenate([np.full(len(ids), c) for c, _, ids, _ in observations])
    view = np.concatenate([np.full(len(ids), frame_index[f]) for _, f, ids, _ in observations])
    points3 = np.concatenate([object_points[ids] for _, _, ids, _ in observations])
    observed = np.concatenate([pixels for _, _, _, pixels in observations])
    n_cams, width = len(names), 15  # per camera: rotation vector, translation, fx, fy, cx, cy, 5 coefficients

    def camera_block(name: str) -> np.ndarray:
        K, dist = intrinsics[name]
        coefficients = np.zeros(5)
        coefficients[:min(5, dist.size)] = dist[:5]
        return np.concatenate([Rotation.from_matrix(poses[name][:3, :3]).as_rotvec(), poses[name][:3, 3],
                               [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], coefficients])

    def residuals(x: np.ndarray) -> np.ndarray:
        cams = x[:width * n_cams].reshape(n_cams, width)[cam]
        board = x[width * n_cams:].reshape(-1, 6)[view]
        world = np.einsum("nij,nj->ni", Rotation.from_rotvec(board[:, :3]).as_matrix(), points3) + board[:, 3:]
        xc = np.einsum("nij,nj->ni", Rotation.from_rotvec(cams[:, :3]).as_matrix(), world) + cams[:, 3:6]
        x_, y_ = xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]
        k1, k2, p1, p2, k3_ = cams[:, 10:15].T
        r2 = x_ * x_ + y_ * y_
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3_))
        u = cams[:, 6] * (x_ * radial + 2 * p1 * x_ * y_ + p2 * (r2 + 2 * x_ * x_)) + cams[:, 8]
        v = cams[:, 7] * (y_ * radial + p1 * (r2 + 2 * y_ * y_) + 2 * p2 * x_ * y_) + cams[:, 9]
        return (np.stack([u, v], axis=1) - observed).reshape(-1)

    x0 = np.concatenate([camera_block(n) for n in names] + [
        np.concatenate([Rotation.from_matrix(boards[f][:3, :3]).as_rotvec(), boards[f][:3, 3]]) for f in frames])
    keep = np.ones(x0.size, dtype=bool)
    fixed = names.index(reference)
    keep[width * fixed:width * fixed + 6] = False  # the reference camera is the world
    if not k3:
        keep[width * np.arange(n_cams) + 14] = False
    # a corner's two residuals depend on its camera's 15 parameters and its board pose's 6
    rows = np.repeat(np.arange(2 * len(cam)), width + 6)
    columns = np.concatenate([width * np.repeat(cam, 2)[:, None] + np.arange(width),
                              width * n_cams + 6 * np.repeat(view, 2)[:, None] + np.arange(6)], axis=1)
    sparsity = coo_matrix((np.ones(rows.size, dtype=int), (rows, columns.reshape(-1))), (2 * len(cam), x0.size))

    def free(y: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[keep] = y
        return residuals(x)

    # lsmr's default tolerances stall the trust region in tiny steps; with tight ones it converges in ~10
    # steps, then creeps along the focal length - distance valley: ftol stops it there (1e-4 of the cost)
    result = least_squares(free, x0[keep], jac_sparsity=sparsity.tocsr()[:, keep], loss="huber", f_scale=1.0,
                           x_scale="jac", method="trf", tr_options={"atol": 1e-12, "btol": 1e-12}, ftol=1e-4,
                           max_nfev=200)
    log.info("bundle adjustment: cost %.4g -> %.4g (%s)", 0.5 * np.sum(residuals(x0) ** 2), result.cost,
             result.message)
    x = x0.copy()
    x[keep] = result.x
    cams, board = x[:width * n_cams].reshape(n_cams, width), x[width * n_cams:].reshape(-1, 6)
    refined_poses, refined_intrinsics = {}, {}
    for i, name in enumerate(names):
        refined_poses[name] = _matrix(Rotation.from_rotvec(cams[i, :3]).as_matrix(), cams[i, 3:6])
        fx, fy, cx, cy = cams[i, 6:10]
        refined_intrinsics[name] = (np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), cams[i, 10:15])
    return (refined_poses, {f: _matrix(Rotation.from_rotvec(board[i, :3]).as_matrix(), board[i, 3:])
                            for i, f in enumerate(frames)}, refined_intrinsics)
