"""Render a render job with Blender: RGB, depth and world-position images with the camera of each.

    blender -b -P factory/render.py -- --job JOB.json --out DIR      (a Blender executable, 3.4 or later)
    python factory/render.py --job JOB.json --out DIR                (a Python with the bpy module)
    from factory.render import render_job; render_job(job_path, out_dir)

The job's JSON format is in `factory.renderjob`.

Output per image in DIR: ``{name}.png`` (8-bit sRGB, view transform Standard), ``{name}_depth.exr``
(float32 channel Z: camera-frame depth in metres, as Blender's Z pass; +inf on the background),
``{name}_position.exr`` (float32 X, Y, Z world metres; NaN on the background; Cycles only) and
``{name}_camera.json``, and ``render.json``: the settings every image of DIR shares (size, engine,
samples, denoising, device, passes; `assets.fileio.record_stage`).  Every file is written under a
temporary name and renamed; an image whose outputs all exist is skipped unless `force`, and a job
of other settings into DIR is refused naming them unless `force` (which renders its images again).

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

import numpy as np
from tqdm import tqdm

from assets.cli import add_out, add_progress, progress, run_cli
from assets.fileio import atomic_path, record_stage, save_json
from factory.renderjob import ENGINES, ImageSpec, RenderJob, RenderJobError, load_job

log = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[1]
#: the record of what a folder's images were rendered with (`RenderJob.settings`)
RECORD = "render.json"
GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "METAL", "ONEAPI")  # preferred first
#: physical sky models, newest first (5.0 renamed Nishita and added multiple scattering)
PHYSICAL_SKIES = ("MULTIPLE_SCATTERING", "NISHITA", "SINGLE_SCATTERING")
#: camera clip range, metres; depth at or beyond CLIP_END_M (less a relative margin) is background
CLIP_START_M, CLIP_END_M, BACKGROUND_MARGIN = 0.01, 100.0, 1e-3
SKIN_SUBSURFACE, SKIN_ROUGHNESS = 0.1, 0.5
#: Cycles' importance map of the world, rebuilt for every image: the bundled maps are 1024 x 512, and
#: the automatic resolution costs 1-2 s per image on 2 cores (a 64 x 64 image renders in 0.1 s)
WORLD_MAP_RESOLUTION = 1024


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

    def __init__(self, job: RenderJob, threads: int = 0):
        bpy = self.bpy = _import_bpy()
        from mathutils import Matrix

        self.Matrix, self.job = Matrix, job
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = self.scene = bpy.context.scene
        _set_engine(scene, job)
        if threads > 0:  # a share of a machine (one Ray task's CPUs); 0: every core
            scene.render.threads_mode, scene.render.threads = "FIXED", threads
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
            # in the system's temporary folder, so a killed render leaves nothing in the output
            with tempfile.TemporaryDirectory(prefix="render-passes-") as scratch:
                multilayer = str(Path(scratch) / f"{image.name}.exr")
                result.save_render(multilayer)
                kwargs = {"multilayer": multilayer, "depth": _str(outputs.get("depth")),
                          "position": _str(outputs.get("position"))}
                if _process_links_openexr():
                    _split_in_subprocess(kwargs)
                else:
                    split_render_passes(**kwargs)
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
               force: bool = False, threads: int = 0) -> RenderReport:
    """Render every image of the job at `job_path` into `out_dir` (see the module docstring) with
    `threads` render threads (0: every core).

    Images whose outputs all exist are skipped unless `force`.  ``render.json`` in `out_dir` records the
    job's `RenderJob.settings`: a job of other settings is refused naming them (old -> new) unless
    `force`, which renders its images again and records the new settings.  Resets the Blender session to factory
    settings when anything is to be rendered."""
    start = time.perf_counter()
    job, out = load_job(job_path), Path(out_dir)
    # images of other settings are never taken for this job's: refused by name, or with `force` made again
    record_stage(out / RECORD, job.settings(), recompute=force)
    done = set() if force else {image.name for image in job.images
                                if all(p.is_file() for p in job.outputs(image, out).values())}
    pending = [image for image in job.images if image.name not in done]
    skipped = [image.name for image in job.images if image.name in done]
    if skipped:
        log.info("%d of %d images already rendered in %s: skipped", len(skipped), len(job.images), out)
    if not pending:
        elapsed = time.perf_counter() - start
        return RenderReport([], skipped, elapsed, elapsed)
    scene = BlenderScene(job, threads)
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
    add_out(parser, "output folder (created)")
    parser.add_argument("--force", action="store_true", help="render again images whose outputs exist")
    add_progress(parser)
    parser.add_argument("--threads", type=int, default=0, metavar="N",
                        help="render threads inside this one Blender process (Cycles' threads; default 0: every "
                        "core); not worker processes: a share of a machine, as a Ray task of the dataset build "
                        "renders with its CPUs")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_cli(lambda: render_job(args.job, args.out, progress=progress(args), force=args.force,
                                      threads=args.threads),
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
