"""Render a render job with Blender: RGB, depth and world-position images with the camera of each.

    blender -b -P factory/render.py -- --job JOB.json --out DIR      (a Blender executable, 3.4 or later)
    python factory/render.py --job JOB.json --out DIR                (a Python with the bpy module)
    from factory.render import render_job; render_job(job_path, out_dir)

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

Output per image in DIR: ``{name}.png`` (8-bit sRGB, view transform Standard), ``{name}_depth.exr``
(float32 channel Z: camera-frame depth in metres, as Blender's Z pass; +inf on the background),
``{name}_position.exr`` (float32 X, Y, Z world metres; NaN on the background; Cycles only) and
``{name}_camera.json``.  Every file is written under a temporary name and renamed; an image whose
outputs all exist is skipped unless `force`.

The garment is exactly the given triangles (no subdivision, no displacement: ground truth is computed
from them), smooth shaded, textured through its UVs.  The scene is built once per job; each image
only moves vertices and objects, the camera, the world and material parameters.  `render_job` starts
from Blender's factory settings, so whatever the session held before is gone.

Blender versions: 3.4 and 5.0 differ in Principled input names ('Sheen' / 'Sheen Weight'), the
physical sky ('NISHITA' / 'MULTIPLE_SCATTERING'), `image_settings.media_type` (5.0 only) and how a
multilayer EXR is laid out (5.0 writes one part per pass); the channel names are the same
('ViewLayer.Depth.Z', 'ViewLayer.Position.X').  Debian's Blender 3.4 links its own OpenEXR, whose C
functions the OpenEXR wheel would bind to and crash; there the passes are split by the venv's Python
in a subprocess.
"""

from __future__ import annotations

import sys
from pathlib import Path

if __name__ == "__main__":
    # As a script, Blender's own Python knows neither the project nor numpy: add the project root and
    # its venv's packages (same Python minor version, so compiled modules load).
    _ROOT = Path(__file__).resolve().parents[1]
    _SITE = _ROOT / ".venv" / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    sys.path[:0] = [str(p) for p in (_ROOT, _SITE) if p.is_dir() and str(p) not in sys.path]
    import importlib.util

    if importlib.util.find_spec("numpy") is None:  # before an ImportError that Blender would exit 0 on
        sys.exit(f"error: numpy is not importable from this Python {sys.version.split()[0]}; the script takes "
                 f"it from the project's venv {_SITE}, which `make test` creates")

import argparse
import ctypes
import importlib.util
import json
import logging
import math
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from assets.cameras import Camera
from assets.cli import run_cli
from assets.fileio import atomic_path, load_json, load_npz, save_json

log = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[1]
ENGINES = {"CYCLES": ("CYCLES",), "EEVEE": ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE"), "WORKBENCH": ("BLENDER_WORKBENCH",)}
DEVICES = ("auto", "CPU", "GPU")
GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "METAL", "ONEAPI")  # preferred first
#: physical sky models, newest first (5.0 renamed Nishita and added multiple scattering)
PHYSICAL_SKIES = ("MULTIPLE_SCATTERING", "NISHITA", "SINGLE_SCATTERING")
#: camera clip range, metres; depth at or beyond CLIP_END_M (less a relative margin) is background
CLIP_START_M, CLIP_END_M, BACKGROUND_MARGIN = 0.01, 100.0, 1e-3
SKIN_SUBSURFACE, SKIN_ROUGHNESS = 0.1, 0.5
#: Cycles' importance map of the world, rebuilt for every image: the bundled maps are 1024 x 512, and
#: the automatic resolution costs 1-2 s per image on 2 cores (a 64 x 64 image renders in 0.1 s)
WORLD_MAP_RESOLUTION = 1024


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


# ---- environments -------------------------------------------------------------------------------
def environment_dir() -> Path:
    """Blender's folder of bundled HDRIs (studiolights/world), found without importing bpy if needed."""
    bpy = sys.modules.get("bpy")
    if bpy is not None:
        return Path(bpy.utils.system_resource("DATAFILES", path="studiolights/world"))
    spec = importlib.util.find_spec("bpy")
    for location in (spec.submodule_search_locations or []) if spec else []:
        found = sorted(Path(location).glob("*/datafiles/studiolights/world"))
        if found:
            return found[-1]
    raise RuntimeError("Blender's bundled environment maps are found through bpy, which is not installed "
                       "here: pip install '.[factory]', or call this inside Blender")


def bundled_environments() -> list[str]:
    """File names (sorted) of the HDRI maps that ship with Blender, usable as an environment's `file`."""
    return sorted(p.name for p in environment_dir().glob("*.exr"))


def _resolve_environment(job: RenderJob, image: ImageSpec) -> Path:
    bundled, local = environment_dir() / image.environment.file, job.path.parent / image.environment.file
    for path in (bundled, local) if Path(image.environment.file).name == image.environment.file else (local,):
        if path.is_file():
            return path
    raise RenderJobError(f"{image.where}.environment.file: {image.environment.file!r} is neither a bundled map "
                         f"({', '.join(bundled_environments())}) nor a file at {local}")


# ---- passes: Blender's multilayer EXR -> single files -------------------------------------------
def split_render_passes(multilayer: str, depth: str | None, position: str | None) -> None:
    """Write the depth (channel Z) and position (X, Y, Z) EXRs from Blender's multilayer render EXR.

    Channels are found by their pass suffix ('Depth.Z', 'Position.X'), whatever the layer prefix and
    part layout.  Background (depth not finite or at the far clip) becomes +inf depth, NaN position."""
    import OpenEXR

    with OpenEXR.File(multilayer) as exr:
        channels = {name: c.pixels for part in exr.parts for name, c in part.channels.items()}

    def channel(suffix: str) -> np.ndarray:
        for name, pixels in channels.items():
            if name == suffix or name.endswith("." + suffix):
                return np.asarray(pixels, dtype=np.float32)
        raise RuntimeError(f"{multilayer}: no '{suffix}' channel among {sorted(channels)}")

    def write(path: str, named: dict[str, np.ndarray]) -> None:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with atomic_path(path) as tmp:
            OpenEXR.File(header, {k: np.ascontiguousarray(v) for k, v in named.items()}).write(str(tmp))

    z = channel("Depth.Z")
    background = ~np.isfinite(z) | (z >= CLIP_END_M * (1 - BACKGROUND_MARGIN))
    if depth:
        write(depth, {"Z": np.where(background, np.float32(np.inf), z)})
    if position:
        write(position, {axis: np.where(background, np.float32(np.nan), channel(f"Position.{axis}")) for axis in "XYZ"})


def _process_links_openexr() -> bool:
    """True when OpenEXR's C core is already linked into this process (Debian's Blender links its own):
    the OpenEXR wheel's calls would bind to that other version's functions and crash."""
    return hasattr(ctypes.CDLL(None), "exr_start_read")


def _split_in_subprocess(kwargs: dict[str, str | None]) -> None:
    spec = importlib.util.find_spec("OpenEXR")
    if spec is None or not spec.origin:
        raise RuntimeError("the OpenEXR python module is not importable: pip install '.[factory]'")
    prefix = Path(spec.origin).resolve().parents[3]  # <prefix>/lib/pythonX.Y/site-packages/OpenEXR*.so
    python = next((p for p in (prefix / "bin" / "python3", prefix / "bin" / "python") if p.is_file()), None)
    if python is None:
        raise RuntimeError(f"no Python next to the OpenEXR module at {prefix} to split the render passes")
    code = ("import json, sys; sys.path.insert(0, sys.argv[2]); from factory.render import split_render_passes; "
            "split_render_passes(**json.loads(sys.argv[1]))")
    result = subprocess.run([str(python), "-c", code, json.dumps(kwargs), str(ROOT)], capture_output=True, text=True)
    if result.returncode:
        raise RuntimeError(f"splitting {kwargs['multilayer']} with {python} failed:\n{result.stderr.strip()}")


# ---- Blender ------------------------------------------------------------------------------------
def _import_bpy():
    try:
        import bpy
    except ImportError as exc:
        raise RuntimeError("bpy is not importable: pip install '.[factory]', or run "
                           "`blender -b -P factory/render.py -- ...`") from exc
    return bpy


def _input(node, *names: str):
    """The first of `names` that `node` has as an input (names differ between Blender versions)."""
    return next((node.inputs[n] for n in names if n in node.inputs), None)


def _set_engine(scene, job: RenderJob) -> None:
    bpy = _import_bpy()
    for engine_id in ENGINES[job.engine]:
        try:
            scene.render.engine = engine_id  # the enum of engines is dynamic: trying is the check
            break
        except TypeError:
            continue
    else:
        raise RenderJobError(f"{job.path}: engine.name: this Blender {bpy.app.version_string} has no {job.engine} "
                             f"engine (tried {', '.join(ENGINES[job.engine])})")
    if job.engine == "CYCLES":
        import _cycles

        scene.cycles.samples = job.samples
        scene.cycles.use_denoising = job.denoise and _cycles.with_openimagedenoise
        if job.denoise and not _cycles.with_openimagedenoise:
            log.warning("this Blender %s is built without OpenImageDenoise: rendering without denoising",
                        bpy.app.version_string)
        gpu = job.device != "CPU" and _enable_gpu(bpy)
        scene.cycles.device = "GPU" if gpu else "CPU"
        if job.device != "CPU" and not gpu:  # a warning when the job asked for a GPU, news for "auto"
            log.log(logging.WARNING if job.device == "GPU" else logging.INFO,
                    "no GPU compute device (tried %s): Cycles renders on the CPU", ", ".join(GPU_BACKENDS))
        log.info("Cycles on %s, %d samples, denoising %s", scene.cycles.device, job.samples,
                 "on" if scene.cycles.use_denoising else "off")
        scene.render.use_persistent_data = True  # keep the BVH and textures between images
    elif job.engine == "EEVEE":
        scene.eevee.taa_render_samples = job.samples
    else:
        scene.display.shading.light = "STUDIO"
        scene.display.shading.color_type = "TEXTURE"


def _enable_gpu(bpy) -> str | None:
    """Switch Cycles to the first GPU backend with a device; None (CPU) when there is none."""
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for backend in GPU_BACKENDS:
        try:
            prefs.compute_device_type = backend
        except TypeError:  # not built into this Blender
            continue
        prefs.refresh_devices()
        if any(d.type == backend for d in prefs.devices):
            for d in prefs.devices:
                d.use = d.type == backend
            log.info("Cycles GPU backend %s: %s", backend, ", ".join(d.name for d in prefs.devices if d.use))
            return backend
    prefs.compute_device_type = "NONE"
    return None


def _mesh_object(bpy, scene, name: str, vertices: np.ndarray, faces: np.ndarray):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices.astype(np.float64).tolist(), [], faces.tolist())
    mesh.polygons.foreach_set("use_smooth", np.ones(len(faces), dtype=bool))
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    return obj


def _principled(bpy, name: str):
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender < 5.0 (5.0 gives every material nodes, use_nodes is deprecated)
        material.use_nodes = True
    return material, material.node_tree.nodes["Principled BSDF"]


class BlenderScene:
    """The job's Blender scene, built once; `show(image)` sets it up for one image."""

    def __init__(self, job: RenderJob):
        bpy = self.bpy = _import_bpy()
        from mathutils import Matrix

        self.Matrix, self.job = Matrix, job
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = self.scene = bpy.context.scene
        _set_engine(scene, job)
        scene.render.film_transparent = False
        # no date, time or render time in the files' metadata: the same job gives the same bytes
        for name in dir(scene.render):
            if name.startswith("use_stamp") and isinstance(getattr(scene.render, name), bool):
                setattr(scene.render, name, False)
        scene.render.resolution_percentage, scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = 100, 1, 1
        scene.display_settings.display_device = "sRGB"
        scene.view_settings.view_transform, scene.view_settings.look = "Standard", "None"
        scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
        layer = scene.view_layers[0]
        layer.use_pass_z = job.depth or job.position  # depth also tells the position pass's background
        layer.use_pass_position = job.position

        arrays = job.scene
        self.garment = _mesh_object(bpy, scene, "garment", arrays["garment_positions"][0], arrays["garment_faces"])
        uv = self.garment.data.uv_layers.new(name="UVMap")  # loops are the faces' corners in order
        uv.data.foreach_set("uv", arrays["garment_uv"].astype(np.float32).ravel())
        cloth, self.cloth_bsdf = _principled(bpy, "cloth")
        texture = cloth.node_tree.nodes.new("ShaderNodeTexImage")
        texture.image = bpy.data.images.load(str(job.texture), check_existing=True)
        cloth.node_tree.links.new(texture.outputs["Color"], self.cloth_bsdf.inputs["Base Color"])
        cloth.node_tree.nodes.active = texture  # what Workbench's texture colour shows
        self.garment.data.materials.append(cloth)
        self.body = self.skin_bsdf = None
        if "body_vertices" in arrays:
            self.body = _mesh_object(bpy, scene, "body", arrays["body_vertices"][0], arrays["body_faces"])
            self.skin, self.skin_bsdf = _principled(bpy, "skin")
            self.skin_bsdf.inputs["Roughness"].default_value = SKIN_ROUGHNESS
            _input(self.skin_bsdf, "Subsurface Weight", "Subsurface").default_value = SKIN_SUBSURFACE
            self.body.data.materials.append(self.skin)

        camera = bpy.data.cameras.new("camera")
        camera.clip_start, camera.clip_end = CLIP_START_M, CLIP_END_M
        self.camera = bpy.data.objects.new("camera", camera)
        scene.collection.objects.link(self.camera)
        scene.camera = self.camera
        self.worlds = {"hdri": self._hdri_world(), "sky": self._sky_world()}

    def _world(self, name: str, texture_type: str):
        world = self.bpy.data.worlds.new(name)
        if world.node_tree is None:  # as for materials
            world.use_nodes = True
        world.cycles.sampling_method, world.cycles.sample_map_resolution = "MANUAL", WORLD_MAP_RESOLUTION
        nodes, links = world.node_tree.nodes, world.node_tree.links
        texture = nodes.new(texture_type)
        links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
        return world, texture

    def _hdri_world(self):
        world, texture = self._world("hdri", "ShaderNodeTexEnvironment")
        nodes, links = world.node_tree.nodes, world.node_tree.links
        mapping = nodes.new("ShaderNodeMapping")
        links.new(nodes.new("ShaderNodeTexCoord").outputs["Generated"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], texture.inputs["Vector"])
        return world

    def _sky_world(self):
        world, texture = self._world("sky", "ShaderNodeTexSky")
        available = {item.identifier for item in texture.bl_rna.properties["sky_type"].enum_items}
        texture.sky_type = next(t for t in PHYSICAL_SKIES if t in available)
        return world

    def show(self, image: ImageSpec, environment_file: Path) -> None:
        """Pose garment and body at the image's frame, place the camera, set world, materials and seed."""
        arrays, matrix = self.job.scene, self.Matrix(image.transform.tolist())
        for obj, key in ((self.garment, "garment_positions"), (self.body, "body_vertices")):
            if obj is not None:
                obj.data.vertices.foreach_set("co", arrays[key][image.frame_index].astype(np.float32).ravel())
                obj.data.update()
                obj.matrix_world = matrix
        params = image.camera.blender_params()
        camera = self.camera.data
        camera.lens, camera.sensor_width = params["lens_mm"], params["sensor_width_mm"]
        camera.sensor_fit = params["sensor_fit"]
        camera.shift_x, camera.shift_y = params["shift_x"], params["shift_y"]
        self.camera.matrix_world = self.Matrix(params["matrix_world"])
        self.scene.render.resolution_x, self.scene.render.resolution_y = params["resolution_x"], params["resolution_y"]

        env = image.environment
        world = self.scene.world = self.worlds[env.kind]
        nodes = world.node_tree.nodes
        nodes["Background"].inputs["Strength"].default_value = env.strength
        if env.kind == "hdri":
            nodes["Environment Texture"].image = self.bpy.data.images.load(str(environment_file), check_existing=True)
            nodes["Mapping"].inputs["Rotation"].default_value = (0.0, 0.0, math.radians(env.rotation_deg))
        else:
            nodes["Sky Texture"].sun_elevation = math.radians(env.sun_elevation_deg)
            nodes["Sky Texture"].sun_rotation = math.radians(env.sun_rotation_deg)

        self.cloth_bsdf.inputs["Roughness"].default_value = image.cloth_roughness
        _input(self.cloth_bsdf, "Sheen Weight", "Sheen").default_value = image.cloth_sheen
        if self.skin_bsdf is not None:
            rgba = (*image.skin_rgb, 1.0)
            self.skin_bsdf.inputs["Base Color"].default_value = rgba
            subsurface_colour = _input(self.skin_bsdf, "Subsurface Color")  # 3.4; 5.0 uses the base colour
            if subsurface_colour is not None:
                subsurface_colour.default_value = rgba
            self.skin.diffuse_color = rgba  # Workbench
        if self.job.engine == "CYCLES":
            self.scene.cycles.seed = image.seed

    def render(self, image: ImageSpec, outputs: dict[str, Path]) -> None:
        """Render the shown image and write its outputs, each atomically."""
        bpy, settings = self.bpy, self.scene.render.image_settings
        try:
            bpy.ops.render.render()
        except RuntimeError as exc:
            raise RuntimeError(f"{image.where} ({image.name}): Blender failed to render: {exc}") from exc
        result = bpy.data.images["Render Result"]
        _image_format(settings, "PNG")
        settings.color_mode, settings.color_depth = "RGB", "8"
        with atomic_path(outputs["png"]) as tmp:
            result.save_render(str(tmp))
        if self.job.depth or self.job.position:
            _image_format(settings, "OPEN_EXR_MULTILAYER")
            settings.color_depth = "32"
            fd, multilayer = tempfile.mkstemp(prefix=f".{image.name}.", suffix=".passes.exr", dir=outputs["png"].parent)
            os.close(fd)
            try:
                result.save_render(multilayer)
                kwargs = {"multilayer": multilayer, "depth": _str(outputs.get("depth")),
                          "position": _str(outputs.get("position"))}
                if _process_links_openexr():
                    _split_in_subprocess(kwargs)
                else:
                    split_render_passes(**kwargs)
            finally:
                Path(multilayer).unlink(missing_ok=True)
        save_json(outputs["camera"], image.camera.to_dict())


def _image_format(settings, file_format: str) -> None:
    if hasattr(settings, "media_type"):  # Blender >= 5.0 filters file formats by media type
        settings.media_type = "MULTI_LAYER_IMAGE" if file_format == "OPEN_EXR_MULTILAYER" else "IMAGE"
    settings.file_format = file_format


def _str(path: Path | None) -> str | None:
    return None if path is None else str(path)


@dataclass(frozen=True)
class RenderReport:
    rendered: list[str]       # image names rendered by this call
    skipped: list[str]        # image names whose outputs were there already
    seconds: float            # the whole call
    setup_seconds: float      # of which reading the job and building the Blender scene


def render_job(job_path: str | os.PathLike, out_dir: str | os.PathLike, progress: bool = True,
               force: bool = False) -> RenderReport:
    """Render every image of the job at `job_path` into `out_dir` (see the module docstring).

    Images whose outputs all exist are skipped unless `force`.  Resets the Blender session to factory
    settings when anything is to be rendered."""
    start = time.perf_counter()
    job, out = load_job(job_path), Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done = set() if force else {image.name for image in job.images
                                if all(p.is_file() for p in job.outputs(image, out).values())}
    pending = [image for image in job.images if image.name not in done]
    skipped = [image.name for image in job.images if image.name in done]
    if skipped:
        log.info("%d of %d images already rendered in %s: skipped", len(skipped), len(job.images), out)
    if not pending:
        elapsed = time.perf_counter() - start
        return RenderReport([], skipped, elapsed, elapsed)
    scene = BlenderScene(job)
    environments = {image.name: _resolve_environment(job, image) for image in pending
                    if image.environment.kind == "hdri"}
    setup = time.perf_counter() - start
    log.info("%s: rendering %d images at %d x %d with %s (Blender %s)", job.path, len(pending),
             *job.resolution, scene.scene.render.engine, scene.bpy.app.version_string)
    for image in tqdm(pending, desc="render", unit="image", disable=not progress):
        scene.show(image, environments.get(image.name))
        scene.render(image, job.outputs(image, out))
    return RenderReport([image.name for image in pending], skipped, time.perf_counter() - start, setup)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="blender -b -P factory/render.py --  |  python factory/render.py",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--job", required=True, help="render job JSON (format above)")
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--force", action="store_true", help="render again images whose outputs exist")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_cli(lambda: render_job(args.job, args.out, progress=not args.no_progress, force=args.force),
                   failures=(RuntimeError,))


if __name__ == "__main__":
    # Under Blender the script's own arguments follow "--"; an exception escaping a `-P` script would
    # leave Blender's exit status at 0, so every failure becomes a status here.
    try:
        status = main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
    except Exception:
        logging.getLogger(__name__).exception("render failed")
        status = 1
    sys.exit(status)
