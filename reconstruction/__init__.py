"""Calibrated multi-view images to complete, intersection-free 4D garment sequences.

    import reconstruction
    settings = reconstruction.RunSettings(template="out/capture/template.npz", detections="groundtruth",
                                          noise_px=0.3, initial_shape="out/capture/sim/dressed.npz")
    evaluation = reconstruction.run("out/rec", "out/capture", settings, evaluate_against="out/capture")

The stages over one output folder (`reconstruction.pipeline`; ``python -m reconstruction`` is their CLI),
each resumable, each recording its settings there and refusing a rerun with others:
- `run`: every stage below in order; `start`: create or reopen a folder with its `RunSettings`
  (``run.json``), which `settings_of` reads back;
- `detect`: views (through the networks, or a factory capture's ground truth) -> detections;
- `triangulate`: detections -> captured points per frame (`TriangulationConfig`);
- `refine`: captured points -> the complete, intersection-free sequence (`RefineConfig`);
- `export`: the sequence as npz, OBJ, PLY and PC2, and the review .blend (`write_review`: Blender in a
  process of its own; `sequence_of` reads a folder's sequence back for review);
- `evaluate`: accuracy against a factory capture's ground truth (`DEFINITIONS` of its fractions).

The parts they are made of, for use on plain data:
- cameras: `read_cameras` (cameras.json or OpenCV YAML), `validate_cameras`, `undistort_pixels`;
  `Views`: the frames of each camera (image folders or videos, shifted by per-camera frame offsets:
  `read_offsets`, `write_offsets`, `estimate_offsets` from motion; `VideoReader` reads a video
  frame-accurately, `extract_frames` a capture's videos as folders of frames); other tools' calibrations
  (EasyMocap, anipose / caliscope TOML, multical, COLMAP text) by `read_calibration` and
  `write_calibration`, the format found by `detect_format`; a rig calibrated from ChArUco board
  images by `calibrate_rig` (a `CharucoBoard`, `RigCalibrationConfig`); a rig refined from the
  garment's own crosspoints by bundle adjustment, `self_calibrate` (or `self_calibrate_detections` from
  a frame's detections; `SelfCalibrationConfig`);
- correspondence: `CrosspointMap` (template crosspoints <-> marker IDs and grid cells);
- triangulation: `triangulate_points`, `triangulate_frame`, `triangulate_sequence` -> `CapturedPoints`
  (`save_sequence`, `load_sequence`); `NeighbourConfig` and `consistent_points`, the pattern-neighbour
  check of a frame's points;
- ground truth: `GroundTruthCapture` (a factory capture's exact observations, `GroundTruthConfig` for
  noise and dropout), `vertex_errors`;
- refinement: `refine_sequence` -> `RefinedSequence`; `load_initial_shape`;
- exports: `GarmentSequence` (from a `RefinedSequence` by `from_refined`), `export_sequence`.

The review in Blender (`reconstruction.review`) imports bpy and is not re-exported here: the Blender
add-on and the export stage's own process import it.  The names above are imported on first use, so
importing the package costs nothing (no OpenCV, warp, torch or bpy).
"""

from assets.lazy import lazy_api

_EXPORTS = {
    "RunSettings": "reconstruction.pipeline",
    "run": "reconstruction.pipeline",
    "start": "reconstruction.pipeline",
    "settings_of": "reconstruction.pipeline",
    "detect": "reconstruction.pipeline",
    "triangulate": "reconstruction.pipeline",
    "refine": "reconstruction.pipeline",
    "export": "reconstruction.pipeline",
    "write_review": "reconstruction.pipeline",
    "sequence_of": "reconstruction.pipeline",
    "evaluate": "reconstruction.evaluation",
    "DEFINITIONS": "reconstruction.evaluation",
    "read_cameras": "reconstruction.cameras",
    "undistort_pixels": "reconstruction.cameras",
    "validate_cameras": "reconstruction.cameras",
    "Views": "reconstruction.views",
    "VideoReader": "reconstruction.video",
    "read_offsets": "reconstruction.video_sync",
    "write_offsets": "reconstruction.video_sync",
    "estimate_offsets": "reconstruction.video_sync",
    "extract_frames": "reconstruction.video_extract",
    "read_calibration": "reconstruction.calibration_formats",
    "write_calibration": "reconstruction.calibration_formats",
    "detect_format": "reconstruction.calibration_formats",
    "CharucoBoard": "reconstruction.charuco",
    "RigCalibrationConfig": "reconstruction.charuco",
    "calibrate_rig": "reconstruction.charuco",
    "SelfCalibrationConfig": "reconstruction.selfcalibration",
    "self_calibrate": "reconstruction.selfcalibration",
    "self_calibrate_detections": "reconstruction.selfcalibration",
    "CrosspointMap": "reconstruction.correspondence",
    "CapturedPoints": "reconstruction.points",
    "load_sequence": "reconstruction.points",
    "save_sequence": "reconstruction.points",
    "TriangulationConfig": "reconstruction.triangulation",
    "triangulate_frame": "reconstruction.triangulation",
    "triangulate_points": "reconstruction.triangulation",
    "triangulate_sequence": "reconstruction.triangulation",
    "NeighbourConfig": "reconstruction.consistency",
    "consistent_points": "reconstruction.consistency",
    "GroundTruthCapture": "reconstruction.groundtruth",
    "GroundTruthConfig": "reconstruction.groundtruth",
    "vertex_errors": "reconstruction.groundtruth",
    "RefineConfig": "reconstruction.refinement",
    "RefinedSequence": "reconstruction.refinement",
    "refine_sequence": "reconstruction.refinement",
    "load_initial_shape": "reconstruction.refinement",
    "GarmentSequence": "reconstruction.exports",
    "from_refined": "reconstruction.exports",
    "export_sequence": "reconstruction.exports",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_api(__name__, {name: (module, name) for name, module in _EXPORTS.items()})
