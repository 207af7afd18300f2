"""Blender building blocks of the add-on: mesh objects from arrays, materials, animation, cameras.

Animation, the pattern material and cameras are `reconstruction.review`'s, the same code that writes
the review .blend, applied to the current scene:
- `animate`: positions (T, V, 3) played at scene frames `frames`, as relative shape keys keyframed
  0 -> 1 -> 0 (self-contained) or, for long or dense sequences, a Mesh Cache modifier reading a PC2
  file written beside the run's output (``<folder>/blender/<name>.pc2``), chosen by
  `reconstruction.review.choose_animation`;
- `set_material`: the texture through the mesh's UVs (`reconstruction.review`'s "garment" material);
- `add_cameras`: `assets.cameras.Camera.blender_params`, in a collection of their own.

Objects the add-on makes live in the "Cloth Capture" collection; importing again replaces an object's
mesh (and drops its old animation) instead of piling up copies.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

COLLECTION = "Cloth Capture"
SKIN_RGBA = (0.85, 0.64, 0.52, 1.0)
CLOTH_RGBA = (0.25, 0.45, 0.85, 1.0)


def collection(scene) -> bpy.types.Collection:
    """The add-on's collection in `scene` (created on first use)."""
    found = bpy.data.collections.get(COLLECTION)
    if found is None:
        found = bpy.data.collections.new(COLLECTION)
    if found.name not in scene.collection.children:
        scene.collection.children.link(found)
    return found


def mesh(name: str, vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray | None = None) -> bpy.types.Mesh:
    """A smooth-shaded triangle mesh: vertices (V, 3) metres, faces (F, 3), corner_uv (F, 3, 2) as UV
    map "UVMap" (origin bottom-left)."""
    faces = np.asarray(faces, dtype=np.int32)
    data = bpy.data.meshes.new(name)
    data.vertices.add(len(vertices))
    data.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    data.loops.add(faces.size)
    data.loops.foreach_set("vertex_index", faces.ravel())
    data.polygons.add(len(faces))
    data.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    data.polygons.foreach_set("use_smooth", np.ones(len(faces), dtype=bool))
    data.update()
    if corner_uv is not None:
        data.uv_layers.new(name="UVMap").data.foreach_set("uv", np.asarray(corner_uv, dtype=np.float32).ravel())
    return data


def put_object(scene, name: str, data: bpy.types.Mesh) -> bpy.types.Object:
    """Object `name` showing `data`: an existing mesh object of that name gets it (its old mesh with
    its shape keys and materials, and its modifiers go; its transform and visibility stay), else a new
    object is made in the add-on's collection."""
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "MESH":
        obj = bpy.data.objects.new(name, data)
        collection(scene).objects.link(obj)
        return obj
    old = obj.data
    obj.data = data
    obj.modifiers.clear()
    if old.users == 0:
        bpy.data.meshes.remove(old)
    if obj.name not in scene.objects:
        collection(scene).objects.link(obj)
    return obj


def remove_object(name: str) -> None:
    """Delete object `name` and its mesh when nothing else uses it."""
    obj = bpy.data.objects.get(name)
    if obj is None:
        return
    data = obj.data
    bpy.data.objects.remove(obj)
    if data is not None and data.users == 0 and isinstance(data, bpy.types.Mesh):
        bpy.data.meshes.remove(data)


def animate(obj: bpy.types.Object, positions: np.ndarray, frames: np.ndarray, fps: float, cache: Path) -> str:
    """Play positions (T, V, 3) on `obj` at scene frames `frames` (T,); returns the way chosen
    ("shape_keys" or "mesh_cache", which writes the PC2 file `cache`)."""
    from reconstruction.export import GarmentSequence, write_pc2
    from reconstruction.review import _animate_mesh_cache, _animate_shape_keys, choose_animation

    positions = np.asarray(positions)
    # review's animators read a sequence's positions and frames only: a face-less one carries them
    sequence = GarmentSequence(positions=positions, faces=np.zeros((0, 3), np.int32), corner_uv=np.zeros((0, 3, 2)),
                               captured=np.zeros(positions.shape[:2], bool), frames=np.asarray(frames), fps=fps)
    mode = choose_animation(sequence)
    if mode == "shape_keys":
        _animate_shape_keys(bpy, obj, sequence)
    else:
        write_pc2(cache, sequence.positions, float(sequence.frames[0]), float(sequence.frame_step))
        _animate_mesh_cache(obj, sequence, cache)
    return mode


def set_frames(scene, first: int, last: int, fps: float) -> None:
    """Scene frame range, rate (``fps / fps_base`` = `fps`) and the current frame (the first)."""
    scene.frame_start, scene.frame_end = int(first), int(last)
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps
    scene.frame_set(int(first))


def set_material(obj: bpy.types.Object, name: str, texture: Path | None,
                 rgba: tuple[float, float, float, float] = CLOTH_RGBA) -> bpy.types.Material:
    """Give `obj` one material `name`: the pattern `texture` through its UVs (reloaded from disk), or
    without a texture a plain one of colour `rgba`.  Materials it had that nothing else uses go."""
    old = list(obj.data.materials)
    if texture is not None:
        from reconstruction.review import _material

        material = _material(bpy, texture)
        material.node_tree.nodes.active.image.reload()
    else:
        material = bpy.data.materials.new(name)
        material.diffuse_color = rgba  # Solid shading
        if material.node_tree is not None:  # Blender 5.0 gives every material nodes
            material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = rgba
    obj.data.materials.clear()
    obj.data.materials.append(material)
    for previous in old:
        if previous is not None and previous.users == 0:
            bpy.data.materials.remove(previous)
    material.name = name
    return material


def add_cameras(scene, cameras: list, name: str) -> bpy.types.Collection | None:
    """`assets.cameras.Camera`s as Blender cameras in collection `name` (replacing one of that name);
    the scene's camera and resolution become the first's."""
    from reconstruction.review import _add_cameras

    old = bpy.data.collections.get(name)
    if old is not None:
        for obj in list(old.objects):
            data = obj.data
            bpy.data.objects.remove(obj)
            if data is not None and data.users == 0:
                bpy.data.cameras.remove(data)
        bpy.data.collections.remove(old)
    if not cameras:
        return None
    _add_cameras(bpy, scene, cameras, [camera.blender_params() for camera in cameras])
    made = scene.camera.users_collection[0]
    made.name = name
    return made


def load_image(path: Path, name: str) -> bpy.types.Image:
    """Image datablock `name` of `path` (read again from disk when it already exists)."""
    image = bpy.data.images.get(name)
    if image is not None and Path(bpy.path.abspath(image.filepath)).resolve() == path.resolve():
        image.reload()
        return image
    if image is not None:
        bpy.data.images.remove(image)
    image = bpy.data.images.load(str(path))
    image.name = name
    return image
