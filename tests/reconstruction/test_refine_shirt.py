"""The post-processing on the default shirt's 12 mm template against a real simulated truth (the test
session's short walk, `shirt_run`): what a ring of cameras sees of two frames, less a patch of the back,
refined from the factory's dressed garment with that patch pushed through the front."""

import numpy as np

from assets.fileio import load_npz
from assets.garments.markers import face_normals
from factory.simulate import load_template
from reconstruction.anchors import LevelAnchoring
from reconstruction.intersections import count_intersections
from reconstruction.refinement import RefineConfig, load_initial_shape, refine_sequence
from tests.reconstruction.cylinder import captured_points, every_key, key_pattern_xy, sewn_pattern_xy


def seen_by_ring(anchoring: LevelAnchoring, positions: np.ndarray, key: np.ndarray, cameras: np.ndarray) -> np.ndarray:
    """(N,) bool: crosspoints whose outward face normal at least two cameras (C, 3) see within 72 degrees
    (no occlusion test: the inside of the shirt faces away from every camera anyway)."""
    points = anchoring.points_on(positions, key)
    normal = face_normals(positions, anchoring.sewn_faces)[anchoring.face[anchoring.rows(key)]]
    towards = cameras[None] - points[:, None]
    cosine = np.einsum("pcd,pd->pc", towards, normal) / np.linalg.norm(towards, axis=2)
    return (cosine > 0.3).sum(axis=1) >= 2


def test_the_shirt_is_completed_without_intersections(shirt_run):
    _, out, path = shirt_run
    template = load_template("shirt")
    truth = load_npz(path, required=("positions",))["positions"][-2:].astype(np.float64)
    anchoring = LevelAnchoring(template, 12)
    key = every_key(anchoring)
    centre = truth[0].mean(axis=0)
    angle = np.arange(8) * np.pi / 4
    cameras = np.stack([centre[0] + 3 * np.cos(angle), centre[1] + 3 * np.sin(angle), np.full(8, 1.3)], axis=1)
    back = [p.name for p in template.pattern.panels].index("back")
    panel, xy = key_pattern_xy(template, anchoring, key)
    back_centre = np.median(xy[panel == back], axis=0)
    hidden = (panel == back) & (np.linalg.norm(xy - back_centre, axis=1) < 0.06)
    rng = np.random.default_rng(0)
    captures = [captured_points(anchoring, truth[t], key[seen_by_ring(anchoring, truth[t], key, cameras) & ~hidden],
                                frame=t, noise=1e-4, rng=rng) for t in range(2)]
    initial, initial_mm = load_initial_shape(out / "dressed.npz")
    # plant an intersection: push the unseen patch of the back in through the front of the shirt
    faces = template.level(12).sewn_faces
    vertex_panel, vertex_xy = sewn_pattern_xy(template, 12)
    distance = np.where(vertex_panel == back, np.linalg.norm(vertex_xy - back_centre, axis=1), np.inf)
    patch = distance < 0.04
    inward = -face_normals(initial, faces)[np.isin(faces, np.flatnonzero(patch)).any(axis=1)].mean(axis=0)
    depth = np.ptp(initial @ inward) + 0.02  # through the whole shirt
    profile = np.where(patch, np.cos(np.pi * np.minimum(distance, 0.04) / 0.08) ** 2, 0.0)
    planted = initial + profile[:, None] * depth * inward
    assert count_intersections(planted, faces) > count_intersections(initial, faces) + 10

    config = RefineConfig(levels_mm=(12,), initial_weights=(1e2, 1e4, 1e6), initial_steps=15)
    result = refine_sequence(template, captures, config, progress=False,
                             initial_shape=planted, initial_level_mm=initial_mm)
    assert result.diagnostics[result.start_frame]["pass1"]["intersections_start"] > 10
    for t in range(2):
        report, captured = result.diagnostics[t], result.captured[t]
        assert report["intersections_after"] == 0
        assert count_intersections(result.positions[t].astype(np.float64), faces) == 0
        assert captured.mean() > 0.6 and not captured[patch].any()
        error = np.linalg.norm(result.positions[t] - truth[t], axis=1)
        assert np.median(error[captured]) < 1e-4  # noise 0.1 mm per coordinate, averaged by the fit
        assert np.median(error[patch]) < 0.01  # the unseen patch of the back: filled by the physics
