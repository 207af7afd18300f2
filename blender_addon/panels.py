"""The "Cloth Capture" tab of the 3D view's sidebar: Pattern, Body & Motion, Garment, Render, Review.

Each panel shows its settings, its operators and its background runs: a progress bar with a cancel
button while a run is active, then its outcome (the imported result, or the error in red).
"""

from __future__ import annotations

import bpy

from . import commands, jobs, library
from .settings import FILE, UNAVAILABLE

_ICONS = {jobs.FINISHED: "CHECKMARK", jobs.FAILED: "ERROR", jobs.CANCELLED: "CANCEL"}


#: pixels of the sidebar's width that a label in a box cannot use (the panel's margins, the box, the
#: label's own padding), at UI scale 1
MARGIN_PX = 44


def wrap(text: str, width_px: float, scale: float = 1.0) -> list[str]:
    """`text` as lines that Blender's UI font at `scale` draws within `width_px` pixels: words stay whole
    where they fit; a longer one (a path) is cut, after a '/' where it can be."""
    import blf

    blf.size(0, bpy.context.preferences.ui_styles[0].widget.points * scale)

    def fits(line: str) -> bool:
        return blf.dimensions(0, line)[0] <= width_px

    lines: list[str] = []
    for word in text.split():
        if lines and fits(f"{lines[-1]} {word}"):
            lines[-1] += f" {word}"
            continue
        while len(word) > 1 and not fits(word):
            low, high = 1, len(word) - 1  # the longest prefix that fits (at least one character)
            while low < high:
                middle = (low + high + 1) // 2
                low, high = (middle, high) if fits(word[:middle]) else (low, middle - 1)
            cut = word.rfind("/", 1, low) + 1 or low
            lines.append(word[:cut])
            word = word[cut:]
        lines.append(word)
    return lines or [""]


def _lines(layout, text: str, context) -> None:
    """`text` as labels wrapped to the width of the region drawn (the sidebar, as wide as the user made it)."""
    scale = context.preferences.system.ui_scale or 1.0
    width = context.region.width if context.region is not None else 300
    for line in wrap(text, width - MARGIN_PX * scale, scale):
        layout.label(text=line)


def draw_jobs(layout, kind: str, context) -> None:
    """The runs of `kind`: progress and cancel while active, then the outcome (dismissable)."""
    for job in jobs.jobs(kind)[-3:]:
        box = layout.box()
        row = box.row(align=True)
        if job.active:
            text = job.progress_text or f"{job.label}: starting"
            if job.state == jobs.CANCELLING:
                text = f"{job.label}: cancelling"
            row.progress(factor=job.progress or 0.0, type="BAR", text=text)
            row.operator("clothcapture.cancel_job", text="", icon="CANCEL").job_id = job.id
            if job.status:
                _lines(box, job.status, context)
            continue
        row.label(text=f"{job.label}: {job.state.lower()} ({job.seconds:.0f} s)", icon=_ICONS[job.state])
        row.operator("clothcapture.dismiss_job", text="", icon="X").job_id = job.id
        column = box.column()
        column.alert = job.state == jobs.FAILED
        _lines(column, job.error if job.state == jobs.FAILED else job.message, context)
        if job.offered:
            box.operator("clothcapture.import_results", text="Import", icon="IMPORT").job_id = job.id


def _describe(layout, label: str, describe, context) -> None:
    """Lines naming what an operator will use (or, in red, why it cannot)."""
    column = layout.column(align=True)
    try:
        _lines(column, f"{label}: {describe()}", context)
    except ValueError as exc:
        column.alert = True
        _lines(column, str(exc), context)


def _why_empty(layout, value: str, module: str, context) -> None:
    """Why a list the project fills is empty (in red), when it is."""
    if value == UNAVAILABLE:
        try:
            library.project_module(module)
        except ValueError as exc:
            column = layout.column()
            column.alert = True
            _lines(column, str(exc), context)


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Cloth Capture"


class CLOTHCAPTURE_PT_main(_Panel, bpy.types.Panel):
    bl_label = "Cloth Capture"

    def draw(self, context):
        settings = context.scene.clothcapture
        self.layout.prop(settings, "output_dir")
        if settings.output_dir.startswith("//") and not bpy.data.filepath:
            _describe(self.layout, "Unsaved file: runs go to", lambda: commands.output_root(settings), context)


class CLOTHCAPTURE_PT_pattern(_Panel, bpy.types.Panel):
    bl_label = "Pattern"

    def draw(self, context):
        settings = context.scene.clothcapture
        pattern, layout = settings.pattern, self.layout
        column = layout.column(align=True)
        for name in ("pitch_mm", "seed", "dpi"):
            column.prop(pattern, name)
        row = layout.row(align=True)
        row.prop(pattern, "rows")
        row.prop(pattern, "cols")
        layout.operator("clothcapture.generate_pattern", icon="TEXTURE")
        layout.operator("clothcapture.apply_pattern", icon="MATERIAL")
        _describe(layout, "Into", lambda: commands.pattern_dir(settings), context)
        draw_jobs(layout, "pattern", context)


class CLOTHCAPTURE_PT_motion(_Panel, bpy.types.Panel):
    bl_label = "Body & Motion"

    def draw(self, context):
        settings = context.scene.clothcapture
        motion, layout = settings.motion, self.layout
        layout.prop(motion, "body_source")
        if motion.body_source == FILE:
            layout.prop(motion, "body_file")
        layout.prop(motion, "source")
        layout.prop(motion, "file" if motion.source == FILE else "builtin")
        if motion.source != FILE:
            _why_empty(layout, motion.builtin, "assets.motion.builtin", context)
        column = layout.column(align=True)
        if motion.source != FILE:
            column.prop(motion, "seconds")
            column.prop(motion, "speed")
        column.prop(motion, "fps")
        layout.prop(motion, "transition")
        layout.operator("clothcapture.import_motion", icon="ARMATURE_DATA")
        draw_jobs(layout, "motion", context)


class CLOTHCAPTURE_PT_garment(_Panel, bpy.types.Panel):
    bl_label = "Garment"

    def draw(self, context):
        settings = context.scene.clothcapture
        garment, layout = settings.garment, self.layout
        layout.prop(garment, "source")
        if garment.source == FILE:
            layout.prop(garment, "file")
        _why_empty(layout, garment.source, "assets.garments.defaults", context)
        row = layout.row(align=True)
        row.prop(garment, "level_mm")
        row.prop(garment, "texture_dpi")
        layout.operator("clothcapture.import_garment", icon="MOD_CLOTH")
        draw_jobs(layout, "garment", context)
        layout.separator()
        row = layout.row(align=True)
        row.prop(garment, "sim_frames")
        row.prop(garment, "sim_level_mm", text="")
        _describe(layout, "Garment", lambda: commands.garment_spec(settings), context)
        _describe(layout, "Into", lambda: commands.simulation_dir(settings), context)
        layout.operator("clothcapture.simulate", icon="PHYSICS")
        draw_jobs(layout, "simulation", context)


class CLOTHCAPTURE_PT_render(_Panel, bpy.types.Panel):
    bl_label = "Render"

    def draw(self, context):
        settings = context.scene.clothcapture
        render, layout = settings.render, self.layout
        layout.prop(render, "rig", expand=True)
        column = layout.column(align=True)
        column.prop(render, "frames")
        if render.rig == "CAPTURE":
            for name in ("first_frame", "cameras", "radius", "ring_height"):
                column.prop(render, name)
        else:
            for name in ("frame_step", "frame_list", "variations"):
                column.prop(render, name)
        layout.prop(render, "engine")
        column = layout.column(align=True)
        column.prop(render, "samples")
        column.prop(render, "denoise")
        row = column.row(align=True)
        row.prop(render, "width")
        row.prop(render, "height")
        column.prop(render, "texture_dpi")
        column.prop(render, "seed")
        layout.prop(render, "output_dir")
        _describe(layout, "Into", lambda: commands.render_dir(settings), context)
        layout.operator("clothcapture.render", icon="RENDER_ANIMATION")
        draw_jobs(layout, "render", context)


class CLOTHCAPTURE_PT_review(_Panel, bpy.types.Panel):
    bl_label = "Review"

    def draw(self, context):
        settings = context.scene.clothcapture
        review, layout = settings.review, self.layout
        layout.prop(review, "capture_dir")
        layout.prop(review, "reconstruction_dir")
        box = layout.box()
        box.prop(review, "detections")
        if review.detections == "groundtruth":
            row = box.row(align=True)
            row.prop(review, "noise_px")
            row.prop(review, "dropout")
        else:
            for name in ("localizer", "recognizer", "crosspoints"):
                box.prop(review, name)
        row = box.row(align=True)
        row.prop(review, "levels")
        row.prop(review, "neighbour_check")
        box.operator("clothcapture.reconstruct", icon="OUTLINER_OB_POINTCLOUD")
        draw_jobs(box, "reconstruction", context)
        row = layout.row(align=True)
        row.prop(review, "show_groundtruth")
        row.prop(review, "groundtruth_offset")
        row = layout.row(align=True)
        row.prop(review, "heatmap")
        row.prop(review, "heatmap_max_mm")
        layout.prop(review, "import_cameras")
        layout.operator("clothcapture.import_reconstruction", icon="IMPORT")
        reviewed = next((obj for obj in context.scene.objects if "clothcapture_evaluation" in obj), None)
        if reviewed is not None:
            box = layout.box()
            for line, definition in evaluation_lines(reviewed):
                box.label(text=line)
                if definition:
                    column = box.column(align=True)
                    column.enabled = False  # grey: the definition under its number
                    _lines(column, definition, context)


#: the evaluation's numbers shown first, in this order
_FIRST = ("garment_coverage", "captured_fraction")


def evaluation_lines(obj) -> list[tuple[str, str]]:
    """(number, its definition) per number of an imported reconstruction's evaluation
    (`results.read_evaluation`), named as ``evaluation.json`` names them: garment coverage first, then
    the captured fraction; fractions as percentages."""
    numbers = obj["clothcapture_evaluation"].to_dict()
    definitions = obj["clothcapture_definitions"].to_dict() if "clothcapture_definitions" in obj else {}
    keys = [k for k in _FIRST if k in numbers] + [k for k in numbers if k not in _FIRST]
    return [(f"{k}: {numbers[k]:.1%}" if k in _FIRST else f"{k}: {numbers[k]:.4g}", definitions.get(k, ""))
            for k in keys]


CLASSES = (CLOTHCAPTURE_PT_main, CLOTHCAPTURE_PT_pattern, CLOTHCAPTURE_PT_motion, CLOTHCAPTURE_PT_garment,
           CLOTHCAPTURE_PT_render, CLOTHCAPTURE_PT_review)
register, unregister = bpy.utils.register_classes_factory(CLASSES)
