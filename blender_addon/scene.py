"""Blender building blocks of the add-on: its collection, objects replaced in place, materials, cameras.

Meshes, animation, the pattern material, cameras and the scene's frame range are
`reconstruction.review`'s, the same code that writes the review .blend, applied to the current scene:
`review.new_mesh`, `review.animate` (positions (T, V, 3) at scene frames (T,): relative shape keys,
or for long or dense sequences a Mesh Cache modifier reading a PC2 file written beside the run's
output, ``<folder>/blender/<name>.pc2``), `review.garment_material`, `review.add_cameras`,
`review.set_frame_range`.

Objects the add-on makes live in the "Cloth Capture" collection; importing again replaces an object's
mesh (and drops its old animation) instead of piling up copies.
"""

from __future__ import annotations

from pathlib import Path

import bpy

from reconstruction import review

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


def put_object(scene, name: str, data: bpy.types.Mesh) -> bpy.types.Object:
    """Object `name` showing `data`: an existing mesh object of that name gets it (its old mesh with
    its shape keys, their animation and its materials, and its modifiers go; its transform and
    visibility stay), else a new object is made in the add-on's collection."""
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "MESH":
        obj = bpy.data.objects.new(name, data)
        collection(scene).objects.link(obj)
        return obj
    old = obj.data
    obj.data = data
    obj.modifiers.clear()
    _remove_unused_mesh(old)
    data.name = name  # (it was "<name>.001" beside the old one)
    if obj.name not in scene.objects:
        collection(scene).objects.link(obj)
    return obj


def remove_object(name: str) -> None:
    """Delete object `name`, and its mesh with what the mesh uses when nothing else uses them."""
    obj = bpy.data.objects.get(name)
    if obj is None:
        return
    data = obj.data
    bpy.data.objects.remove(obj)
    if isinstance(data, bpy.types.Mesh):
        _remove_unused_mesh(data)


def _remove_unused_mesh(mesh: bpy.types.Mesh) -> None:
    """Delete `mesh` when nothing uses it, and then its materials and its shape keys' animation when
    nothing else uses them (left behind, they would take their names from the next import's)."""
    if mesh.users != 0:
        return
    materials = [m for m in mesh.materials if m is not None]
    keys = mesh.shape_keys
    action = keys.animation_data.action if keys is not None and keys.animation_data is not None else None
    bpy.data.meshes.remove(mesh)
    for material in materials:
        if material.users == 0:
            bpy.data.materials.remove(material)
    if action is not None and action.users == 0:
        bpy.data.actions.remove(action)


def set_material(obj: bpy.types.Object, name: str, texture: Path | None,
                 rgba: tuple[float, float, float, float] = CLOTH_RGBA) -> bpy.types.Material:
    """Give `obj` one material `name`: the pattern `texture` through its UVs (reloaded from disk), or
    without a texture a plain one of colour `rgba`.  Materials it had that nothing else uses go."""
    old = list(obj.data.materials)
    if texture is not None:
        material = review.garment_material(texture, name)
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


def _uid(datablock) -> int:
    """A datablock's identity in this session (Blender < 4.0 has no `session_uid`: its address)."""
    return getattr(datablock, "session_uid", None) or datablock.as_pointer()


def objects_state() -> dict[int, int | None]:
    """Every object's identity -> its data's: what `made_since` compares."""
    return {_uid(obj): _uid(obj.data) if obj.data is not None else None for obj in bpy.data.objects}


def made_since(before: dict[int, int | None]) -> list[bpy.types.Object]:
    """The objects made, or given new data, since `before` (`objects_state`)."""
    return [obj for obj in bpy.data.objects
            if before.get(_uid(obj), -1) != (_uid(obj.data) if obj.data is not None else None)]


def show(scene, objects: list[bpy.types.Object]) -> None:
    """Make what an import made the selection, as Blender's importers do: its meshes (its cameras when
    it made no mesh) selected, the first active, the rest deselected, in every view layer of `scene`;
    and framed in every 3D view showing `scene` (not those looking through a camera)."""
    shown = [obj for obj in objects if obj.type == "MESH" and obj.visible_get()] or objects
    if not shown:
        return
    for layer in scene.view_layers:
        for obj in layer.objects:
            obj.select_set(obj in shown, view_layer=layer)
        layer.objects.active = shown[0]
    for window in bpy.context.window_manager.windows:
        if window.scene != scene:
            continue
        for area in window.screen.areas:
            region = next((r for r in area.regions if r.type == "WINDOW"), None)
            if area.type != "VIEW_3D" or region is None or area.spaces.active.region_3d.view_perspective == "CAMERA":
                continue
            with bpy.context.temp_override(window=window, area=area, region=region, scene=scene,
                                           view_layer=window.view_layer):
                bpy.ops.view3d.view_selected()


def remove_cameras(name: str) -> None:
    """Delete collection `name` with its camera objects (and their cameras that nothing else uses)."""
    old = bpy.data.collections.get(name)
    if old is None:
        return
    for obj in list(old.objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)
    bpy.data.collections.remove(old)


def add_cameras(scene, cameras: list, name: str) -> bpy.types.Collection | None:
    """`assets.cameras.Camera`s as Blender cameras in collection `name` (replacing one of that name;
    `review.add_cameras`); the scene's camera and resolution become the first's."""
    remove_cameras(name)
    return review.add_cameras(scene, cameras, name) if cameras else None


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
