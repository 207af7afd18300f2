"""Calibrated multi-view images to complete, intersection-free 4D garment sequences.

    from reconstruction import CrosspointMap, GroundTruthCapture, GroundTruthConfig, triangulate_frame
    capture = GroundTruthCapture("out/capture")                  # a factory capture folder
    crosspoints = CrosspointMap.build(capture.template, 12)      # template level, mm
    config = GroundTruthConfig(noise_px=0.3)
    points = triangulate_frame(crosspoints, capture.cameras, capture.detections(frame, config),
                               frame=frame, source=config.source)   # -> CapturedPoints

The names below are imported on first use, so importing the package costs nothing (no OpenCV, no
warp, no torch).
"""

from importlib import import_module

_EXPORTS = {
    "read_cameras": "reconstruction.cameras",
    "undistort_pixels": "reconstruction.cameras",
    "validate_cameras": "reconstruction.cameras",
    "Views": "reconstruction.views",
    "CrosspointMap": "reconstruction.correspondence",
    "CapturedPoints": "reconstruction.points",
    "load_sequence": "reconstruction.points",
    "save_sequence": "reconstruction.points",
    "TriangulationConfig": "reconstruction.triangulate",
    "triangulate_frame": "reconstruction.triangulate",
    "triangulate_points": "reconstruction.triangulate",
    "triangulate_sequence": "reconstruction.triangulate",
    "NeighbourConfig": "reconstruction.consistency",
    "consistent_points": "reconstruction.consistency",
    "GroundTruthCapture": "reconstruction.groundtruth",
    "GroundTruthConfig": "reconstruction.groundtruth",
    "vertex_errors": "reconstruction.groundtruth",
    "RefineConfig": "reconstruction.refine",
    "RefinedSequence": "reconstruction.refine",
    "refine_sequence": "reconstruction.refine",
    "GarmentSequence": "reconstruction.export",
    "export_sequence": "reconstruction.export",
    "write_review_blend": "reconstruction.review",
    "build_review_scene": "reconstruction.review",
    "reconstruction_sequence": "reconstruction.review",
    "RunSettings": "reconstruction.pipeline",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'reconstruction' has no attribute {name!r}")
