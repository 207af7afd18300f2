"""Cameras: the one place for intrinsics, extrinsics, projection, files and Blender's numbers.

Convention (DESIGN.md): OpenCV camera frame, x right, y down, z forward.  A world point X (metres)
goes to the camera frame as ``Xc = R X + t`` (R world -> camera), then to continuous pixel
coordinates ``(u, v) = K (x', y', 1)`` with ``(x', y')`` the distorted normalised coordinates of
``(Xc.x / Xc.z, Xc.y / Xc.z)`` (OpenCV's model: its 5 coefficients k1, k2, p1, p2, k3, or 8 with the
rational k4, k5, k6, 12 with the thin prism s1..s4, or 14 with the sensor tilt tauX, tauY).  Pixel (row r, col c) covers
[c, c + 1] x [r, r + 1], so its centre is at (c + 0.5, r + 0.5) and an undistorted camera whose
principal point is the middle of a W x H image has cx = W / 2, cy = H / 2.  OpenCV's own image
functions put pixel centres at integers: subtract 0.5 from cx and cy before handing K to them
(projection-only functions such as `cv2.projectPoints` give the same numbers either way).
`depth` is always the camera-frame z, i.e. the distance along the view axis, as in Blender's Z pass.

Blender (no bpy needed here, `blender_params` / `Camera.from_blender`)::

    matrix_world = [[R^T diag(1, -1, -1), C], [0, 0, 0, 1]]    C = -R^T t, the camera centre
        Blender cameras look down their local -Z with local +Y up, so Blender's local axes are
        OpenCV's (x, -y, -z).
    sensor_fit = 'HORIZONTAL':  fx = fy = lens_mm / sensor_width_mm * W
    cx = W / 2 - shift_x * W      (shift_x > 0 moves the view right: the principal point moves left)
    cy = H / 2 + shift_y * W      (shift_y > 0 moves the view up; OpenCV's y points down)
        With HORIZONTAL fit Blender measures both shifts in units of the image width.

Blender renders square pixels with no skew and no lens distortion, so only such cameras convert.

`cameras.json` holds ``{"cameras": [camera.to_dict(), ...]}``; each camera is
``{"name", "width", "height", "K" (3x3), "dist" (5, 8, 12 or 14), "R" (3x3), "t" (3)}`` in metres and
pixels.  A camera keeps the shortest of OpenCV's coefficient counts that holds its non-zero ones (a
14-coefficient dist of a plain radial lens is stored as 5), so equal lenses compare equal.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

import numpy as np

from assets.fileio import check_json_object, check_limit, load_json, safe_name, save_json

#: Blender's local camera axes expressed in OpenCV's: x stays, y and z flip.
_CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])
_ROTATION_TOLERANCE = 1e-6
#: OpenCV's distortion coefficient counts (4 is read as 5 with k3 = 0)
DIST_LENGTHS = (5, 8, 12, 14)
#: the largest image (width x height) a calibration file may declare: 16 times an 8K frame
MAX_IMAGE_PIXELS = 16 * 7680 * 4320


def _frozen(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    """A read-only copy of `value` as a finite float64 array of `shape` (`_field`'s checks)."""
    array = np.array(_field(value, shape, f"Camera: {name}"))
    array.setflags(write=False)
    return array


def distortion_coefficients(value: Any, where: str) -> np.ndarray:
    """OpenCV distortion coefficients (4, 5, 8, 12 or 14 finite numbers, any nesting such as 1 x 5) as
    the shortest (5,), (8,), (12,) or (14,) float64 array that holds all non-zero ones; ValueError
    naming `where` otherwise."""
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers, got {value!r}") from None
    if array.size not in (4,) + DIST_LENGTHS:
        raise ValueError(f"{where}: expected 4, 5, 8, 12 or 14 OpenCV distortion coefficients, got {array.size}")
    if not np.isfinite(array).all():
        raise ValueError(f"{where}: not finite")
    nonzero = np.flatnonzero(array)
    used = int(nonzero[-1]) + 1 if nonzero.size else 0
    length = next(n for n in DIST_LENGTHS if n >= used)
    out = np.zeros(length)
    out[:min(length, array.size)] = array[:length]
    return out


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera with OpenCV distortion.

    K (3, 3) float64 intrinsics in pixels (continuous coordinates, pixel centres at +0.5);
    R (3, 3) float64 world -> camera rotation; t (3,) float64 metres (``Xc = R X + t``);
    width, height in pixels; dist (5,), (8,), (12,) or (14,) float64 OpenCV (k1, k2, p1, p2, k3[, k4, k5,
    k6[, s1, s2, s3, s4[, tauX, tauY]]]) (4 given are read as 5; kept at the shortest length that holds
    the non-zero ones); name for files and logs.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    name: str = ""

    def __post_init__(self) -> None:
        K = _frozen(self.K, (3, 3), "K")
        R = _frozen(self.R, (3, 3), "R")
        t = _frozen(self.t, (3,), "t")
        dist = distortion_coefficients(self.dist, f"Camera {self.name!r}: dist")
        dist.setflags(write=False)
        if not np.array_equal(K[2], [0.0, 0.0, 1.0]):
            raise ValueError(f"Camera {self.name!r}: K's last row must be (0, 0, 1), got {K[2].tolist()}")
        if not (K[0, 0] > 0 and K[1, 1] > 0) or K[1, 0] != 0 or abs(np.linalg.det(K)) < 1e-12:
            raise ValueError(f"Camera {self.name!r}: K must be upper triangular and invertible with positive "
                             f"focal lengths, got fx={K[0, 0]}, fy={K[1, 1]}, K[1, 0]={K[1, 0]}")
        if np.abs(R @ R.T - np.eye(3)).max() > _ROTATION_TOLERANCE or np.linalg.det(R) < 0:
            raise ValueError(f"Camera {self.name!r}: R must be a rotation (orthonormal, det +1), "
                             f"got det {np.linalg.det(R):.6g}")
        for key in ("width", "height"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
                raise ValueError(f"Camera {self.name!r}: {key} must be a positive integer, got {value!r}")
            object.__setattr__(self, key, int(value))
        if not isinstance(self.name, str):
            raise ValueError(f"Camera: name must be a string, got {self.name!r}")
        for key, value in (("K", K), ("R", R), ("t", t), ("dist", dist)):
            object.__setattr__(self, key, value)

    # ---- geometry ------------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, metres: ``-R^T t``."""
        return -self.R.T @ self.t

    @property
    def distorted(self) -> bool:
        return bool(np.any(self.dist != 0))

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera-frame points (N, 3)."""
        return _points(points, "points") @ self.R.T + self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) metres -> (pixels (N, 2) float64 continuous (x, y), depth (N,) camera z).

        Distortion (if any) follows `cv2.projectPoints`.  Pixels are meaningless where depth <= 0
        (inf or nan where depth is 0): test depth before using them.
        """
        xc = self.to_camera(points)
        depth = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = xc[:, :2] / depth[:, None]
        if self.distorted:
            xy = _distort(xy, self.dist)
        pixels = xy @ self.K[:2, :2].T + self.K[:2, 2]
        return pixels, depth

    def unproject(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Continuous pixels (N, 2) and camera-frame depths (N,) -> world points (N, 3).

        Only for undistorted cameras (undistortion is iterative and not needed by the pipeline)."""
        if self.distorted:
            raise ValueError(f"Camera {self.name!r}: unproject needs zero distortion, got dist={self.dist.tolist()}")
        pixels = np.asarray(pixels, dtype=np.float64)
        depth = np.asarray(depth, dtype=np.float64)
        if pixels.ndim != 2 or pixels.shape[1] != 2:
            raise ValueError(f"unproject: pixels must have shape (N, 2), got {pixels.shape}")
        if depth.shape != (len(pixels),):
            raise ValueError(f"unproject: depth must have shape ({len(pixels)},), got {depth.shape}")
        rays = np.concatenate([pixels, np.ones((len(pixels), 1))], axis=1) @ np.linalg.inv(self.K).T
        return (rays * depth[:, None] - self.t) @ self.R

    @classmethod
    def look_at(
        cls,
        eye: Sequence[float],
        target: Sequence[float],
        up: Sequence[float] = (0.0, 0.0, 1.0),
        focal_mm: float = 50.0,
        sensor_mm: float = 36.0,
        width: int = 512,
        height: int = 512,
        name: str = "",
    ) -> "Camera":
        """A camera at `eye` looking at `target` with `up` pointing up in the image.

        Focal length `focal_mm` on a sensor `sensor_mm` wide (spanning the image width), square
        pixels, principal point at the image centre (W / 2, H / 2), no distortion."""
        eye, target, up = (_frozen(v, (3,), key) for v, key in ((eye, "eye"), (target, "target"), (up, "up")))
        forward = target - eye
        if np.linalg.norm(forward) < 1e-12:
            raise ValueError(f"Camera.look_at: eye and target coincide at {eye.tolist()}")
        z = forward / np.linalg.norm(forward)
        right = np.cross(z, up)
        if np.linalg.norm(right) < 1e-9 * np.linalg.norm(up):
            raise ValueError(f"Camera.look_at: up {up.tolist()} is parallel to the view direction {z.tolist()}")
        x = right / np.linalg.norm(right)
        y = np.cross(z, x)  # image down
        if not (focal_mm > 0 and sensor_mm > 0):
            raise ValueError(f"Camera.look_at: focal_mm and sensor_mm must be > 0, got {focal_mm}, {sensor_mm}")
        f = focal_mm / sensor_mm * width
        K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
        R = np.stack([x, y, z])
        return cls(K=K, R=R, t=-R @ eye, width=width, height=height, name=name)

    # ---- Blender -------------------------------------------------------------------------------
    def blender_params(self, sensor_width_mm: float = 36.0) -> dict[str, Any]:
        """The Blender camera that renders this camera's image (see the module docstring).

        Returns matrix_world (4x4 nested lists), lens_mm, sensor_width_mm, sensor_fit ('HORIZONTAL'),
        shift_x, shift_y, resolution_x, resolution_y (render at resolution_percentage 100 and pixel
        aspect 1).  Raises ValueError for distortion, skew or non-square pixels."""
        K, w, h = self.K, self.width, self.height
        if self.distorted:
            raise ValueError(f"Camera {self.name!r}: Blender renders no lens distortion, got dist={self.dist.tolist()}")
        if abs(K[0, 1]) > 1e-9 * K[0, 0]:
            raise ValueError(f"Camera {self.name!r}: Blender cameras have no skew, got K[0, 1]={K[0, 1]}")
        if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0]:
            raise ValueError(f"Camera {self.name!r}: Blender renders square pixels here, got fx={K[0, 0]} != fy={K[1, 1]}")
        if not sensor_width_mm > 0:
            raise ValueError(f"sensor_width_mm must be > 0, got {sensor_width_mm}")
        matrix = np.eye(4)
        matrix[:3, :3] = self.R.T @ _CV_TO_BLENDER
        matrix[:3, 3] = self.center
        return {
            "matrix_world": matrix.tolist(),
            "lens_mm": float(K[0, 0] * sensor_width_mm / w),
            "sensor_width_mm": float(sensor_width_mm),
            "sensor_fit": "HORIZONTAL",
            "shift_x": float((w / 2 - K[0, 2]) / w),
            "shift_y": float((K[1, 2] - h / 2) / w),
            "resolution_x": w,
            "resolution_y": h,
        }

    @classmethod
    def from_blender(
        cls,
        matrix_world: Any,
        lens_mm: float,
        sensor_width_mm: float,
        shift_x: float,
        shift_y: float,
        width: int,
        height: int,
        name: str = "",
    ) -> "Camera":
        """The camera of a Blender camera object with sensor_fit 'HORIZONTAL' (inverse of
        `blender_params`).  matrix_world (4, 4): nested lists or a mathutils.Matrix; object scale is
        removed (Blender ignores it when rendering)."""
        m = _frozen(matrix_world, (4, 4), "matrix_world")
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError(f"Camera.from_blender: matrix_world's last row must be (0, 0, 0, 1), got {m[3].tolist()}")
        if not (lens_mm > 0 and sensor_width_mm > 0):
            raise ValueError(f"Camera.from_blender: lens_mm and sensor_width_mm must be > 0, got {lens_mm}, {sensor_width_mm}")
        axes = m[:3, :3]
        scale = np.linalg.norm(axes, axis=0)
        if not (scale > 1e-12).all():
            raise ValueError(f"Camera.from_blender: matrix_world has a zero scale {scale.tolist()}")
        rotation = axes / scale
        if np.abs(rotation.T @ rotation - np.eye(3)).max() > _ROTATION_TOLERANCE or np.linalg.det(rotation) < 0:
            raise ValueError("Camera.from_blender: matrix_world is sheared or mirrored, not a rotation and scale")
        R = (rotation @ _CV_TO_BLENDER).T
        f = lens_mm / sensor_width_mm * width
        K = np.array([[f, 0.0, width / 2 - shift_x * width], [0.0, f, height / 2 + shift_y * width], [0.0, 0.0, 1.0]])
        return cls(K=K, R=R, t=-R @ m[:3, 3], width=width, height=height, name=name)

    # ---- files ---------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "camera") -> "Camera":
        """Read `to_dict`'s output; dist and name may be left out.  Errors name `source` and the field."""
        check_json_object(data, ("name", "width", "height", "K", "dist", "R", "t"), source)
        name = data.get("name", "")
        if not isinstance(name, str):
            raise ValueError(f"{source}: field 'name' must be a string, got {name!r}")
        size = {}
        for key in ("width", "height"):
            value = data.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not float(value).is_integer() or value <= 0:
                raise ValueError(f"{source}: field '{key}' must be a positive integer, got {value!r}")
            size[key] = int(value)
        arrays = {}
        for key, shape in (("K", (3, 3)), ("R", (3, 3)), ("t", (3,))):
            if key not in data:
                raise ValueError(f"{source}: missing field '{key}'")
            arrays[key] = _field(data[key], shape, f"{source}: field '{key}'")
        arrays["dist"] = distortion_coefficients(data.get("dist", np.zeros(5)), f"{source}: field 'dist'")
        try:
            return cls(name=name, **size, **arrays)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from exc


def _field(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A JSON value as a finite float64 array of `shape`, or ValueError naming `where`."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers, got {value!r}") from None
    if array.shape != shape:
        raise ValueError(f"{where}: expected a list of shape {list(shape)}, got shape {list(array.shape)}")
    if not np.isfinite(array).all():
        raise ValueError(f"{where}: not finite")
    return array


def _points(points: np.ndarray, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {points.shape}")
    return points


def _distort(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's distortion (`cv2.projectPoints`) of normalised coordinates (N, 2) with 5, 8, 12 or 14
    coefficients (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tauX, tauY)."""
    c = np.zeros(14)
    c[:dist.size] = dist
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y = c
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (s1 + s2 * r2)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (s3 + s4 * r2)
    if tau_x or tau_y:
        # the tilted sensor: a rotation of the image plane, projected back along z (OpenCV's
        # computeTiltProjectionMatrix)
        cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
        rot_xy = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]])
        proj_z = np.array([[rot_xy[2, 2], 0, -rot_xy[0, 2]], [0, rot_xy[2, 2], -rot_xy[1, 2]], [0, 0, 1]])
        tilted = np.stack([xd, yd, np.ones_like(xd)], axis=1) @ (proj_z @ rot_xy).T
        return tilted[:, :2] / tilted[:, 2:]
    return np.stack([xd, yd], axis=1)


def save_cameras(path: str | os.PathLike, cameras: Iterable[Camera]) -> None:
    """Write ``{"cameras": [...]}`` to `path` atomically."""
    save_json(path, {"cameras": [camera.to_dict() for camera in cameras]})


def load_cameras(path: str | os.PathLike, max_image_pixels: int = MAX_IMAGE_PIXELS) -> list[Camera]:
    """Read a `cameras.json`; errors name the file, the camera and the field.  Camera names become
    folder names, so each must be one safe path component (`safe_name`); an image larger than
    `max_image_pixels` is refused."""
    data = load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), list):
        raise ValueError(f"{path}: expected an object with a list 'cameras'")
    cameras = [Camera.from_dict(entry, f"{path}: cameras[{i}]") for i, entry in enumerate(data["cameras"])]
    for i, camera in enumerate(cameras):
        check_camera_file_fields(camera, f"{path}: cameras[{i}]", max_image_pixels)
    names = [c.name for c in cameras if c.name]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: duplicate camera names {sorted({n for n in names if names.count(n) > 1})}")
    return cameras



def check_camera_file_fields(camera: Camera, source: str, max_image_pixels: int = MAX_IMAGE_PIXELS) -> None:
    """Refuse what a calibration file may not declare, naming `source` and the field: a name that is
    not one safe path component (names become folders of detections) and an image above
    `max_image_pixels` (images of that size are allocated later)."""
    if camera.name:
        safe_name(camera.name, f"{source}.name")
    check_limit(camera.width * camera.height, max_image_pixels, f"width x height ({camera.width} x {camera.height})",
                source, "max_image_pixels (--max-image-pixels of python -m reconstruction)")
