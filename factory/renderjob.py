"""A render job: what `factory.render` renders, read and checked without Blender.

The job (JSON; paths relative to the job file's folder unless absolute)::

    {"version": 1, "scene": "scene.npz", "texture": "pattern_texture.png", "resolution": [W, H],
     "engine": {"name": "CYCLES" | "EEVEE" | "WORKBENCH", "samples": 16, "denoise": false,
                "device": "auto" | "CPU" | "GPU"},
     "passes": {"depth": true, "position": false},
     "images": [{"name": "f000012_v0", "frame": 12,
                 "camera": Camera.to_dict() (assets.cameras; W x H, no distortion),
                 "transform": 4 x 4 row-major object matrix for garment and body,
                 "environment": {"type": "hdri", "file": "forest.exr", "rotation_deg": 30, "strength": 1}
                              | {"type": "sky", "sun_elevation_deg": 35, "sun_rotation_deg": 120, "strength": 0.5},
                 "cloth": {"roughness": 0.8, "sheen": 0.5}, "skin": {"rgb": [0.8, 0.6, 0.5]}, "seed": 1234}]}

The scene ``.npz``: garment_positions (T, V, 3) float32 world metres, garment_faces (F, 3) int,
garment_uv (F, 3, 2) per face corner (origin bottom-left), frames (T,) int (an image's `frame` is one
of these values), optionally body_vertices (T, Vb, 3) and body_faces (Fb, 3).  An HDRI `file` is one
of Blender's bundled maps (`bundled_environments()`) or a path.

`load_job` checks every field and the scene's array shapes and raises RenderJobError naming the file and
the field; nothing here imports bpy.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from assets.cameras import Camera
from assets.fileio import load_json, load_npz

ENGINES = {"CYCLES": ("CYCLES",), "EEVEE": ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE"), "WORKBENCH": ("BLENDER_WORKBENCH",)}
DEVICES = ("auto", "CPU", "GPU")


class RenderJobError(ValueError):
    """A render job that cannot be rendered: the message names the file and the field."""


# ---- the job ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Environment:
    """An image's world: an HDRI map rotated about Z, or Blender's physical sky."""

    kind: str                 # "hdri" | "sky"
    strength: float
    file: str = ""            # hdri: bundled name or path (resolved against the job folder)
    rotation_deg: float = 0.0
    sun_elevation_deg: float = 0.0
    sun_rotation_deg: float = 0.0


@dataclass(frozen=True, eq=False)
class ImageSpec:
    """One image of a job, checked."""

    name: str
    frame_index: int          # index into the scene's frames
    camera: Camera
    transform: np.ndarray     # (4, 4) float64 object matrix
    environment: Environment
    cloth_roughness: float
    cloth_sheen: float
    skin_rgb: tuple[float, float, float]
    seed: int
    where: str                # "job.json: images[3]", for messages


@dataclass(frozen=True, eq=False)
class RenderJob:
    """A checked render job with its scene arrays loaded (see the module docstring for the fields)."""

    path: Path
    scene: dict[str, np.ndarray]
    texture: Path
    resolution: tuple[int, int]
    engine: str
    samples: int
    denoise: bool
    device: str
    depth: bool
    position: bool
    images: tuple[ImageSpec, ...]

    def settings(self) -> dict:
        """What every image rendered into one folder shares (its record, `factory.render`): size, engine,
        samples, denoising, device and passes; the scene and the images differ between the jobs of a
        dataset's shards, which render into one folder."""
        return {"resolution": list(self.resolution), "engine": self.engine, "samples": self.samples,
                "denoise": self.denoise, "device": self.device,
                "passes": {"depth": self.depth, "position": self.position}}

    def outputs(self, image: ImageSpec, out_dir: Path) -> dict[str, Path]:
        files = {"png": f"{image.name}.png", "camera": f"{image.name}_camera.json"}
        if self.depth:
            files["depth"] = f"{image.name}_depth.exr"
        if self.position:
            files["position"] = f"{image.name}_position.exr"
        return {key: out_dir / name for key, name in files.items()}


def _at(where: str, key: str) -> str:
    """The name of field `key` inside `where` ("job.json:" + "engine" -> "job.json: engine")."""
    return f"{where} {key}" if where.endswith(":") else f"{where}.{key}"


def _get(obj: Any, key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    if not isinstance(obj, dict):
        raise RenderJobError(f"{where.rstrip(':')}: expected a JSON object, got {type(obj).__name__}")
    if key not in obj:
        raise RenderJobError(f"{where.rstrip(':')}: missing field '{key}'")
    value = obj[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise RenderJobError(f"{_at(where, key)}: expected {names}, got {value!r}")
    return value


def _number(obj: Any, key: str, where: str, low: float = -math.inf, high: float = math.inf) -> float:
    value = float(_get(obj, key, where, (int, float)))
    if not low <= value <= high:
        raise RenderJobError(f"{_at(where, key)}: expected a number in [{low}, {high}], got {value}")
    return value


def _file(job_path: Path, value: str, where: str) -> Path:
    path = Path(value) if Path(value).is_absolute() else job_path.parent / value
    if not path.is_file():
        raise RenderJobError(f"{where}: file not found: {path}")
    return path


def _load_scene(path: Path, where: str) -> dict[str, np.ndarray]:
    try:
        arrays = load_npz(path, required=("garment_positions", "garment_faces", "garment_uv", "frames"))
    except ValueError as exc:
        raise RenderJobError(f"{where}: {exc}") from exc
    expected = {"garment_positions": ("T", "V", 3), "garment_faces": ("F", 3), "garment_uv": ("F", 3, 2),
                "frames": ("T",), "body_vertices": ("T", "Vb", 3), "body_faces": ("Fb", 3)}
    if ("body_vertices" in arrays) != ("body_faces" in arrays):
        raise RenderJobError(f"{path}: body_vertices and body_faces come together; only one is present")
    sizes: dict[str, int] = {}
    for key, shape in expected.items():
        if key not in arrays:
            continue
        array = arrays[key]
        ok = array.ndim == len(shape)
        for dim, n in zip(shape, array.shape if ok else ()):
            ok &= n == dim if isinstance(dim, int) else sizes.setdefault(dim, n) == n
        if not ok:
            raise RenderJobError(f"{path}: {key} has shape {array.shape}, expected {shape} "
                                 f"(with {', '.join(f'{k}={v}' for k, v in sizes.items())})")
        integer = key in ("garment_faces", "body_faces", "frames")
        if integer != np.issubdtype(array.dtype, np.integer) or not integer and not np.isfinite(array).all():
            raise RenderJobError(f"{path}: {key} must be {'integers' if integer else 'finite floats'} "
                                 f"(dtype {array.dtype})")
    for faces, vertices in (("garment_faces", "V"), ("body_faces", "Vb")):
        index = arrays.get(faces, np.zeros(0, dtype=int))
        if len(index) and not 0 <= index.min() <= index.max() < sizes[vertices]:
            raise RenderJobError(f"{path}: {faces} index outside [0, {sizes[vertices]})")
    if not len(arrays["frames"]):
        raise RenderJobError(f"{path}: no frames")
    if len(np.unique(arrays["frames"])) != len(arrays["frames"]):
        raise RenderJobError(f"{path}: frames has repeated values")
    return arrays


def _load_environment(spec: Any, where: str) -> Environment:
    kind = _get(spec, "type", where, str)
    strength = _number(spec, "strength", where, 0.0)
    if kind == "hdri":
        name = _get(spec, "file", where, str)
        if not name:
            raise RenderJobError(f"{where}.file: empty")
        return Environment("hdri", strength, file=name, rotation_deg=_number(spec, "rotation_deg", where))
    if kind == "sky":
        return Environment("sky", strength, sun_elevation_deg=_number(spec, "sun_elevation_deg", where, -90.0, 90.0),
                           sun_rotation_deg=_number(spec, "sun_rotation_deg", where) % 360.0)
    raise RenderJobError(f"{where}.type: expected 'hdri' or 'sky', got {kind!r}")


def _load_image(spec: Any, where: str, frame_index: dict[int, int], resolution: tuple[int, int]) -> ImageSpec:
    name = _get(spec, "name", where, str)
    if not name or name.startswith(".") or any(c in name for c in "/\\\0"):
        raise RenderJobError(f"{where}.name: must be a plain file name (no '/', not starting with '.'), got {name!r}")
    frame = _get(spec, "frame", where, int)
    if frame not in frame_index:
        raise RenderJobError(f"{where}.frame: {frame} is not in the scene's frames "
                             f"({min(frame_index)}..{max(frame_index)}, {len(frame_index)} frames)")
    try:
        camera = Camera.from_dict(_get(spec, "camera", where, dict), f"{where}.camera")
        camera.blender_params()
    except ValueError as exc:
        raise RenderJobError(str(exc) if str(exc).startswith(where) else f"{where}.camera: {exc}") from exc
    if (camera.width, camera.height) != resolution:
        raise RenderJobError(f"{where}.camera: size {camera.width} x {camera.height} differs from the job's "
                             f"resolution {list(resolution)}")
    transform = _get(spec, "transform", where, list)
    try:
        transform = np.asarray(transform, dtype=np.float64)
    except (TypeError, ValueError):  # ragged or not numbers
        transform = np.zeros(0)
    if transform.shape != (4, 4) or not np.isfinite(transform).all() or not np.allclose(transform[3], [0, 0, 0, 1]):
        raise RenderJobError(f"{where}.transform: expected a finite 4 x 4 row-major matrix with last row [0, 0, 0, 1]")
    cloth, skin = _get(spec, "cloth", where, dict), _get(spec, "skin", where, dict)
    rgb = _get(skin, "rgb", f"{where}.skin", list)
    if len(rgb) != 3 or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and 0 <= c <= 1 for c in rgb):
        raise RenderJobError(f"{where}.skin.rgb: expected three numbers in [0, 1], got {rgb!r}")
    seed = _get(spec, "seed", where, int)
    if not 0 <= seed < 2**31:
        raise RenderJobError(f"{where}.seed: expected an integer in [0, 2**31), got {seed}")
    return ImageSpec(name=name, frame_index=frame_index[frame], camera=camera, transform=transform,
                     environment=_load_environment(_get(spec, "environment", where, dict), f"{where}.environment"),
                     cloth_roughness=_number(cloth, "roughness", f"{where}.cloth", 0.0, 1.0),
                     cloth_sheen=_number(cloth, "sheen", f"{where}.cloth", 0.0, 1.0),
                     skin_rgb=tuple(float(c) for c in rgb), seed=seed, where=where)


def load_job(job_path: str | os.PathLike) -> RenderJob:
    """Read and check a render job and its scene arrays (no bpy needed); RenderJobError names the field."""
    path = Path(job_path)
    if not path.is_file():
        raise RenderJobError(f"{path}: job file not found")
    data = load_json(path)
    top = f"{path}:"
    if _get(data, "version", top, int) != 1:
        raise RenderJobError(f"{path}: version: expected 1, got {data['version']}")
    scene = _load_scene(_file(path, _get(data, "scene", top, str), f"{path}: scene"), f"{path}: scene")
    texture = _file(path, _get(data, "texture", top, str), f"{path}: texture")
    resolution = _get(data, "resolution", top, list)
    if len(resolution) != 2 or not all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in resolution):
        raise RenderJobError(f"{path}: resolution: expected [width, height] positive integers, got {resolution!r}")
    engine = _get(data, "engine", top, dict)
    name = _get(engine, "name", f"{path}: engine", str)
    if name not in ENGINES:
        raise RenderJobError(f"{path}: engine.name: unknown engine {name!r}, expected one of {sorted(ENGINES)}")
    samples = _get(engine, "samples", f"{path}: engine", int)
    if samples < 1:
        raise RenderJobError(f"{path}: engine.samples: expected >= 1, got {samples}")
    device = _get(engine, "device", f"{path}: engine", str)
    if device not in DEVICES:
        raise RenderJobError(f"{path}: engine.device: expected one of {list(DEVICES)}, got {device!r}")
    passes = _get(data, "passes", top, dict)
    depth, position = (_get(passes, key, f"{path}: passes", bool) for key in ("depth", "position"))
    if position and name != "CYCLES":
        raise RenderJobError(f"{path}: passes.position: the world-position pass is rendered by CYCLES only, "
                             f"not {name}")
    frame_index = {int(f): i for i, f in enumerate(scene["frames"])}
    images = tuple(_load_image(spec, f"{path}: images[{i}]", frame_index, tuple(resolution))
                   for i, spec in enumerate(_get(data, "images", top, list)))
    names = [image.name for image in images]
    if len(set(names)) != len(names):
        raise RenderJobError(f"{path}: images: repeated names {sorted({n for n in names if names.count(n) > 1})}")
    return RenderJob(path=path, scene=scene, texture=texture, resolution=tuple(resolution), engine=name,
                     samples=samples, denoise=_get(engine, "denoise", f"{path}: engine", bool), device=device,
                     depth=depth, position=position, images=images)
