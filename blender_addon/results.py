"""Each stage's output folder -> objects in the current scene (run in Blender's main thread).

Frame numbers: scene frame = the stage's frame index, so a simulation's frame 0 (the dressed garment
at the start of the transition) is scene frame 0 and a capture's frame 121 is scene frame 121, and a
body, its simulated garment and their reconstruction line up on the timeline.

Objects (in the "Cloth Capture" collection; importing again replaces them):
  "Body"                    the posed body of a motion or of a simulation
  "<garment>"               a template level in its pre-dressing pose (panels placed around the body)
  "<garment> simulation"    the simulated garment
  "reconstruction"          a reconstructed sequence (`reconstruction.review.build_review_scene`'s
                            garment object: "captured" colours, "captured_fraction"; plus "error_mm"
                            and the "error" heat map against the ground truth,
                            `reconstruction.groundtruth.vertex_errors`; the evaluation's numbers and
                            their definitions in "clothcapture_evaluation", "clothcapture_definitions")
  "ground truth"            the capture's ground-truth garment, moved beside the reconstruction
Custom properties ``clothcapture_*`` on them say where they came from.
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy
import numpy as np

from reconstruction import review

from . import scene as build

BODY = "Body"
RECONSTRUCTION, GROUND_TRUTH = "reconstruction", "ground truth"
#: the error heat map's colour ramp (linear RGBA) from no error to its maximum and beyond
HEAT_STOPS = np.array([[0.02, 0.05, 0.6, 1.0], [0.0, 0.6, 0.2, 1.0], [0.9, 0.8, 0.0, 1.0], [0.8, 0.02, 0.02, 1.0]])


def _cache(folder: Path, name: str) -> Path:
    return folder / "blender" / f"{name}.pc2"


# ---- pattern ---------------------------------------------------------------------------------------
def import_pattern(folder: Path) -> bpy.types.Image:
    """The printable ``pattern.png`` as image "clothcapture pattern"."""
    return build.load_image(folder / "pattern.png", "clothcapture pattern")


def apply_pattern(obj: bpy.types.Object, folder: Path) -> bpy.types.Material:
    """The printable pattern of `folder` through `obj`'s UV map (the whole fabric over UV 0..1)."""
    if obj.type != "MESH" or not obj.data.uv_layers:
        raise ValueError(f"{obj.name}: needs a mesh with a UV map to carry the pattern")
    if not (folder / "pattern.png").is_file():
        raise ValueError(f"{folder}: no pattern.png yet: generate the pattern first")
    return build.set_material(obj, "clothcapture pattern", folder / "pattern.png")


# ---- body and motion -------------------------------------------------------------------------------
def _body_object(scene, vertices: np.ndarray, faces: np.ndarray, fps: float, folder: Path, source: str):
    obj = build.put_object(scene, BODY, review.new_mesh(BODY, vertices[0], faces))
    build.set_material(obj, "clothcapture skin", None, build.SKIN_RGBA)
    mode = review.animate(obj, vertices, np.arange(len(vertices)), _cache(folder, "body"))
    obj["clothcapture_source"] = source
    review.set_frame_range(scene, 0, len(vertices) - 1, fps)
    return obj, mode


def import_motion(scene, folder: Path) -> str:
    """``body_sequence.npz`` of `python -m assets.motion preview` as the animated "Body"."""
    from assets.fileio import load_json, load_npz

    data = load_npz(folder / "body_sequence.npz", required=("vertices", "faces", "fps"))
    summary = load_json(folder / "summary.json")
    obj, mode = _body_object(scene, data["vertices"], data["faces"], float(data["fps"]), folder, str(folder))
    obj["clothcapture_motion"] = summary["motion"]
    return f"{summary['motion']} on the {summary['body']} body: {summary['frames']} frames at {summary['fps']:g} Hz " \
           f"({mode.replace('_', ' ')})"


# ---- garment ---------------------------------------------------------------------------------------
def import_garment(scene, folder: Path, level_mm: int, name: str | None = None) -> bpy.types.Object:
    """Level `level_mm` of the template in `folder` (`python -m assets.garments build`) in its
    pre-dressing pose (`assets.garments.export.placed_positions`, as the CLI's meshes), textured with
    ``pattern_texture.png``; into object `name` (default: the garment's name)."""
    from assets.garments import Template
    from assets.garments.export import placed_positions

    template = Template.load(folder / "template.npz")
    level = template.level(level_mm)
    name = name or template.name
    data = review.new_mesh(name, placed_positions(template, level_mm), level.faces, level.uv[level.faces])
    obj = build.put_object(scene, name, data)
    build.set_material(obj, f"{template.name} pattern", folder / "pattern_texture.png")
    obj["clothcapture_template"] = str(folder / "template.npz")
    obj["clothcapture_level_mm"] = level_mm
    return obj


def import_simulation(scene, folder: Path) -> str:
    """``sequence.npz`` of `python -m factory.simulate`: the animated garment "<garment> simulation"
    (the template's UVs and texture when the garment is a built template, whose pre-dressing object
    is then hidden) and the body it collided with, posed from the sequence's body poses, as "Body"."""
    from assets.body import load_body
    from assets.fileio import load_npz
    from assets.garments.loading import load_template

    data = load_npz(folder / "sequence.npz", required=("positions", "faces", "body_poses", "body_trans",
                                                       "body_betas", "fps", "meta"))
    meta = json.loads(str(data["meta"]))
    spec, level_mm, fps = meta["garment_spec"], int(meta["level_mm"]), float(data["fps"])
    level = load_template(spec).level(level_mm)
    name = f"{meta['garment']} simulation"
    data_mesh = review.new_mesh(name, data["positions"][0], data["faces"], level.uv[level.faces])
    garment = build.put_object(scene, name, data_mesh)
    texture = Path(spec).parent / "pattern_texture.png" if spec.endswith(".npz") else None
    build.set_material(garment, f"{meta['garment']} simulation", texture if texture and texture.is_file() else None)
    frames = np.arange(len(data["positions"]))
    mode = review.animate(garment, data["positions"], frames, _cache(folder, "garment"))
    garment["clothcapture_simulation"] = str(folder)
    garment["clothcapture_level_mm"] = level_mm
    for placed in scene.objects:  # the template in its pre-dressing pose would hide the result
        if placed.get("clothcapture_template") == spec:
            placed.hide_render = True
            placed.hide_set(True, view_layer=scene.view_layers[0])
    posed = load_body(meta["body"]).pose(data["body_poses"], data["body_trans"], data["body_betas"])
    _body_object(scene, posed.vertices.astype(np.float32), posed.faces, fps, folder, str(folder))
    return f"{meta['garment']} on {meta['motion']}: {len(frames)} frames at {fps:g} Hz, max strain " \
           f"{meta.get('max_strain', 0.0):.3f}, max penetration {meta.get('max_penetration_mm', 0.0):.2f} mm " \
           f"({mode.replace('_', ' ')})"


# ---- render ----------------------------------------------------------------------------------------
def import_render(scene, folder: Path, rig: str) -> str:
    """A dataset's or capture's contact sheet as an image; a capture's cameras in "capture cameras"."""
    from assets.cameras import load_cameras

    sheet = folder / "contact_sheet.png"
    if sheet.is_file():
        build.load_image(sheet, f"{folder.name} contact sheet")
    if rig == "CAPTURE":
        cameras = load_cameras(folder / "cameras.json")
        build.add_cameras(scene, cameras, "capture cameras")
        return f"capture of {len(cameras)} cameras in {folder}"
    images = (folder / "manifest.jsonl").read_text().splitlines()
    return f"{len(images)} images in {folder}"


# ---- review ----------------------------------------------------------------------------------------
def import_reconstruction(scene, folder: Path, capture: Path | None, groundtruth_offset: float | None = None,
                          heatmap_max_mm: float | None = None, cameras: bool = True) -> str:
    """A reconstruction folder's sequence (`reconstruction.pipeline.sequence_of`: the export
    stage's, or the refined one when it was not exported) as "reconstruction"
    (`reconstruction.review.build_review_scene`: the capture's texture, "captured" colours, animated,
    the detect stage's cameras in "reconstruction cameras"); with the capture folder, its ground truth
    as "ground truth" moved `groundtruth_offset` m along X and the per-vertex error (attributes
    "error_mm" mean and "error_mm_max" over frames, colour "error" red at `heatmap_max_mm`)."""
    from reconstruction.pipeline import sequence_of, stage_cameras

    sequence = sequence_of(folder)
    texture = capture / "texture.png" if capture is not None and (capture / "texture.png").is_file() else None
    found = stage_cameras(folder) if cameras else None
    build.remove_object(RECONSTRUCTION)
    if cameras:
        build.remove_cameras("reconstruction cameras")
    made = review.build_review_scene(scene, sequence, found, texture, cache=_cache(folder, RECONSTRUCTION),
                                     name=RECONSTRUCTION, collection=build.collection(scene),
                                     cameras_name="reconstruction cameras")
    obj = made.garment
    obj["clothcapture_reconstruction"] = str(folder)
    numbers, definitions = read_evaluation(folder)
    if numbers:
        obj["clothcapture_evaluation"], obj["clothcapture_definitions"] = numbers, definitions
    coverage = f"garment coverage {numbers['garment_coverage']:.0%}" if "garment_coverage" in numbers else \
        f"{sequence.captured.mean():.0%} of the vertices captured, mean over frames"
    notes = [f"{len(sequence)} frames, {sequence.num_vertices} vertices at {sequence.level_mm} mm ({coverage})"]
    if capture is not None and (groundtruth_offset is not None or heatmap_max_mm is not None):
        notes += _compare(scene, obj, sequence, capture, folder, groundtruth_offset, heatmap_max_mm)
    if found is not None:
        notes.append(f"{len(found)} cameras")
    return "; ".join(notes)


def read_evaluation(folder: Path) -> tuple[dict, dict]:
    """The numbers of a reconstruction folder's ``evaluation.json`` summary (garment coverage,
    captured fraction, errors; those it could compute) and the definitions it gives of them; empty
    without an evaluation."""
    path = folder / "evaluation.json"
    if not path.is_file():
        return {}, {}
    evaluation = json.loads(path.read_text())
    numbers = {k: v for k, v in evaluation["summary"].items() if isinstance(v, (int, float))}
    return numbers, {k: v for k, v in evaluation.get("definitions", {}).items() if k in numbers}


def _compare(scene, obj, sequence, capture_dir: Path, folder: Path, offset: float | None,
             max_mm: float | None) -> list[str]:
    from reconstruction.groundtruth import GroundTruthCapture, vertex_errors

    capture = GroundTruthCapture(capture_dir)
    notes = []
    if offset is not None:
        garment = capture.garment
        level = capture.template.level(capture.level_mm)
        data = review.new_mesh(GROUND_TRUTH, garment["positions"][0], garment["faces"], level.uv[level.faces])
        truth = build.put_object(scene, GROUND_TRUTH, data)
        texture = capture_dir / "texture.png"
        build.set_material(truth, GROUND_TRUTH, texture if texture.is_file() else None)
        review.animate(truth, garment["positions"], garment["frames"], _cache(folder, "groundtruth"))
        truth.location = (offset, 0.0, 0.0)
        truth["clothcapture_capture"] = str(capture_dir)
        notes.append(f"ground truth beside at +{offset:g} m X")
    if max_mm is not None:
        errors = vertex_errors(capture, sequence.positions, sequence.frames, sequence.level_mm)
        mean, worst = errors.mean(axis=0), errors.max(axis=0)
        mesh = obj.data
        for name, values in (("error_mm", mean * 1e3), ("error_mm_max", worst * 1e3)):
            mesh.attributes.new(name=name, type="FLOAT", domain="POINT").data.foreach_set(
                "value", values.astype(np.float32))
        heat = mesh.color_attributes.new(name="error", type="FLOAT_COLOR", domain="POINT")
        heat.data.foreach_set("color", heat_colours(mean, max_mm).ravel())
        mesh.color_attributes.active_color = heat
        notes.append(f"error {np.median(mean) * 1e3:.2f} mm median, {worst.max() * 1e3:.2f} mm max")
    return notes


def heat_colours(error_m: np.ndarray, max_mm: float) -> np.ndarray:
    """Linear RGBA (N, 4) float32 of errors (N,) metres: blue at 0, green, yellow, red at `max_mm`."""
    t = np.clip(np.asarray(error_m) * 1e3 / max_mm, 0.0, 1.0) * (len(HEAT_STOPS) - 1)
    low = np.minimum(t.astype(int), len(HEAT_STOPS) - 2)
    w = (t - low)[:, None]
    return ((1 - w) * HEAT_STOPS[low] + w * HEAT_STOPS[low + 1]).astype(np.float32)
