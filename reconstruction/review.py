"""Review of a reconstructed garment sequence in Blender (4.2+, 5.0): the review `.blend`, and the
scene building blocks it is made of, which the Blender add-on applies to the user's own scene.

This is reconstruction's one bpy module, a leaf: it imports bpy when imported, and no module of the
package imports it.  The pipeline's export stage runs it in a process of its own
(`reconstruction.pipeline.write_review`, ``python -m reconstruction.review``), so that a
reconstruction never loads bpy and a caller inside Blender keeps its open file (`write_review_blend`
resets bpy to factory settings first, discarding whatever the process had loaded in bpy).

    python -m reconstruction.review out/rec/export/sequence.npz out/review.blend \\
        --cameras out/rec/detections/cameras.json --texture out/texture.png

    # inside Blender: the review of a reconstruction folder in the current scene
    from reconstruction.pipeline import sequence_of
    from reconstruction.review import build_review_scene
    build_review_scene(bpy.context.scene, sequence_of("out/rec"), cache=Path("out/rec/garment.pc2"))

The review (`build_review_scene`; `write_review_blend` saves it as the one scene of a file):
- object "garment" (``name``): the sewn mesh at the first frame, smooth shaded, UV map "UVMap" (the
  template's corner UVs) and material "garment" (the pattern texture through the UVs when a texture is
  given, else the "captured" colours);
- the animation, one of (``animation``):
  * "shape_keys": a relative shape key per frame after the first (the basis is the first frame),
    its value keyframed 0 at the previous frame, 1 at its own and 0 at the next, linear in between:
    the .blend is self-contained and plays exactly the sequence's positions at its frames;
  * "mesh_cache": a Mesh Cache modifier reading a PC2 file (``cache``; `write_review_blend`:
    ``<path stem>.pc2`` beside the .blend, referred to relatively, so keep the two files together;
    `reconstruction.exports.write_pc2`), for long or dense sequences, where shape keys would bloat the
    file and slow Blender down;
  * "auto" (default): shape keys when T x V <= `SHAPE_KEY_MAX_VERTEX_FRAMES` (2e6: 6e6 floats, about
    24 MB in the file), else the mesh cache.  Measured with bpy 5.0 on the shirt (4 mm level, 58885
    vertices, 30 frames; 12 mm, 6579 vertices, 240 frames): shape keys write in 0.3-0.5 s, the file
    opens in 0.1 s and a frame evaluates in a few ms, so 2e6 keeps one to two seconds at 120 Hz of the
    12 mm level self-contained;
- mesh attributes: "captured", a point colour attribute (FLOAT_COLOR) of the first frame's flags
  (`CAPTURED_RGBA` captured, `FILLED_RGBA` filled by physics), shown by the viewport's Solid shading
  in Attribute colour mode, which the review sets; and "captured_fraction", a point FLOAT attribute,
  the fraction of frames in which each vertex was captured.  Per-frame flags are not animated (Blender
  cannot keyframe attributes; one attribute per frame would weigh as much as the positions): the
  per-frame PLY files and the npz carry them;
- custom properties on the object: "source" (where the 2D observations came from), "level_mm";
- the cameras (collection "cameras", `assets.cameras.Camera.blender_params`, so a camera's view is
  the captured image), each with its image size as custom properties "resolution_x", "resolution_y";
  the scene's camera and render resolution are the first camera's (Blender has one resolution per
  scene: set it to a camera's own size before looking through it);
- the scene's frame range (first to last capture frame number), current frame (the first) and frame
  rate (``render.fps / render.fps_base`` = the sequence's fps).

Building blocks (each works on the scene or object it is given): `new_mesh` (a triangle mesh from
arrays), `garment_object`, `garment_material`, `animate` (positions (T, V, 3) at frame numbers (T,)),
`add_cameras`, `set_frame_range`, `show_captured_colours`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

try:
    import bpy
    from mathutils import Matrix
except ImportError as exc:
    raise ImportError("reconstruction.review builds the review in Blender: it needs the bpy module "
                      "(pip install '.[factory]') or Blender's own Python") from exc

from assets.cameras import Camera, load_cameras
from assets.fileio import atomic_path
from reconstruction.exports import GarmentSequence, frame_step, load_sequence_npz, write_pc2

#: Shape keys store T x V x 3 floats in the .blend; above T x V of this, "auto" takes the mesh cache.
SHAPE_KEY_MAX_VERTEX_FRAMES = 2_000_000
ANIMATIONS = ("auto", "shape_keys", "mesh_cache")
#: Linear RGBA of the "captured" colour attribute.
CAPTURED_RGBA = (0.05, 0.5, 0.1, 1.0)
FILLED_RGBA = (0.8, 0.2, 0.03, 1.0)
CLIP_START_M, CLIP_END_M = 0.01, 100.0


def choose_animation(positions: np.ndarray, animation: str = "auto") -> str:
    """'shape_keys' or 'mesh_cache' for positions (T, V, 3) (see the module docstring)."""
    if animation not in ANIMATIONS:
        raise ValueError(f"animation must be one of {', '.join(ANIMATIONS)}, got {animation!r}")
    if animation != "auto":
        return animation
    frames, vertices = np.shape(positions)[:2]
    return "shape_keys" if frames * vertices <= SHAPE_KEY_MAX_VERTEX_FRAMES else "mesh_cache"


# ---- the review ------------------------------------------------------------------------------------
class ReviewScene(NamedTuple):
    """What `build_review_scene` made: the garment object, its animation ("shape_keys" or
    "mesh_cache") and the cameras' collection (None without cameras)."""

    garment: object
    animation: str
    cameras: object | None


def write_review_blend(path: str | os.PathLike, sequence: GarmentSequence, cameras: Sequence[Camera] | None = None,
                       texture: str | os.PathLike | None = None, animation: str = "auto",
                       sensor_width_mm: float = 36.0) -> list[Path]:
    """Write the review .blend of `sequence` to `path` atomically (and ``<path stem>.pc2`` with the
    mesh cache).  cameras: `assets.cameras.Camera` list (undistorted, square pixels); texture: the
    pattern PNG, referred to relatively (not packed).  Returns the written paths."""
    path = Path(path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cache = path.with_suffix(".pc2")
    review = build_review_scene(bpy.context.scene, sequence, cameras, texture, animation, cache,
                                sensor_width_mm=sensor_width_mm)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.unlink()  # Blender would keep the empty placeholder as a "<name>1" backup
        # absolute paths (texture, point cache) become relative to the file's folder (relative_remap)
        result = bpy.ops.wm.save_as_mainfile(filepath=str(tmp), check_existing=False, relative_remap=True)
        if "FINISHED" not in result:
            raise RuntimeError(f"{path}: Blender did not save the review file ({', '.join(sorted(result))})")
    return [path] + ([cache] if review.animation == "mesh_cache" else [])


def build_review_scene(scene, sequence: GarmentSequence, cameras: Sequence[Camera] | None = None,
                       texture: str | os.PathLike | None = None, animation: str = "auto",
                       cache: str | os.PathLike | None = None, name: str = "garment", collection=None,
                       cameras_name: str = "cameras", sensor_width_mm: float = 36.0) -> ReviewScene:
    """The review of `sequence` (module docstring) in bpy scene `scene`: object `name` in `collection`
    (default: the scene's own), animated (the mesh cache writes the PC2 file `cache`), the `cameras`
    in collection `cameras_name`, the scene's frame range and rate, Solid shading by the "captured"
    colours.  Bad input (cameras, texture, animation, no `cache` where one is needed) is refused before
    anything is made."""
    cameras = list(cameras or [])
    _camera_params(cameras, sensor_width_mm)
    if texture is not None and not Path(texture).is_file():
        raise FileNotFoundError(f"review: texture {texture} does not exist")
    mode = choose_animation(sequence.positions, animation)
    if mode == "mesh_cache":
        if cache is None:
            raise ValueError(f"review: {len(sequence)} frames of {sequence.num_vertices} vertices play from a mesh "
                             "cache: give the PC2 file's path (cache)")
        frame_step(sequence.frames, "review: frames")  # unevenly spaced frames are refused here, not midway
    garment = garment_object(scene, sequence, texture, name, collection)
    animate(garment, sequence.positions, sequence.frames, cache, mode)
    made = add_cameras(scene, cameras, cameras_name, sensor_width_mm) if cameras else None
    set_frame_range(scene, sequence.frames[0], sequence.frames[-1], sequence.fps)
    show_captured_colours(scene)
    return ReviewScene(garment, mode, made)


# ---- building blocks -------------------------------------------------------------------------------
def new_mesh(name: str, vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray | None = None):
    """A smooth-shaded triangle mesh (bpy.types.Mesh) `name`: vertices (V, 3) metres, faces (F, 3) (loops
    are the faces' corners in order), corner_uv (F, 3, 2) as UV map "UVMap" (origin bottom-left)."""
    faces = np.asarray(faces, dtype=np.int32)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("use_smooth", np.ones(len(faces), dtype=bool))
    mesh.update()
    if corner_uv is not None:
        mesh.uv_layers.new(name="UVMap").data.foreach_set("uv", np.asarray(corner_uv, dtype=np.float32).ravel())
    return mesh


def garment_object(scene, sequence: GarmentSequence, texture: str | os.PathLike | None = None,
                   name: str = "garment", collection=None):
    """The garment object `name` (mesh and material of that name too) at the sequence's first frame, with
    UVs, the "captured" and "captured_fraction" attributes, its material and custom properties; linked
    into `collection` (default: `scene`'s own)."""
    mesh = new_mesh(name, sequence.positions[0], sequence.faces, sequence.corner_uv)
    colour = mesh.color_attributes.new(name="captured", type="FLOAT_COLOR", domain="POINT")
    rgba = np.where(sequence.captured[0][:, None], CAPTURED_RGBA, FILLED_RGBA).astype(np.float32)
    colour.data.foreach_set("color", rgba.ravel())
    mesh.color_attributes.active_color = colour
    mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    fraction = mesh.attributes.new(name="captured_fraction", type="FLOAT", domain="POINT")
    fraction.data.foreach_set("value", sequence.captured.mean(axis=0).astype(np.float32))

    mesh.materials.append(garment_material(texture, name))
    obj = bpy.data.objects.new(name, mesh)
    obj["source"] = sequence.source
    obj["level_mm"] = sequence.level_mm
    (scene.collection if collection is None else collection).objects.link(obj)
    return obj


def garment_material(texture: str | os.PathLike | None = None, name: str = "garment"):
    """A new material `name`: the texture through UV map "UVMap" when given (read again from disk when
    Blender holds it already: a regenerated texture), else the "captured" colours."""
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender < 5.0 (5.0 gives every material nodes; use_nodes is deprecated)
        material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.8
    if texture is not None:
        source = nodes.new("ShaderNodeTexImage")
        source.image = bpy.data.images.load(str(Path(texture).resolve()), check_existing=True)
        source.image.reload()
    else:
        source = nodes.new("ShaderNodeVertexColor")
        source.layer_name = "captured"
    links.new(source.outputs["Color"], bsdf.inputs["Base Color"])
    nodes.active = source
    return material


def animate(obj, positions: np.ndarray, frames: np.ndarray, cache: str | os.PathLike | None = None,
            animation: str = "auto") -> str:
    """Play positions (T, V, 3) metres on mesh object `obj` (V vertices) at scene frames `frames` (T,)
    (increasing; evenly spaced for a mesh cache): by shape keys or by a Mesh Cache modifier reading the
    PC2 file `cache`, which it writes (`choose_animation`).  Returns the way chosen."""
    positions = np.asarray(positions, dtype=np.float32)
    frames = np.asarray(frames, dtype=np.int64)
    vertices = len(obj.data.vertices)
    if positions.ndim != 3 or positions.shape[1:] != (vertices, 3) or len(frames) != len(positions):
        raise ValueError(f"animate {obj.name}: positions must be (T, {vertices}, 3) with T = {len(frames)} frames, "
                         f"got {positions.shape}")
    if (np.diff(frames) <= 0).any():
        raise ValueError(f"animate {obj.name}: frames must increase, got {frames.tolist()[:10]}")
    mode = choose_animation(positions, animation)
    if mode == "shape_keys":
        _animate_shape_keys(obj, positions, frames.tolist())
        return mode
    if cache is None:
        raise ValueError(f"animate {obj.name}: a mesh cache needs the PC2 file's path (cache)")
    step = frame_step(frames, f"animate {obj.name}: frames")
    write_pc2(cache, positions, float(frames[0]), float(step))
    _animate_mesh_cache(obj, Path(cache), int(frames[0]), step)
    return mode


def _animate_shape_keys(obj, positions: np.ndarray, frames: list[int]) -> None:
    """One relative shape key per frame after the first, its value keyframed linearly 0 -> 1 -> 0."""
    if len(frames) == 1:
        return  # the mesh is the one frame
    obj.shape_key_add(name="Basis", from_mix=False)
    for t in range(1, len(frames)):
        key = obj.shape_key_add(name=f"f{frames[t]:06d}", from_mix=False)
        key.data.foreach_set("co", positions[t].ravel())
        for frame, value in zip(frames[t - 1:t + 2], (0.0, 1.0, 0.0)):
            key.value = value
            key.keyframe_insert("value", frame=frame)
    for fcurve in _fcurves(obj.data.shape_keys.animation_data.action):  # Bezier (the default) would ease
        for point in fcurve.keyframe_points:
            point.interpolation = "LINEAR"


def _fcurves(action) -> list:
    """The F-curves of `action`: in its layers' channel bags (Blender 4.4+; 5.0 has no
    ``action.fcurves``), else ``action.fcurves`` (4.2, 4.3)."""
    if getattr(action, "layers", None):
        return [fcurve for layer in action.layers for strip in layer.strips for bag in strip.channelbags
                for fcurve in bag.fcurves]
    return list(action.fcurves)


def _animate_mesh_cache(obj, pc2: Path, first_frame: int, step: int) -> None:
    """A Mesh Cache modifier playing `pc2`: in 'FRAME' time mode Blender reads sample
    ``frame_scale * scene_frame - frame_start`` (interpolated), so sample t plays at first + t * step."""
    modifier = obj.modifiers.new("capture", "MESH_CACHE")
    modifier.cache_format = "PC2"
    modifier.filepath = str(pc2.resolve())
    modifier.time_mode, modifier.play_mode, modifier.interpolation = "FRAME", "SCENE", "LINEAR"
    modifier.forward_axis, modifier.up_axis = "POS_Y", "POS_Z"  # the file is in Blender's axes already
    modifier.frame_scale = 1.0 / step
    modifier.frame_start = float(first_frame) / step


def _camera_params(cameras: Sequence[Camera], sensor_width_mm: float) -> list[dict]:
    """Every camera's `Camera.blender_params` (which refuses distortion); ValueError for a non-Camera."""
    for i, camera in enumerate(cameras):
        if not isinstance(camera, Camera):
            raise ValueError(f"review: cameras[{i}] must be an assets.cameras.Camera, got {type(camera).__name__}")
    return [camera.blender_params(sensor_width_mm) for camera in cameras]


def add_cameras(scene, cameras: Sequence[Camera], name: str = "cameras", sensor_width_mm: float = 36.0):
    """`assets.cameras.Camera`s (undistorted, square pixels) as Blender cameras in a new collection
    `name` of `scene` (returned); the scene's camera and render resolution become the first's."""
    params = _camera_params(cameras, sensor_width_mm)
    collection = bpy.data.collections.new(name)
    scene.collection.children.link(collection)
    objects = []
    for i, (camera, p) in enumerate(zip(cameras, params)):
        label = camera.name or f"camera{i:02d}"
        data = bpy.data.cameras.new(label)
        data.lens, data.sensor_width, data.sensor_fit = p["lens_mm"], p["sensor_width_mm"], p["sensor_fit"]
        data.shift_x, data.shift_y = p["shift_x"], p["shift_y"]
        data.clip_start, data.clip_end = CLIP_START_M, CLIP_END_M
        obj = bpy.data.objects.new(label, data)
        obj.matrix_world = Matrix(p["matrix_world"])
        obj["resolution_x"], obj["resolution_y"] = p["resolution_x"], p["resolution_y"]
        collection.objects.link(obj)
        objects.append(obj)
    if objects:
        scene.camera = objects[0]
        scene.render.resolution_x, scene.render.resolution_y = params[0]["resolution_x"], params[0]["resolution_y"]
        scene.render.resolution_percentage, scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = 100, 1, 1
    return collection


def set_frame_range(scene, first: int, last: int, fps: float) -> None:
    """`scene`'s frame range `first`..`last`, rate (``render.fps / render.fps_base`` = `fps`) and current
    frame (the first)."""
    scene.frame_start, scene.frame_end = int(first), int(last)
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps
    scene.frame_set(int(first))


def show_captured_colours(scene) -> None:
    """Solid shading in Attribute colour mode (the "captured" colours) in `scene`'s Workbench renders
    and in every 3D view."""
    shadings = [scene.display.shading]
    shadings += [space.shading for screen in bpy.data.screens for area in screen.areas
                 for space in area.spaces if space.type == "VIEW_3D"]
    for shading in shadings:
        shading.type, shading.color_type = "SOLID", "VERTEX"


# ---- the export stage's process ----------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    """``python -m reconstruction.review SEQUENCE BLEND [--cameras JSON] [--texture PNG]``: the review
    .blend of a sequence npz (`reconstruction.exports.save_sequence_npz`); the written paths go to
    stdout as one JSON line, last."""
    import math

    from assets.cli import run_cli

    parser = argparse.ArgumentParser(prog="python -m reconstruction.review", description=main.__doc__)
    parser.add_argument("sequence", help="the sequence npz (an export folder's sequence.npz)")
    parser.add_argument("blend", help="the .blend to write (a mesh cache goes beside it, <name>.pc2)")
    parser.add_argument("--cameras", help="cameras.json of the cameras to add (a reconstruction's "
                        "detections/cameras.json)")
    parser.add_argument("--texture", help="the garment's pattern texture PNG")
    parser.add_argument("--animation", choices=ANIMATIONS, default="auto", help="shape keys or a mesh cache")
    args = parser.parse_args(argv)

    def action() -> None:
        # the detect stage bounded the cameras' image sizes when it wrote them
        cameras = load_cameras(args.cameras, max_image_pixels=math.inf) if args.cameras else None
        written = write_review_blend(args.blend, load_sequence_npz(args.sequence), cameras, args.texture,
                                     args.animation)
        print(json.dumps([str(p) for p in written]))

    return run_cli(action, failures=(RuntimeError,))


if __name__ == "__main__":
    sys.exit(main())
