"""Triangulation on synthetic cameras: exact without noise, bounded with noise, robust to outliers
and wrong marker IDs; a frame's detections on a real (small) template to CapturedPoints."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from assets.cameras import Camera
from assets.garments.markers import MarkerSurface
from assets.garments.template import Template
from networks.detections import Detections
from reconstruction.cameras import pinhole
from reconstruction.correspondence import CrosspointMap
from reconstruction.points import CapturedPoints, load_sequence, save_sequence
from reconstruction.triangulation import (TriangulationConfig, gather_views, merge_duplicates, triangulate_frame,
                                        triangulate_points)
from tests.assets.garment_fixtures import tube


def _ring(count=8, dist=(0.0,) * 5, radius=3.0):
    cameras = []
    for i in range(count):
        a = 2 * np.pi * i / count + 0.1
        base = Camera.look_at((radius * np.cos(a), radius * np.sin(a), 1.2 + 0.3 * (i % 2)), (0.0, 0.0, 1.0),
                              focal_mm=30.0, width=1280, height=960, name=f"cam{i:02d}")
        cameras.append(Camera(K=base.K, R=base.R, t=base.t, width=1280, height=960, dist=np.asarray(dist),
                              name=base.name))
    return cameras


def _scene(n=3000, seed=0, min_views=2, facing_only=True):
    """Points around (0, 0, 1) seen from a ring of 8 cameras, each by a random subset of at least
    `min_views` of the cameras (of those facing it, as the far side of a garment is hidden)."""
    rng = np.random.default_rng(seed)
    cameras = _ring()
    points = rng.uniform(-0.3, 0.3, (n, 3)) + [0.0, 0.0, 1.0]
    pixels = np.stack([c.project(points)[0] for c in cameras], axis=1)
    normal = np.c_[points[:, :2], np.zeros(n)]  # outward, as on a cylinder
    facing = np.stack([((c.center - points) * normal).sum(axis=1) > 0 for c in cameras], axis=1)
    observed = (facing | (not facing_only)) & (rng.random(facing.shape) < 0.7)
    keep = observed.sum(axis=1) >= min_views
    return cameras, points[keep], pixels[keep], observed[keep], rng


def test_exact_recovery_without_noise():
    cameras, points, pixels, observed, _ = _scene()
    result = triangulate_points(cameras, pixels, observed)
    assert result.valid.all()
    assert np.abs(result.xyz - points).max() < 1e-9
    np.testing.assert_array_equal(result.inliers, observed)
    assert result.reprojection_px.max() < 1e-6
    assert ((result.confidence > 0) & (result.confidence <= 1)).all()


def test_bounded_error_with_noise():
    cameras, points, pixels, observed, rng = _scene()
    noisy = pixels + rng.normal(0.0, 0.3, pixels.shape)
    result = triangulate_points(cameras, noisy, observed)
    assert result.valid.mean() > 0.999
    error = np.linalg.norm(result.xyz - points, axis=1)[result.valid]
    across = 0.3 * 3.0 / cameras[0].K[0, 0]  # 0.3 px is 0.84 mm across the view at 3 m
    assert np.median(error) < 1.5 * across and np.percentile(error, 99) < 5 * across
    # the refinement reaches the least-squares optimum (checked against scipy on a few points)
    for i in range(20):
        views = np.flatnonzero(observed[i])

        def residual(x):
            return np.concatenate([cameras[c].project(x[None])[0][0] - noisy[i, c] for c in views])

        optimum = least_squares(residual, points[i], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        assert np.square(residual(result.xyz[i])).sum() <= np.square(residual(optimum)).sum() + 1e-12
        assert np.abs(result.xyz[i] - optimum).max() < 1e-8
    assert 0.1 < np.median(result.reprojection_px[result.valid]) < 0.3
    assert (result.inliers[result.valid] == observed[result.valid]).mean() > 0.999
    more = result.inliers.sum(axis=1)
    assert result.confidence[more >= 4].mean() > result.confidence[more == 2].mean()


def test_wrong_observations_are_rejected_and_the_point_is_still_right():
    cameras, points, pixels, observed, rng = _scene(n=1000, min_views=5, facing_only=False)
    n = len(points)
    # in each point, one or two of its views are wrong: a gross error of 20 to 300 px (a wrong
    # crosspoint, or the crosspoint of another marker read under this one's ID)
    wrong = np.zeros_like(observed)
    for k in range(2):
        pick = rng.random(n) < (1.0 if k == 0 else 0.5)
        choice = np.array([rng.choice(np.flatnonzero(o & ~w)) for o, w in zip(observed, wrong)])
        wrong[np.flatnonzero(pick), choice[pick]] = True
    angle = rng.uniform(0, 2 * np.pi, observed.shape)
    offset = rng.uniform(20, 300, observed.shape)[..., None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    corrupted = np.where(wrong[..., None], pixels + offset, pixels)
    result = triangulate_points(cameras, corrupted, observed)
    assert result.valid.all()
    np.testing.assert_array_equal(result.inliers, observed & ~wrong)
    assert np.abs(result.xyz - points).max() < 1e-9
    # two views that disagree cannot make a point
    two = np.zeros_like(observed)
    two[:, :2] = True
    off_line = pixels.copy()
    off_line[:, 1] += [0.0, 40.0]
    assert not triangulate_points(cameras, off_line, two).valid.any()


def test_points_seen_along_one_line_are_dropped():
    """Two cameras 1 cm apart (0.2 degrees at 3 m), or facing each other across the point, do not
    fix it; a third view at a good angle does."""
    base = _ring(count=4)
    near, across = (Camera.look_at(eye, (0.0, 0.0, 1.0), focal_mm=30.0, width=1280, height=960, name=name)
                    for eye, name in ((base[0].center + [0.0, 0.0, 0.01], "near"),
                                      (2 * np.array([0.0, 0.0, 1.0]) - base[0].center, "across")))
    cameras = [base[0], near, across, base[1]]
    points = np.random.default_rng(3).uniform(-0.01, 0.01, (50, 3)) + [0.0, 0.0, 1.0]
    pixels = np.stack([c.project(points)[0] for c in cameras], axis=1)
    for views, valid in (([0, 1], False), ([0, 2], False), ([0, 1, 3], True)):
        observed = np.zeros((len(points), 4), bool)
        observed[:, views] = True
        result = triangulate_points(cameras, pixels, observed)
        assert (result.valid == valid).all(), views
        if not valid:
            assert result.angle_deg[~result.valid].size == 50 and np.isnan(result.xyz).all()
    assert triangulate_points(cameras, pixels, observed, TriangulationConfig(min_angle_deg=0.1)).valid.all()


def test_one_view_s_duplicate_observations_are_merged():
    key = np.array([5, 5, 7, 5, 9])
    pixels = np.array([[10.0, 10.0], [10.6, 10.0], [0.0, 0.0], [50.0, 50.0], [3.0, 4.0]])
    confidence = np.array([0.5, 1.0, 1.0, 0.9, 0.2])
    unique, merged, best = merge_duplicates(key, pixels, confidence, tolerance_px=2.0)
    assert unique.tolist() == [5, 7, 9]
    # key 5: the most confident (10.6, 10) averaged with (10, 10), which agrees; (50, 50) is dropped
    np.testing.assert_allclose(merged, [[(0.5 * 10 + 1.0 * 10.6) / 1.5, 10.0], [0.0, 0.0], [3.0, 4.0]])
    np.testing.assert_allclose(best, [1.0, 1.0, 0.2])


@pytest.fixture(scope="module")
def tube_scene():
    """The tube template's 12 mm level wrapped round a cylinder, seen by a ring of distorted cameras."""
    template = Template.build(tube(), dpi=150.0)
    tables = template.layout.tables()
    crosspoints = CrosspointMap.build(template, 12, tables)
    surface = MarkerSurface.build(template, 12, tables)
    level = template.level(12)
    first = np.zeros(level.num_sewn_vertices, np.int64)
    first[level.sewn_index[::-1]] = np.arange(level.num_vertices)[::-1]  # a sewn vertex's first member
    xy, panel = level.pattern_xy[first], level.panel[first]
    angle = xy[:, 0] / 0.1 + np.pi * panel
    positions = np.c_[0.1 * np.cos(angle), 0.1 * np.sin(angle), 0.9 + xy[:, 1]]
    cameras = _ring(count=6, dist=(-0.2, 0.05, 0.001, -0.0005, 0.0))
    return template, crosspoints, surface, positions, cameras


def _detections(surface, positions, cameras, rng):
    """Every camera's detections of the markers facing it (about 4 of 6 cameras see each marker)."""
    _, xp = surface.points(positions)  # (M, K, K, 3)
    normals = surface.normals(positions)[1]
    out = []
    for camera in cameras:
        pixels = camera.project(xp.reshape(-1, 3))[0].reshape(xp.shape[:3] + (2,))
        with np.errstate(invalid="ignore"):
            facing = ((camera.center - xp) * normals).sum(axis=-1) > -0.05
        visible = facing & np.isfinite(pixels).all(axis=-1)
        keep = visible.any(axis=(1, 2))
        m = int(keep.sum())
        out.append(Detections(marker_id=surface.marker_id[keep].astype(np.int64),
                              confidence=rng.uniform(0.8, 1.0, m).astype(np.float32),
                              points_px=np.zeros((m, 5, 2), np.float32),
                              crosspoints_px=pixels[keep].astype(np.float32),
                              crosspoint_visible=visible[keep], partial=np.zeros(m, bool)))
    return out


def test_a_frame_of_detections_becomes_captured_points(tube_scene, tmp_path):
    template, crosspoints, surface, positions, cameras = tube_scene
    rng = np.random.default_rng(7)
    detections = _detections(surface, positions, cameras, rng)
    # camera 0 reads marker A as marker B, which it does not see itself and which is not on the same
    # line of sight (where a wrong ID is no outlier), and it sees an ID of no garment
    seen = [set(d.marker_id.tolist()) for d in detections]
    centre = cameras[0].project(surface.points(positions)[0][:, 0])[0]  # IDs are rows here
    a, b = next((a, b) for a in sorted(seen[0]) for b in sorted(set().union(*seen[1:]) - seen[0])
                if sum(b in s for s in seen[1:]) >= 3 and np.linalg.norm(centre[a] - centre[b]) > 15)
    ids = detections[0].marker_id.copy()
    ids[np.flatnonzero(ids != a)[0]] = 4000
    ids[ids == a] = b
    detections[0] = Detections(**{**detections[0].to_dict(), "marker_id": ids})
    # float32 pixels: exact up to their rounding (6e-5 px at 1280 px, 2e-7 m at 3 m)
    points = triangulate_frame(crosspoints, cameras, detections, frame=12, source="test")
    assert isinstance(points, CapturedPoints) and points.frame == 12 and points.source == "test"
    assert points.level_mm == 12 and points.views.shape == (len(points), 6)
    truth = crosspoints.points(positions, points.key)
    assert np.abs(points.xyz - truth).max() < 1e-6
    face, bary = crosspoints.locate(points.key)
    np.testing.assert_array_equal(points.face, face)
    np.testing.assert_array_equal(points.bary, bary)
    # B's crosspoints got their 3D points from the other cameras; camera 0's impostor views are out
    row = np.searchsorted(crosspoints.marker_id, b)
    b_keys = crosspoints.flat(np.c_[np.full(25 * 25, crosspoints.panel[row]),
                                    crosspoints.crosspoint_index[row].reshape(-1)])
    mine = np.isin(crosspoints.flat(points.key), b_keys)
    assert mine.sum() > 100 and not points.views[mine, 0].any()
    gathered = gather_views(crosspoints, cameras, detections)
    assert gathered.observed[np.isin(gathered.flat, b_keys), 0].sum() > 100  # they were there, and rejected
    # every crosspoint in >= 2 views of the camera's detections is captured, with exact views
    assert len(points) > 0.9 * len(np.unique(crosspoints.flat(points.key)))
    assert (points.reprojection_px < 1e-3).all() and ((points.confidence > 0) & (points.confidence <= 1)).all()
    # the file round trip, and a sequence of them
    points.save(tmp_path / "points.npz")
    again = CapturedPoints.load(tmp_path / "points.npz")
    for name in ("key", "xyz", "face", "bary", "views", "reprojection_px", "confidence"):
        np.testing.assert_array_equal(getattr(again, name), getattr(points, name))
    assert (again.level_mm, again.frame, again.source) == (12, 12, "test")
    half = points.select(points.confidence > np.median(points.confidence))
    assert 0 < len(half) < len(points) and half.source == "test"
    save_sequence(tmp_path / "seq", [points, CapturedPoints.empty(12, 6, frame=13, source="test")])
    frames = load_sequence(tmp_path / "seq")
    assert [p.frame for p in frames] == [12, 13] and len(frames[0]) == len(points) and len(frames[1]) == 0


def test_distortion_is_undone_before_triangulating(tube_scene):
    """The same scene seen through the pinhole twins gives the same points: undistortion is exact."""
    _, crosspoints, surface, positions, cameras = tube_scene
    distorted = triangulate_frame(crosspoints, cameras, _detections(surface, positions, cameras,
                                                                     np.random.default_rng(1)))
    plain = [pinhole(c) for c in cameras]
    straight = triangulate_frame(crosspoints, plain, _detections(surface, positions, plain, np.random.default_rng(1)))
    np.testing.assert_array_equal(distorted.key, straight.key)
    assert np.abs(distorted.xyz - straight.xyz).max() < 1e-6


def test_captured_points_check_their_arrays(tmp_path):
    good = CapturedPoints.empty(4, 3)
    with pytest.raises(ValueError, match=r"CapturedPoints.xyz: expected shape \(0, 3\) float64, got \(0, 3\) float32"):
        CapturedPoints(**{**{k: getattr(good, k) for k in ("level_mm", "key", "face", "bary", "views",
                                                            "reprojection_px", "confidence")},
                          "xyz": np.zeros((0, 3), np.float32)})
    (tmp_path / "broken.npz").write_bytes(b"no zip")
    with pytest.raises(ValueError, match="broken.npz"):
        CapturedPoints.load(tmp_path / "broken.npz")
    with pytest.raises(ValueError, match="distinct, known"):
        save_sequence(tmp_path / "seq", [good])
