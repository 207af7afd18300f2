"""A review `.blend` of a reconstructed garment sequence, written through bpy (Blender 4.2+, 5.0).

    from reconstruction.review import write_review_blend
    write_review_blend("out/review.blend", sequence, cameras=cameras, texture="out/texture.png")

The file holds one scene:
- object "garment": the sewn mesh at the first frame, smooth shaded, UV map "UVMap" (the template's
  corner UVs) and material "garment" (the pattern texture through the UVs when a texture is given,
  else the "captured" colours);
- the animation, one of (``animation``):
  * "shape_keys": a relative shape key per frame after the first (the basis is the first frame),
    its value keyframed 0 at the previous frame, 1 at its own and 0 at the next, linear in between:
    the .blend is self-contained and plays exactly the sequence's positions at its frames;
  * "mesh_cache": a Mesh Cache modifier reading ``<path stem>.pc2`` written beside the .blend
    (`reconstruction.export.write_pc2`; referred to relatively, so keep the two files together);
    for long or dense sequences, where shape keys would bloat the file and slow Blender down;
  * "auto" (default): shape keys when T x V <= `SHAPE_KEY_MAX_VERTEX_FRAMES` (2e6: 6e6 floats, about
    24 MB in the file), else the mesh cache.  Measured with bpy 5.0 on the shirt (4 mm level, 58885
    vertices, 30 frames; 12 mm, 6579 vertices, 240 frames): shape keys write in 0.3-0.5 s, the file
    opens in 0.1 s and a frame evaluates in a few ms, so 2e6 keeps one to two seconds at 120 Hz of the
    12 mm level self-contained;
- mesh attributes: "captured", a point colour attribute (FLOAT_COLOR) of the first frame's flags
  (`CAPTURED_RGBA` captured, `FILLED_RGBA` filled by physics), shown by the viewport's Solid shading
  in Attribute colour mode, which this file sets; and "captured_fraction", a point FLOAT attribute,
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

bpy is imported inside `write_review_blend` only; `write_review_blend` resets bpy to factory
settings first, so it discards whatever the process had loaded in bpy.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from assets.cameras import Camera
from assets.fileio import atomic_path
from reconstruction.export import GarmentSequence, write_pc2

#: Shape keys store T x V x 3 floats in the .blend; above T x V of this, "auto" takes the mesh cache.
SHAPE_KEY_MAX_VERTEX_FRAMES = 2_000_000
ANIMATIONS = ("auto", "shape_keys", "mesh_cache")
#: Linear RGBA of the "captured" colour attribute.
CAPTURED_RGBA = (0.05, 0.5, 0.1, 1.0)
FILLED_RGBA = (0.8, 0.2, 0.03, 1.0)
CLIP_START_M, CLIP_END_M = 0.01, 100.0


def _import_bpy():
    try:
        import bpy
    except ImportError as exc:
        raise RuntimeError("writing a review .blend needs the bpy module (pip install '.[factory]')") from exc
    return bpy


def choose_animation(sequence: GarmentSequence, animation: str = "auto") -> str:
    """'shape_keys' or 'mesh_cache' for `sequence` (see the module docstring)."""
    if animation not in ANIMATIONS:
        raise ValueError(f"animation must be one of {', '.join(ANIMATIONS)}, got {animation!r}")
    if animation != "auto":
        return animation
    return "shape_keys" if len(sequence) * sequence.num_vertices <= SHAPE_KEY_MAX_VERTEX_FRAMES else "mesh_cache"


def write_review_blend(path: str | os.PathLike, sequence: GarmentSequence, cameras: Sequence[Camera] | None = None,
                       texture: str | os.PathLike | None = None, animation: str = "auto",
                       sensor_width_mm: float = 36.0) -> list[Path]:
    """Write the review .blend of `sequence` to `path` atomically (and ``<path stem>.pc2`` with the
    mesh cache).  cameras: `assets.cameras.Camera` list (undistorted, square pixels); texture: the
    pattern PNG, referred to relatively (not packed).  Returns the written paths."""
    path = Path(path)
    mode = choose_animation(sequence, animation)
    cameras = list(cameras or [])
    for i, camera in enumerate(cameras):
        if not isinstance(camera, Camera):
            raise ValueError(f"write_review_blend: cameras[{i}] must be an assets.cameras.Camera, got "
                             f"{type(camera).__name__}")
    params = [camera.blender_params(sensor_width_mm) for camera in cameras]  # raises for distortion first
    if texture is not None and not Path(texture).is_file():
        raise FileNotFoundError(f"write_review_blend: texture {texture} does not exist")
    written = []
    if mode == "mesh_cache":
        written.append(path.with_suffix(".pc2"))
        write_pc2(written[-1], sequence.positions, float(sequence.frames[0]), float(sequence.frame_step))

    bpy = _import_bpy()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    garment = _garment_object(bpy, scene, sequence, texture)
    if mode == "shape_keys":
        _animate_shape_keys(bpy, garment, sequence)
    else:
        _animate_mesh_cache(garment, sequence, written[0])
    _add_cameras(bpy, scene, cameras, params)
    scene.frame_start, scene.frame_end = int(sequence.frames[0]), int(sequence.frames[-1])
    scene.render.fps = max(1, round(sequence.fps))
    scene.render.fps_base = scene.render.fps / sequence.fps
    scene.frame_set(int(sequence.frames[0]))
    _show_captured_colours(bpy)

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.unlink()  # Blender would keep the empty placeholder as a "<name>1" backup
        # absolute paths (texture, point cache) become relative to the file's folder (relative_remap)
        result = bpy.ops.wm.save_as_mainfile(filepath=str(tmp), check_existing=False, relative_remap=True)
        if "FINISHED" not in result:
            raise RuntimeError(f"{path}: Blender did not save the review file ({', '.join(sorted(result))})")
    return [path] + written


def _garment_object(bpy, scene, sequence: GarmentSequence, texture: str | os.PathLike | None):
    """The garment mesh object at the first frame, with UVs, colour attributes and its material."""
    faces = sequence.faces
    mesh = bpy.data.meshes.new("garment")
    mesh.vertices.add(sequence.num_vertices)
    mesh.vertices.foreach_set("co", sequence.positions[0].ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("use_smooth", np.ones(len(faces), dtype=bool))
    mesh.update()
    uv = mesh.uv_layers.new(name="UVMap")  # loops are the faces' corners in order
    uv.data.foreach_set("uv", sequence.corner_uv.ravel())

    colour = mesh.color_attributes.new(name="captured", type="FLOAT_COLOR", domain="POINT")
    rgba = np.where(sequence.captured[0][:, None], CAPTURED_RGBA, FILLED_RGBA).astype(np.float32)
    colour.data.foreach_set("color", rgba.ravel())
    mesh.color_attributes.active_color = colour
    mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    fraction = mesh.attributes.new(name="captured_fraction", type="FLOAT", domain="POINT")
    fraction.data.foreach_set("value", sequence.captured.mean(axis=0).astype(np.float32))

    mesh.materials.append(_material(bpy, texture))
    obj = bpy.data.objects.new("garment", mesh)
    obj["source"] = sequence.source
    obj["level_mm"] = sequence.level_mm
    scene.collection.objects.link(obj)
    return obj


def _material(bpy, texture: str | os.PathLike | None):
    """Material "garment": the texture through "UVMap" when given, else the "captured" colours."""
    material = bpy.data.materials.new("garment")
    if material.node_tree is None:  # Blender < 5.0 (5.0 gives every material nodes; use_nodes is deprecated)
        material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.8
    if texture is not None:
        source = nodes.new("ShaderNodeTexImage")
        source.image = bpy.data.images.load(str(Path(texture).resolve()), check_existing=True)
    else:
        source = nodes.new("ShaderNodeVertexColor")
        source.layer_name = "captured"
    links.new(source.outputs["Color"], bsdf.inputs["Base Color"])
    nodes.active = source
    return material


def _animate_shape_keys(bpy, obj, sequence: GarmentSequence) -> None:
    """One relative shape key per frame after the first, its value keyframed linearly 0 -> 1 -> 0."""
    frames = sequence.frames.tolist()
    if len(frames) == 1:
        return  # the mesh is the one frame
    obj.shape_key_add(name="Basis", from_mix=False)
    for t in range(1, len(frames)):
        key = obj.shape_key_add(name=f"f{frames[t]:06d}", from_mix=False)
        key.data.foreach_set("co", sequence.positions[t].ravel())
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


def _animate_mesh_cache(obj, sequence: GarmentSequence, pc2: Path) -> None:
    """A Mesh Cache modifier playing `pc2`: in 'FRAME' time mode Blender reads sample
    ``frame_scale * scene_frame - frame_start`` (interpolated), so sample t plays at frames[t]."""
    step = sequence.frame_step
    modifier = obj.modifiers.new("capture", "MESH_CACHE")
    modifier.cache_format = "PC2"
    modifier.filepath = str(pc2.resolve())
    modifier.time_mode, modifier.play_mode, modifier.interpolation = "FRAME", "SCENE", "LINEAR"
    modifier.forward_axis, modifier.up_axis = "POS_Y", "POS_Z"  # the file is in Blender's axes already
    modifier.frame_scale = 1.0 / step
    modifier.frame_start = float(sequence.frames[0]) / step


def _add_cameras(bpy, scene, cameras: list[Camera], params: list[dict]) -> None:
    from mathutils import Matrix

    collection = bpy.data.collections.new("cameras")
    scene.collection.children.link(collection)
    objects = []
    for i, (camera, p) in enumerate(zip(cameras, params)):
        name = camera.name or f"camera{i:02d}"
        data = bpy.data.cameras.new(name)
        data.lens, data.sensor_width, data.sensor_fit = p["lens_mm"], p["sensor_width_mm"], p["sensor_fit"]
        data.shift_x, data.shift_y = p["shift_x"], p["shift_y"]
        data.clip_start, data.clip_end = CLIP_START_M, CLIP_END_M
        obj = bpy.data.objects.new(name, data)
        obj.matrix_world = Matrix(p["matrix_world"])
        obj["resolution_x"], obj["resolution_y"] = p["resolution_x"], p["resolution_y"]
        collection.objects.link(obj)
        objects.append(obj)
    if objects:
        scene.camera = objects[0]
        scene.render.resolution_x, scene.render.resolution_y = params[0]["resolution_x"], params[0]["resolution_y"]
        scene.render.resolution_percentage, scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = 100, 1, 1


def _show_captured_colours(bpy) -> None:
    """Solid shading in Attribute colour mode (the "captured" colours) in every 3D view and in
    Workbench renders."""
    shadings = [bpy.context.scene.display.shading]
    shadings += [space.shading for screen in bpy.data.screens for area in screen.areas
                 for space in area.spaces if space.type == "VIEW_3D"]
    for shading in shadings:
        shading.type, shading.color_type = "SOLID", "VERTEX"
