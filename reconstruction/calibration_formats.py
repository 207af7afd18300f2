"""Calibration files of other tools, read into and written from `assets.cameras.Camera`.

Formats (the name is what ``--format`` takes; `detect_format` guesses it from the path):

* ``json``: this project's ``cameras.json`` (`assets.cameras`).
* ``opencv``: one OpenCV YAML / XML file (`reconstruction.cameras.read_opencv`), in OpenCV's pixel
  convention both ways.
* ``easymocap``: EasyMocap's folder with ``intri.yml`` (``names``, ``K_<name>``, ``dist_<name>``,
  ``H_<name>``, ``W_<name>``) and ``extri.yml`` (``names``, ``R_<name>`` a Rodrigues vector,
  ``Rot_<name>`` the matrix, ``T_<name>``), OpenCV FileStorage YAML.  ``Rot_`` is preferred when
  present (exact); EasyMocap itself reads ``R_``, so both are written.
* ``toml``: anipose / aniposelib ``calibration.toml`` (tables ``[cam_0]``... with ``name``, ``size``
  = [width, height], ``matrix``, ``distortions``, ``rotation`` a Rodrigues vector, ``translation``;
  ``[metadata]``) and caliscope's ``camera_array.toml`` (tables ``[cameras.<id>]`` with ``cam_id`` or
  ``port`` instead of a name, ``rotation`` a Rodrigues vector or a 3 x 3 matrix, ``ignore``, and
  ``fisheye``).  Written in anipose's layout.
* ``multical``: multical's ``calibration.json``: ``cameras`` {name: {model, image_size, K, dist}} and
  ``camera_poses`` {name: {R, T}} where a key ``A_to_B`` gives camera A's pose in camera B's frame
  (``X_A = R X_B + T``; multical writes ``camX_to_<master>`` with the master's pose the identity).
  Written with absolute poses (keys = camera names), which keeps this project's world frame.
* ``colmap``: COLMAP's text model, a folder with ``cameras.txt`` (``CAMERA_ID MODEL WIDTH HEIGHT
  PARAMS...``) and ``images.txt`` (``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then a line of
  2D points).  Each image is one camera, named after the image file without its image suffix
  (folders joined by ``_``); written one COLMAP camera per camera, images named ``<name>.png``.

Conventions.  Rotations and translations are world -> camera everywhere (``Xc = R X + t``).
OpenCV-based tools (opencv, easymocap, toml, multical) put pixel centres at integers: their cx, cy
are this project's minus 0.5, shifted on the way in and out.  COLMAP puts them at +0.5, as we do.
Translations are in the file's unit: ``unit_m`` is its length in metres (0.001 for millimetres, as
anipose calibrations usually are).  Distortion: OpenCV's 4, 5, 8, 12 and 14 coefficient models are
carried; COLMAP's SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV map onto them (PINHOLE and
SIMPLE_PINHOLE have none).  Fisheye and other models that OpenCV's pinhole model cannot express are
refused by name (a ValueError naming the file, the camera and the model), as is what a format
cannot hold (skew or thin-prism coefficients in COLMAP, fisheye tables).  Files that do not record
the image size (EasyMocap without ``H_``/``W_``) need ``image_size``.
"""

from __future__ import annotations

import json
import logging
import math
import tomllib
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from assets.cameras import (MAX_IMAGE_PIXELS, Camera, check_camera_file_fields, distortion_coefficients, load_cameras,
                            save_cameras)
from assets.fileio import atomic_path, load_json, save_json
from reconstruction.cameras import read_opencv, validate_cameras, write_opencv

log = logging.getLogger(__name__)

FORMATS = ("json", "opencv", "easymocap", "toml", "multical", "colmap")
#: COLMAP's camera models without distortion or with OpenCV's, and how their parameters map:
#: name -> (number of parameters, indices of fx, fy, cx, cy, indices of the OpenCV coefficients)
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": (3, (0, 0, 1, 2), ()),
    "PINHOLE": (4, (0, 1, 2, 3), ()),
    "SIMPLE_RADIAL": (4, (0, 0, 1, 2), (3,)),
    "RADIAL": (5, (0, 0, 1, 2), (3, 4)),
    "OPENCV": (8, (0, 1, 2, 3), (4, 5, 6, 7)),
    "FULL_OPENCV": (12, (0, 1, 2, 3), (4, 5, 6, 7, 8, 9, 10, 11)),
}
#: COLMAP's other models: fisheye, FOV and thin-prism lenses that OpenCV's pinhole model cannot express
_COLMAP_REFUSED = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE", "FOV",
                   "RAD_TAN_THIN_PRISM_FISHEYE", "SIMPLE_FISHEYE", "FISHEYE")
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr")
#: multical's lens models by OpenCV coefficient count
_MULTICAL_MODELS = {5: "standard", 8: "rational", 12: "thin_prism", 14: "tilted"}


# ---- the dispatch ---------------------------------------------------------------------------------

def detect_format(path: str | Path, for_writing: bool = False) -> str:
    """The format of `path` (one of `FORMATS`): a folder with intri.yml / extri.yml is EasyMocap's
    (so is either file), one with cameras.txt / images.txt COLMAP's (so is either file); .toml is
    anipose / caliscope; .json is multical's when it has ``camera_poses`` or a map of ``cameras``,
    else ours; .yaml / .yml / .xml OpenCV's.  For writing, a path that does not exist yet is judged
    by its name only (a .json is ours), and a folder needs the format named."""
    path = Path(path)
    if path.name in ("intri.yml", "extri.yml"):
        return "easymocap"
    if path.name in ("cameras.txt", "images.txt"):
        return "colmap"
    if path.is_dir():
        if (path / "intri.yml").is_file() or (path / "extri.yml").is_file():
            return "easymocap"
        if (path / "cameras.txt").is_file() or (path / "images.txt").is_file():
            return "colmap"
        if not for_writing:
            raise ValueError(f"{path}: a folder without intri.yml / extri.yml (EasyMocap) or cameras.txt / "
                             "images.txt (COLMAP)")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return "toml"
    if suffix in (".yaml", ".yml", ".xml"):
        return "opencv"
    if suffix == ".json":
        if for_writing or not path.is_file():
            return "json"
        data = load_json(path)
        multical = isinstance(data, dict) and ("camera_poses" in data or isinstance(data.get("cameras"), dict))
        return "multical" if multical else "json"
    raise ValueError(f"{path}: cannot tell the calibration format from the name; name it "
                     f"(--format {', '.join(FORMATS)})")


def read_calibration(path: str | Path, format: str | None = None, unit_m: float = 1.0,
                     image_size: tuple[int, int] | None = None,
                     max_image_pixels: int = MAX_IMAGE_PIXELS) -> list[Camera]:
    """The cameras of a calibration in `format` (default: `detect_format`); translations in the
    file's unit `unit_m` (metres per unit) come out in metres; `image_size` (width, height) is used
    where the file does not record one.  Validated by `validate_cameras`."""
    path = Path(path)
    format = format or detect_format(path)
    if format not in FORMATS:
        raise ValueError(f"unknown calibration format {format!r} (known: {', '.join(FORMATS)})")
    if not unit_m > 0:
        raise ValueError(f"unit_m must be > 0, got {unit_m}")
    if format in ("easymocap", "colmap") and path.is_file():
        path = path.parent
    elif not path.exists():
        raise FileNotFoundError(f"{path}: no such calibration file or folder")
    if format == "json":
        cameras = load_cameras(path, max_image_pixels)
        cameras = [_scaled(c, unit_m) for c in cameras]
    elif format == "opencv":
        cameras = read_opencv(path, translation_scale=unit_m, max_image_pixels=max_image_pixels)
    else:
        reader: Callable[..., list[Camera]] = {"easymocap": _read_easymocap, "toml": _read_toml,
                                               "multical": _read_multical, "colmap": _read_colmap}[format]
        cameras = [_scaled(c, unit_m) for c in reader(path, image_size)]
        for camera in cameras:
            check_camera_file_fields(camera, f"{path}: camera {camera.name!r}", max_image_pixels)
    validate_cameras(cameras, source=str(path))
    return cameras


def write_calibration(path: str | Path, cameras: Sequence[Camera], format: str | None = None,
                      unit_m: float = 1.0) -> Path:
    """Write `cameras` in `format` (default: from the name, `detect_format`), translations in the unit
    `unit_m` (metres per unit); returns the file or folder written.  Each file is written atomically."""
    path = Path(path)
    format = format or detect_format(path, for_writing=True)
    if format not in FORMATS:
        raise ValueError(f"unknown calibration format {format!r} (known: {', '.join(FORMATS)})")
    if not unit_m > 0:
        raise ValueError(f"unit_m must be > 0, got {unit_m}")
    validate_cameras(cameras, source=f"cameras for {path}")
    scaled = [_scaled(c, 1.0 / unit_m) for c in cameras]
    if format in ("easymocap", "colmap") and path.name in ("intri.yml", "extri.yml", "cameras.txt", "images.txt"):
        path = path.parent
    if format == "json":
        save_cameras(path, scaled)
    elif format == "opencv":
        write_opencv(path, scaled, pixel_centre=0.0)
    else:
        {"easymocap": _write_easymocap, "toml": _write_toml, "multical": _write_multical,
         "colmap": _write_colmap}[format](path, scaled)
    return path


def _scaled(camera: Camera, factor: float) -> Camera:
    if factor == 1.0:
        return camera
    return Camera(K=camera.K, R=camera.R, t=camera.t * factor, width=camera.width, height=camera.height,
                  dist=camera.dist, name=camera.name)


def _camera(where: str, name: str, K: Any, dist: Any, R: Any, t: Any, size: Any, pixel_centre: float) -> Camera:
    """A Camera from a file's values, errors naming `where`; `pixel_centre` is where the file puts
    pixel centres (0 for OpenCV's tools), moved to this project's +0.5."""
    K = _array(K, (3, 3), f"{where}: K")
    K[:2, 2] += 0.5 - pixel_centre
    R = _array(R, None, f"{where}: rotation")
    if R.size == 3:
        R = cv2.Rodrigues(R.reshape(3))[0]
    elif R.size != 9:
        raise ValueError(f"{where}: rotation must be a Rodrigues vector (3 numbers) or a 3 x 3 matrix, "
                         f"got {R.size} numbers")
    size = _array(size, (2,), f"{where}: image size")
    if not (size == np.round(size)).all() or (size <= 0).any():
        raise ValueError(f"{where}: image size must be positive whole pixels, got {size.tolist()}")
    try:
        return Camera(K=K, R=R.reshape(3, 3), t=_array(t, (3,), f"{where}: translation"), width=int(size[0]),
                      height=int(size[1]), dist=distortion_coefficients(dist, f"{where}: distortion"), name=name)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def _array(value: Any, shape: tuple[int, ...] | None, where: str) -> np.ndarray:
    """`value` as a finite float64 array with `shape`'s number of elements (any nesting), reshaped."""
    if value is None:
        raise ValueError(f"{where}: missing")
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers, got {value!r}") from None
    if shape is not None:
        if array.size != math.prod(shape):
            raise ValueError(f"{where}: expected {math.prod(shape)} numbers, got {array.size}")
        array = array.reshape(shape)
    if not np.isfinite(array).all():
        raise ValueError(f"{where}: not finite")
    return array


def _opencv_K(camera: Camera) -> np.ndarray:
    """K in OpenCV's pixel convention (pixel centres at integers)."""
    K = camera.K.copy()
    K[:2, 2] -= 0.5
    return K


# ---- EasyMocap ----------------------------------------------------------------------------------

def _read_easymocap(folder: Path, image_size: tuple[int, int] | None) -> list[Camera]:
    intri, extri = folder / "intri.yml", folder / "extri.yml"
    for path in (intri, extri):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing (EasyMocap calibrations are intri.yml and extri.yml)")
    with _storage(intri) as fi, _storage(extri) as fe:
        names = _names(fi, intri)
        cameras = []
        for name in names:
            where = f"{intri} / {extri}: camera {name!r}"
            K = _node_matrix(fi, f"K_{name}", intri)
            dist = _node_matrix(fi, f"dist_{name}", intri, required=False)
            if dist is None:
                dist = _node_matrix(fi, f"D_{name}", intri, required=False)
            width, height = fi.getNode(f"W_{name}"), fi.getNode(f"H_{name}")
            if not width.empty() and not height.empty():
                size = (width.real(), height.real())
            elif image_size is not None:
                size = image_size
            else:
                raise ValueError(f"{intri}: camera {name!r} has no H_{name} / W_{name}: give the image size "
                                 "(--image-size WIDTH HEIGHT)")
            R = _node_matrix(fe, f"Rot_{name}", extri, required=False)
            if R is None:
                R = _node_matrix(fe, f"R_{name}", extri)
            T = _node_matrix(fe, f"T_{name}", extri)
            cameras.append(_camera(where, name, K, np.zeros(5) if dist is None else dist, R, T, size, 0.0))
    return cameras


def _write_easymocap(folder: Path, cameras: Sequence[Camera]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for filename, entries in (
        ("intri.yml", lambda c: [(f"K_{c.name}", _opencv_K(c)), (f"dist_{c.name}", c.dist.reshape(1, -1)),
                                 (f"H_{c.name}", c.height), (f"W_{c.name}", c.width)]),
        ("extri.yml", lambda c: [(f"R_{c.name}", cv2.Rodrigues(c.R)[0]), (f"Rot_{c.name}", c.R),
                                 (f"T_{c.name}", c.t.reshape(3, 1))]),
    ):
        with _writing(folder / filename) as storage:
            storage.startWriteStruct("names", cv2.FileNode_SEQ)
            for camera in cameras:
                storage.write("", camera.name)
            storage.endWriteStruct()
            for camera in cameras:
                for key, value in entries(camera):
                    storage.write(key, value)


class _storage:
    """A cv2.FileStorage opened for reading, as a context; unreadable files are a ValueError."""

    def __init__(self, path: Path):
        self.path = path

    def __enter__(self) -> Any:
        try:
            self.fs = cv2.FileStorage(str(self.path), cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:
            detail = str(exc).strip().splitlines()[-1]
            raise ValueError(f"{self.path}: not a readable OpenCV YAML file ({detail})") from None
        if not self.fs.isOpened():
            raise ValueError(f"{self.path}: not a readable OpenCV YAML file")
        return self.fs

    def __exit__(self, *exc: object) -> None:
        self.fs.release()


class _writing:
    """A cv2.FileStorage writing `path` atomically (YAML), as a context."""

    def __init__(self, path: Path):
        self.path = path

    def __enter__(self) -> Any:
        self.atomic = atomic_path(self.path)
        tmp = self.atomic.__enter__()
        self.target = tmp.with_name(tmp.name + ".yml")  # FileStorage picks the format from the suffix
        self.tmp = tmp
        self.fs = cv2.FileStorage(str(self.target), cv2.FILE_STORAGE_WRITE)
        return self.fs

    def __exit__(self, kind: Any, value: Any, traceback: Any) -> None:
        self.fs.release()
        if kind is None:
            self.target.replace(self.tmp)
        self.target.unlink(missing_ok=True)
        self.atomic.__exit__(kind, value, traceback)


def _names(storage: Any, path: Path) -> list[str]:
    node = storage.getNode("names")
    if node.empty() or not node.isSeq():
        raise ValueError(f"{path}: missing the list 'names' of cameras")
    names = []
    for i in range(node.size()):
        item = node.at(i)
        # EasyMocap writes names quoted, but hand-made files have bare numbers
        names.append(item.string() if item.isString() else f"{int(item.real())}" if item.isInt() else "")
        if not names[-1]:
            raise ValueError(f"{path}: names[{i}] must be a string or an integer")
    return names


def _node_matrix(storage: Any, key: str, path: Path, required: bool = True) -> np.ndarray | None:
    node = storage.getNode(key)
    if node.empty():
        if required:
            raise ValueError(f"{path}: missing {key}")
        return None
    try:
        matrix = node.mat()
    except cv2.error as exc:
        raise ValueError(f"{path}: {key} is not a valid OpenCV matrix ({exc.err})") from None
    if matrix is None and node.isSeq():
        matrix = np.array([node.at(i).real() for i in range(node.size())])
    if matrix is None:
        raise ValueError(f"{path}: {key} must be an OpenCV matrix or a list of numbers")
    return np.asarray(matrix, dtype=np.float64)


# ---- anipose / caliscope TOML -------------------------------------------------------------------

def _read_toml(path: Path, image_size: tuple[int, int] | None) -> list[Camera]:
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable TOML file ({exc})") from None
    if isinstance(data.get("cameras"), dict):  # caliscope's camera_array.toml
        tables = [(f"cameras.{key}", f"cam_{key}", value) for key, value in data["cameras"].items()]
    else:  # anipose's calibration.toml, caliscope's older config.toml
        tables = [(key, key, value) for key, value in data.items() if key.startswith("cam_")]
    cameras = []
    for key, default_name, table in tables:
        where = f"{path}: [{key}]"
        if not isinstance(table, dict):
            raise ValueError(f"{where}: expected a table")
        if table.get("ignore") is True:
            log.warning("%s: skipped, marked ignore = true", where)
            continue
        if "port" in table or "cam_id" in table:
            default_name = f"cam_{table.get('cam_id', table.get('port'))}"
        name = table.get("name", default_name)
        if not isinstance(name, str):
            raise ValueError(f"{where}: name must be a string, got {name!r}")
        if table.get("fisheye") is True:
            raise ValueError(f"{where}: camera {name!r} uses the fisheye model, which OpenCV's pinhole model "
                             "here cannot express")
        missing = [field for field in ("matrix", "rotation", "translation") if field not in table]
        if missing:
            raise ValueError(f"{where}: camera {name!r} is not calibrated (missing {', '.join(missing)})")
        cameras.append(_camera(f"{where} ({name!r})", name, table["matrix"], table.get("distortions", np.zeros(5)),
                               table["rotation"], table["translation"], table.get("size", image_size), 0.0))
    if not cameras:
        raise ValueError(f"{path}: no calibrated cameras ([cam_0]... or [cameras.0]... tables)")
    return cameras


def _write_toml(path: Path, cameras: Sequence[Camera]) -> None:
    lines = []
    for i, camera in enumerate(cameras):
        lines += [f"[cam_{i}]", f"name = {json.dumps(camera.name)}", f"size = [{camera.width}, {camera.height}]",
                  f"matrix = {_toml_array(_opencv_K(camera))}", f"distortions = {_toml_array(camera.dist)}",
                  f"rotation = {_toml_array(cv2.Rodrigues(camera.R)[0].reshape(3))}",
                  f"translation = {_toml_array(camera.t)}", ""]
    lines += ["[metadata]", "adjusted = false", ""]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines))


def _toml_array(array: np.ndarray) -> str:
    if array.ndim > 1:
        return "[" + ", ".join(_toml_array(row) for row in array) + "]"
    return "[" + ", ".join(repr(float(v)) for v in array) + "]"


# ---- multical -----------------------------------------------------------------------------------

def _read_multical(path: Path, image_size: tuple[int, int] | None) -> list[Camera]:
    data = load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), dict):
        raise ValueError(f"{path}: expected an object with a map 'cameras' (multical's calibration.json)")
    if not isinstance(data.get("camera_poses"), dict):
        raise ValueError(f"{path}: missing the map 'camera_poses' (intrinsics alone make no rig)")
    names = list(data["cameras"])
    absolute: dict[str, np.ndarray] = {}
    relative: list[tuple[str, str, np.ndarray]] = []
    for key, pose in data["camera_poses"].items():
        where = f"{path}: camera_poses.{key}"
        if not isinstance(pose, dict):
            raise ValueError(f"{where}: expected an object with R and T")
        matrix = np.eye(4)
        matrix[:3, :3] = _array(pose.get("R"), (3, 3), f"{where}.R")
        matrix[:3, 3] = _array(pose.get("T"), (3,), f"{where}.T")
        source, _, target = key.partition("_to_")
        for name in (source, target) if target else (source,):
            if name not in names:
                raise ValueError(f"{where}: no camera {name!r} in 'cameras' ({names})")
        if target:
            relative.append((source, target, matrix))
        else:
            absolute[source] = matrix
    if not absolute and relative:
        absolute[relative[0][1]] = np.eye(4)  # only relative poses: the first target is the world
    # chain relative poses from the known ones: X_source = M X_target, so P_source = M P_target
    changed = True
    while changed:
        changed = False
        for source, target, matrix in relative:
            if source not in absolute and target in absolute:
                absolute[source] = matrix @ absolute[target]
                changed = True
            elif target not in absolute and source in absolute:
                absolute[target] = np.linalg.inv(matrix) @ absolute[source]
                changed = True
    cameras = []
    for name in names:
        where = f"{path}: cameras.{name}"
        camera = data["cameras"][name]
        if not isinstance(camera, dict):
            raise ValueError(f"{where}: expected an object with K, dist and image_size")
        model = camera.get("model", "standard")
        if model not in _MULTICAL_MODELS.values():
            raise ValueError(f"{where}: camera {name!r} uses the lens model {model!r}, which OpenCV's pinhole "
                             f"model here cannot express (known: {', '.join(_MULTICAL_MODELS.values())})")
        if name not in absolute:
            raise ValueError(f"{path}: camera_poses place no pose for camera {name!r}")
        pose = absolute[name]
        cameras.append(_camera(where, name, camera.get("K"), camera.get("dist", np.zeros(5)), pose[:3, :3],
                               pose[:3, 3], camera.get("image_size", image_size), 0.0))
    return cameras


def _write_multical(path: Path, cameras: Sequence[Camera]) -> None:
    save_json(path, {
        "cameras": {c.name: {"model": _MULTICAL_MODELS[c.dist.size], "image_size": [c.width, c.height],
                             "K": _opencv_K(c).tolist(), "dist": [c.dist.tolist()]} for c in cameras},
        "camera_poses": {c.name: {"R": c.R.tolist(), "T": c.t.tolist()} for c in cameras},
    })


# ---- COLMAP -------------------------------------------------------------------------------------

def _read_colmap(folder: Path, image_size: tuple[int, int] | None) -> list[Camera]:
    cameras_txt, images_txt = folder / "cameras.txt", folder / "images.txt"
    for path in (cameras_txt, images_txt):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing (a COLMAP text model is cameras.txt and images.txt)")
    intrinsics = {}
    for number, fields in _data_lines(cameras_txt):
        where = f"{cameras_txt}:{number}"
        if len(fields) < 4:
            raise ValueError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {' '.join(fields)!r}")
        camera_id, model = fields[0], fields[1]
        if model in _COLMAP_REFUSED:
            raise ValueError(f"{where}: camera {camera_id} uses the COLMAP model {model}, which OpenCV's pinhole "
                             "model here cannot express")
        if model not in _COLMAP_MODELS:
            raise ValueError(f"{where}: camera {camera_id}: unknown COLMAP model {model!r} "
                             f"(known: {', '.join(_COLMAP_MODELS)})")
        count, (fx, fy, cx, cy), coefficients = _COLMAP_MODELS[model]
        params = _array([_number(v, where) for v in fields[4:]], None, where)
        if params.size != count:
            raise ValueError(f"{where}: the {model} model has {count} parameters, got {params.size}")
        K = np.array([[params[fx], 0.0, params[cx]], [0.0, params[fy], params[cy]], [0.0, 0.0, 1.0]])
        dist = np.zeros(8 if model == "FULL_OPENCV" else 5)
        dist[:len(coefficients)] = params[list(coefficients)]
        intrinsics[camera_id] = (K, dist, (_number(fields[2], where), _number(fields[3], where)), model)
    cameras = []
    lines = _data_lines(images_txt, keep_empty=True)
    for (number, fields) in lines[::2]:  # every image has a second line of 2D points, perhaps empty
        where = f"{images_txt}:{number}"
        if len(fields) < 10:
            raise ValueError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, "
                             f"got {' '.join(fields)!r}")
        q = _array([_number(v, where) for v in fields[1:5]], (4,), f"{where}: quaternion")
        if not 0.5 < np.linalg.norm(q) < 2.0:
            raise ValueError(f"{where}: the quaternion {q.tolist()} is not a rotation (norm {np.linalg.norm(q):.3g})")
        t = _array([_number(v, where) for v in fields[5:8]], (3,), f"{where}: translation")
        if fields[8] not in intrinsics:
            raise ValueError(f"{where}: camera {fields[8]} is not in {cameras_txt.name}")
        K, dist, size, model = intrinsics[fields[8]]
        image = " ".join(fields[9:])
        name = image[:-len(Path(image).suffix)] if Path(image).suffix.lower() in _IMAGE_SUFFIXES else image
        name = name.replace("/", "_").replace("\\", "_")
        cameras.append(_camera(f"{where} (image {image!r}, {model})", name, K, dist, _quaternion_to_matrix(q), t,
                               size, 0.5))
    if not cameras:
        raise ValueError(f"{images_txt}: no images")
    return cameras


def _write_colmap(folder: Path, cameras: Sequence[Camera]) -> None:
    camera_lines = ["# Camera list with one line of data per camera:",
                    "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {len(cameras)}"]
    image_lines = ["# Image list with two lines of data per image:",
                   "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)",
                   f"# Number of images: {len(cameras)}, mean observations per image: 0"]
    for i, camera in enumerate(cameras, start=1):
        K, dist = camera.K, camera.dist
        if K[0, 1] != 0:
            raise ValueError(f"camera {camera.name!r}: COLMAP's camera models have no skew, got K[0, 1]={K[0, 1]}")
        if dist.size > 8:
            raise ValueError(f"camera {camera.name!r}: COLMAP has no pinhole model with OpenCV's thin-prism or tilt "
                             f"coefficients, got {dist.size} coefficients {dist.tolist()}")
        model, coefficients = ("PINHOLE", []) if not camera.distorted else \
            ("OPENCV", dist[:4].tolist()) if dist.size == 5 and dist[4] == 0 else \
            ("FULL_OPENCV", np.concatenate([dist, np.zeros(8 - dist.size)]).tolist())
        params = [K[0, 0], K[1, 1], K[0, 2], K[1, 2]] + coefficients
        camera_lines.append(" ".join([str(i), model, str(camera.width), str(camera.height)]
                                     + [repr(float(v)) for v in params]))
        image_lines.append(" ".join([str(i)] + [repr(float(v)) for v in _matrix_to_quaternion(camera.R)]
                                    + [repr(float(v)) for v in camera.t] + [str(i), f"{camera.name}.png"]))
        image_lines.append("")
    folder.mkdir(parents=True, exist_ok=True)
    for filename, lines in (("cameras.txt", camera_lines), ("images.txt", image_lines)):
        with atomic_path(folder / filename) as tmp:
            tmp.write_text("\n".join(lines) + "\n")


def _data_lines(path: Path, keep_empty: bool = False) -> list[tuple[int, list[str]]]:
    """(line number, fields) of the lines that are not comments (nor empty unless `keep_empty`)."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file (COLMAP's binary models are not read; export them as "
                         "text)") from None
    rows = [(n, line.split()) for n, line in enumerate(text.splitlines(), start=1) if not line.startswith("#")]
    if keep_empty:
        while rows and not rows[-1][1] and len(rows) % 2:
            rows.pop()  # a trailing empty line after the last image's points
        return rows
    return [(n, fields) for n, fields in rows if fields]


def _number(text: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{where}: expected a number, got {text!r}") from None


def _quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """COLMAP's (qw, qx, qy, qz) (normalised here) as a rotation matrix."""
    return Rotation.from_quat(np.roll(q, -1)).as_matrix()


def _matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """A rotation matrix as COLMAP's (qw, qx, qy, qz), qw >= 0."""
    q = np.roll(Rotation.from_matrix(R).as_quat(), 1)
    return q if q[0] >= 0 else -q
