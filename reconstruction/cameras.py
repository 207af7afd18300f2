"""Camera calibration files for reconstruction, their validation, and undistortion of detections.

Two formats are read (`read_cameras` picks by suffix):

* ``cameras.json`` (`assets.cameras`): ``{"cameras": [{"name", "width", "height", "K", "dist", "R",
  "t"}, ...]}``, metres and pixels, pixel centres at integer + 0.5.
* OpenCV calibration YAML / XML (`cv2.FileStorage`), one camera per file (keys at the top level,
  named after the file unless it has a ``name``) or several under a top-level sequence ``cameras``.
  Accepted keys per camera (the first present of each group is used):

    intrinsics     camera_matrix | K | cameraMatrix             3 x 3
    distortion     distortion_coefficients | D | dist | distCoeffs   4, 5, 8, 12 or 14 numbers,
                   OpenCV's model (optional: no distortion when absent)
    rotation       R | rotation_matrix (3 x 3, world -> camera; 3 numbers are read as a
                   Rodrigues vector) or rvec | rotation_vector (Rodrigues, 3 numbers)
    translation    T | t | tvec | translation_vector            3 numbers (world -> camera)
    image size     image_width and image_height, or image_size | imageSize = [width, height]
    name           name (string, optional)

  Values are OpenCV matrices (``!!opencv-matrix``) or plain sequences.  OpenCV's own calibration
  puts pixel centres at integers: such a K is shifted by +0.5 px in cx, cy (``pixel_centre=0.0``,
  the default for these files; pass 0.5 for files already in this project's convention, as
  `write_opencv` writes them).  Translations are scaled by ``translation_scale`` (0.001 for a
  calibration made with a board measured in millimetres) to metres.

Triangulation works in the pinhole model: `undistort_pixels` maps detected pixels of a distorted
camera to the pixels its `pinhole` twin (same K, R, t, no distortion) would see.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import cv2
import numpy as np

from assets.cameras import MAX_IMAGE_PIXELS, Camera, check_camera_file_fields, distortion_coefficients, load_cameras
from assets.fileio import atomic_path

_KEYS = {
    "K": ("camera_matrix", "K", "cameraMatrix"),
    "dist": ("distortion_coefficients", "D", "dist", "distCoeffs"),
    "R": ("R", "rotation_matrix"),
    "rvec": ("rvec", "rotation_vector"),
    "t": ("T", "t", "tvec", "translation_vector"),
    "size": ("image_size", "imageSize"),
}
_YAML_SUFFIXES = (".yaml", ".yml", ".xml")
#: iterations and tolerance (normalised units) of the iterative undistortion
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


def read_cameras(path: str | Path | Sequence[str | Path], translation_scale: float = 1.0,
                 pixel_centre: float = 0.0, max_image_pixels: int = MAX_IMAGE_PIXELS) -> list[Camera]:
    """Cameras from a ``cameras.json``, an OpenCV YAML / XML file, or a list of OpenCV files (one
    camera each, in that order); validated by `validate_cameras`.  `translation_scale` and
    `pixel_centre` apply to OpenCV files only (module docstring); a camera whose images would be
    larger than `max_image_pixels` is refused."""
    paths = [Path(path)] if isinstance(path, (str, Path)) else [Path(p) for p in path]
    if not paths:
        raise ValueError("read_cameras: no calibration file given")
    cameras: list[Camera] = []
    for p in paths:
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such calibration file")
        if p.suffix.lower() == ".json":
            if len(paths) > 1:
                raise ValueError(f"{p}: a cameras.json holds every camera; give it alone, not in a list of files")
            cameras = load_cameras(p, max_image_pixels)
        elif p.suffix.lower() in _YAML_SUFFIXES:
            cameras += read_opencv(p, translation_scale, pixel_centre, max_image_pixels)
        else:
            raise ValueError(f"{p}: unknown calibration format (expected .json, .yaml, .yml or .xml)")
    validate_cameras(cameras, source=", ".join(str(p) for p in paths))
    return cameras


def read_opencv(path: str | Path, translation_scale: float = 1.0, pixel_centre: float = 0.0,
                max_image_pixels: int = MAX_IMAGE_PIXELS) -> list[Camera]:
    """The camera(s) of one OpenCV calibration YAML / XML file (keys in the module docstring); names
    must be safe folder names and images at most `max_image_pixels`."""
    path = Path(path)
    if not translation_scale > 0:
        raise ValueError(f"translation_scale must be > 0, got {translation_scale}")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the parser's cv2.error may arrive wrapped in a SystemError
        cause = exc if isinstance(exc, cv2.error) else exc.__cause__ or exc.__context__ or exc
        detail = getattr(cause, "err", None) or str(cause).strip().splitlines()[-1]
        raise ValueError(f"{path}: not a readable OpenCV YAML/XML file ({detail})") from None
    if not storage.isOpened():
        raise ValueError(f"{path}: not a readable OpenCV YAML/XML file")
    try:
        root = storage.root()
        listed = root.getNode("cameras")
        if not listed.empty():
            if not listed.isSeq():
                raise ValueError(f"{path}: 'cameras' must be a sequence of camera maps")
            entries = [(listed.at(i), f"{path}: cameras[{i}]", f"cam{i:02d}") for i in range(listed.size())]
        else:
            entries = [(root, str(path), path.stem)]
        cameras = []
        for node, where, default_name in entries:
            if not node.isMap():
                raise ValueError(f"{where}: expected a map of calibration keys")
            values = {key: _value(node.getNode(key), f"{where}: {key}") for key in node.keys()}
            cameras.append(_camera(values, where, default_name, translation_scale, pixel_centre))
            check_camera_file_fields(cameras[-1], where, max_image_pixels)
        return cameras
    finally:
        storage.release()


def write_opencv(path: str | Path, cameras: Iterable[Camera], pixel_centre: float = 0.5) -> None:
    """Write `cameras` as an OpenCV YAML / XML file (by suffix) with a sequence ``cameras``, with pixel
    centres at integer + `pixel_centre`: by default this project's convention (read it back with
    ``pixel_centre=0.5``), 0.0 for OpenCV's own (what `read_opencv` assumes by default)."""
    path = Path(path)
    if path.suffix.lower() not in _YAML_SUFFIXES:
        raise ValueError(f"{path}: an OpenCV calibration file ends in .yaml, .yml or .xml")
    with atomic_path(path) as tmp:
        # FileStorage picks the format from the name's suffix
        target = tmp.with_name(tmp.name + path.suffix)
        try:
            storage = cv2.FileStorage(str(target), cv2.FILE_STORAGE_WRITE)
            storage.startWriteStruct("cameras", cv2.FileNode_SEQ)
            for camera in cameras:
                storage.startWriteStruct("", cv2.FileNode_MAP)
                storage.write("name", camera.name)
                storage.write("image_width", camera.width)
                storage.write("image_height", camera.height)
                K = camera.K.copy()
                K[:2, 2] -= 0.5 - pixel_centre
                storage.write("camera_matrix", K)
                storage.write("distortion_coefficients", camera.dist.reshape(1, -1))
                storage.write("R", camera.R)
                storage.write("T", camera.t.reshape(3, 1))
                storage.endWriteStruct()
            storage.endWriteStruct()
            storage.release()
            target.replace(tmp)
        finally:
            target.unlink(missing_ok=True)


def validate_cameras(cameras: Sequence[Camera], source: str = "cameras",
                     image_sizes: Mapping[str, tuple[int, int]] | None = None) -> None:
    """Raise ValueError naming `source` and the camera for: no cameras, a missing or duplicate name,
    a K that is singular or badly conditioned, or (with `image_sizes`: camera name -> (width,
    height) of its images) an image size that differs from the calibration's."""
    if not cameras:
        raise ValueError(f"{source}: no cameras")
    names = [c.name for c in cameras]
    if any(not n for n in names):
        raise ValueError(f"{source}: camera {names.index('')} has no name (names pick the image folders)")
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"{source}: duplicate camera names {duplicates}")
    for camera in cameras:
        if np.linalg.cond(camera.K) > 1e12:
            raise ValueError(f"{source}: camera {camera.name!r}: K is not invertible (condition number "
                             f"{np.linalg.cond(camera.K):.3g})")
    for name, size in (image_sizes or {}).items():
        if name not in names:
            raise ValueError(f"{source}: images for camera {name!r}, which is not calibrated (cameras: {names})")
        camera = cameras[names.index(name)]
        if tuple(int(v) for v in size) != (camera.width, camera.height):
            raise ValueError(f"{source}: camera {name!r} is calibrated for {camera.width} x {camera.height} pixels "
                             f"but its images are {size[0]} x {size[1]}")


def pinhole(camera: Camera) -> Camera:
    """`camera` without lens distortion (same K, R, t, size, name): the model triangulation uses."""
    if not camera.distorted:
        return camera
    return Camera(K=camera.K, R=camera.R, t=camera.t, width=camera.width, height=camera.height, name=camera.name)


def undistort_pixels(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Detected pixels (N, 2) of `camera` -> the pixels (N, 2) float64 its `pinhole` twin sees for the
    same rays (continuous coordinates both; NaN rows stay NaN).  Iterative, to 1e-14 in normalised
    coordinates, so it inverts `Camera.project` far below a pixel's thousandth for usual lenses."""
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 2 or pixels.shape[1] != 2:
        raise ValueError(f"undistort_pixels: pixels must have shape (N, 2), got {pixels.shape}")
    if not camera.distorted:
        return pixels.copy()
    out = np.full_like(pixels, np.nan)
    finite = np.isfinite(pixels).all(axis=1)
    if finite.any():
        # to normalised coordinates with K here, as OpenCV ignores K's skew on the way in; K's
        # pixel-centre convention cancels, as the same K maps pixels to rays and back
        k = camera.K
        y = (pixels[finite, 1] - k[1, 2]) / k[1, 1]
        x = (pixels[finite, 0] - k[0, 2] - k[0, 1] * y) / k[0, 0]
        ideal = cv2.undistortPointsIter(np.stack([x, y], axis=1).reshape(-1, 1, 2), np.eye(3), camera.dist, None,
                                        np.eye(3), _UNDISTORT_CRITERIA).reshape(-1, 2)
        out[finite] = ideal @ k[:2, :2].T + k[:2, 2]
    return out


# ---- OpenCV file values --------------------------------------------------------------------------

def _value(node: Any, where: str) -> Any:
    """A FileNode as a string, a float, an array (OpenCV matrix) or a list (sequence); `where` names
    it in errors."""
    if node.isString():
        return node.string()
    if node.isInt() or node.isReal():
        return node.real()
    if node.isSeq():
        return [_value(node.at(i), f"{where}[{i}]") for i in range(node.size())]
    if node.isMap():
        try:
            matrix = node.mat()
        except cv2.error as exc:  # an !!opencv-matrix whose rows x cols disagree with its data
            raise ValueError(f"{where}: not a valid OpenCV matrix ({exc.err})") from None
        return matrix if matrix is not None else {key: _value(node.getNode(key), f"{where}.{key}") for key in node.keys()}
    return None


def _numbers(value: Any, where: str, sizes: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers, got {value!r}") from None
    if array.size not in sizes:
        raise ValueError(f"{where}: expected {' or '.join(map(str, sizes))} numbers, got {array.size}")
    if not np.isfinite(array).all():
        raise ValueError(f"{where}: not finite")
    return array


def _pick(values: dict[str, Any], group: str, where: str, required: bool = True) -> tuple[str, Any] | None:
    for key in _KEYS[group]:
        if key in values:
            return key, values[key]
    if required:
        raise ValueError(f"{where}: missing {' / '.join(_KEYS[group])}")
    return None


def _camera(values: dict[str, Any], where: str, default_name: str, translation_scale: float,
            pixel_centre: float) -> Camera:
    key, K = _pick(values, "K", where)
    K = _numbers(K, f"{where}: {key}", (9,)).reshape(3, 3)
    K[:2, 2] += 0.5 - pixel_centre
    dist = np.zeros(5)
    picked = _pick(values, "dist", where, required=False)
    if picked is not None:
        key, coefficients = picked
        dist = distortion_coefficients(coefficients, f"{where}: {key}")
    rotation = _pick(values, "R", where, required=False)
    if rotation is not None:
        key, R = rotation
        R = _numbers(R, f"{where}: {key}", (9, 3))
        R = cv2.Rodrigues(R)[0] if R.size == 3 else R.reshape(3, 3)
    else:
        key, rvec = _pick(values, "rvec", where)
        R = cv2.Rodrigues(_numbers(rvec, f"{where}: {key}", (3,)))[0]
    key, t = _pick(values, "t", where)
    t = _numbers(t, f"{where}: {key}", (3,)) * translation_scale
    if "image_width" in values and "image_height" in values:
        size = _numbers([values["image_width"], values["image_height"]], f"{where}: image_width/image_height", (2,))
    else:
        key, size = _pick(values, "size", where)
        size = _numbers(size, f"{where}: {key}", (2,))
    if not (size == np.round(size)).all() or (size <= 0).any():
        raise ValueError(f"{where}: image size must be positive whole pixels, got {size.tolist()}")
    name = values.get("name", default_name)
    if not isinstance(name, str):
        raise ValueError(f"{where}: name must be a string, got {name!r}")
    try:
        return Camera(K=K, R=R, t=t, width=int(size[0]), height=int(size[1]), dist=dist, name=name)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
