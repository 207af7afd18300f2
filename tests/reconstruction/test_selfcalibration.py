"""Self-calibration on synthetic cameras and points (no rendering): a perturbed rig is recovered from
its observations, its gauge is held as documented, and inputs it cannot use are refused by name."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.cameras import Camera
from reconstruction.selfcalibration import (SelfCalibrationConfig, perturb_cameras, project, self_calibrate,
                                           similarity_fit)
from reconstruction.triangulation import TriangulationConfig, triangulate_points


def _ring(count=6, dist=(0.0,) * 5):
    cameras = []
    for i in range(count):
        a = 2 * np.pi * i / count + 0.1
        base = Camera.look_at((3.0 * np.cos(a), 3.0 * np.sin(a), 1.0 + 0.4 * (i % 2)), (0.0, 0.0, 1.0),
                              focal_mm=30.0, width=1280, height=960, name=f"cam{i:02d}")
        cameras.append(Camera(K=base.K, R=base.R, t=base.t, width=1280, height=960, dist=np.asarray(dist),
                              name=base.name))
    return cameras


def _frames(cameras, frames=2, n=400, noise_px=0.0, seed=0):
    """Per frame (n, C, 2) detected pixels of points on a wavy cylinder around (0, 0, 1), each seen by
    the cameras facing it (70% of them), NaN elsewhere; and the points (frames, n, 3)."""
    rng = np.random.default_rng(seed)
    out, truth = [], []
    for f in range(frames):
        angle = rng.uniform(0, 2 * np.pi, n)
        radius = 0.25 + 0.03 * np.sin(5 * angle + f)
        points = np.c_[radius * np.cos(angle), radius * np.sin(angle), rng.uniform(0.7, 1.3, n)]
        normal = np.c_[np.cos(angle), np.sin(angle), np.zeros(n)]
        pixels = np.stack([project(c, points) for c in cameras], axis=1)
        pixels += rng.normal(0.0, noise_px, pixels.shape)
        seen = np.stack([((c.center - points) * normal).sum(axis=1) > 0 for c in cameras], axis=1)
        seen &= rng.random(seen.shape) < 0.9
        out.append(np.where(seen[..., None], pixels, np.nan))
        truth.append(points)
    return out, np.stack(truth)


def _perturb(cameras, seed=1, degrees=1.0, mm=10.0, focal=0.01):
    return perturb_cameras(cameras, np.random.default_rng(seed), degrees, mm, focal)


def _similarity_error(a, b):
    """Largest centre distance (m) and rotation difference (degrees) between rigs a and b after the
    similarity transform that best maps a's centres onto b's (the gauge self-calibration cannot see)."""
    s, Q, d = similarity_fit(np.stack([c.center for c in a]), np.stack([c.center for c in b]))
    centre = max(np.linalg.norm(s * Q @ x.center + d - y.center) for x, y in zip(a, b))
    angle = max(np.degrees(Rotation.from_matrix(x.R @ Q.T @ y.R.T).magnitude()) for x, y in zip(a, b))
    return centre, angle


def _shape_error_mm(cameras, pixels, truth):
    """Median distance (mm) of the points triangulated with `cameras` from the truth, after the
    similarity transform that best maps them onto it."""
    found, true = [], []
    for frame, points in zip(pixels, truth):
        solved = triangulate_points(cameras, frame, np.isfinite(frame).all(axis=2),
                                    TriangulationConfig(threshold_px=np.inf, neighbours=None))
        found.append(solved.xyz[solved.valid])
        true.append(points[solved.valid])
    found, true = np.concatenate(found), np.concatenate(true)
    s, Q, d = similarity_fit(found, true)
    return 1000.0 * float(np.median(np.linalg.norm(s * found @ Q.T + d - true, axis=1)))


def test_perturbed_rig_is_recovered_exactly_without_noise():
    exact = _ring()
    pixels, _ = _frames(exact)
    perturbed = _perturb(exact)
    refined, report = self_calibrate(perturbed, pixels, SelfCalibrationConfig(focal=True))
    centre, angle = _similarity_error(refined, exact)
    assert centre < 1e-5 and angle < 1e-4, (centre, angle)
    for r, e in zip(refined, exact):
        assert r.K[0, 0] == pytest.approx(e.K[0, 0], rel=1e-6) and r.name == e.name
    assert report.rms_before_px > 5.0 and report.rms_after_px < 1e-3
    assert [c.name for c in report.cameras] == [c.name for c in exact]
    assert all(c.rms_after_px < 1e-3 and c.observations > 100 for c in report.cameras)
    json.dumps(report.to_dict())  # the CLI writes it


def test_noisy_observations_restore_the_shape_of_the_exact_rig():
    """With 0.3 px noise the focal length and the distance to the garment trade against each other
    (a 1% focal change moves its image by less than the noise), so the measure is what the cameras
    are for: the triangulated points, within 10% of the exact cameras' error."""
    exact = _ring()
    pixels, truth = _frames(exact, noise_px=0.3, seed=2)
    perturbed = _perturb(exact, seed=3)
    refined, report = self_calibrate(perturbed, pixels, SelfCalibrationConfig(focal=True))
    exact_mm, perturbed_mm, refined_mm = (_shape_error_mm(c, pixels, truth) for c in (exact, perturbed, refined))
    assert perturbed_mm > 5 * exact_mm and refined_mm < 1.1 * exact_mm, (exact_mm, perturbed_mm, refined_mm)
    # 2D noise of 0.3 px per axis is 0.42 px RMS in distance; the fit takes up part of it
    assert 0.2 < report.rms_after_px < 0.42 < report.rms_before_px / 10


def test_distortion_is_refined_when_asked():
    exact = _ring(dist=(-0.12, 0.05, 0.0, 0.0, 0.0))
    pixels, _ = _frames(exact, frames=3, n=600)
    start = [Camera(K=c.K, R=c.R, t=c.t, width=c.width, height=c.height, dist=(-0.08, 0.0, 0.0, 0.0, 0.0),
                    name=c.name) for c in _perturb(exact, seed=4, degrees=0.3, mm=3.0, focal=0.0)]
    refined, report = self_calibrate(start, pixels, SelfCalibrationConfig(distortion=True))
    assert report.rms_after_px < 1e-3
    for r in refined:
        assert r.dist[0] == pytest.approx(-0.12, abs=1e-4) and r.dist[1] == pytest.approx(0.05, abs=1e-3)


def test_reference_gauge_keeps_the_reference_pose_and_the_distance():
    exact = _ring()
    pixels, _ = _frames(exact)
    perturbed = _perturb(exact, seed=5, focal=0.0)
    refined, _ = self_calibrate(perturbed, pixels, SelfCalibrationConfig(keep="reference", reference="cam02"))
    assert np.allclose(refined[2].R, perturbed[2].R) and np.allclose(refined[2].t, perturbed[2].t)
    given = [np.linalg.norm(c.center - perturbed[2].center) for c in perturbed]
    far = int(np.argmax(given))
    assert np.linalg.norm(refined[far].center - refined[2].center) == pytest.approx(given[far], rel=1e-12)


def test_gross_outliers_are_dropped():
    exact = _ring()
    pixels, truth = _frames(exact, noise_px=0.2, seed=6)
    rng = np.random.default_rng(7)
    wrong = np.isfinite(pixels[0]) & (rng.random(pixels[0].shape) < 0.03)  # 3% of the views 40-80 px off
    pixels[0] = np.where(wrong, pixels[0] + rng.choice([-1, 1], wrong.shape) * rng.uniform(40, 80, wrong.shape),
                         pixels[0])
    refined, report = self_calibrate(_perturb(exact, seed=8), pixels, SelfCalibrationConfig(focal=True))
    assert wrong.any(axis=2).sum() <= report.outliers < 1.2 * wrong.any(axis=2).sum()
    clean = [np.where(wrong, np.nan, pixels[0])] + pixels[1:]
    assert _shape_error_mm(refined, clean, truth) < 1.1 * _shape_error_mm(exact, clean, truth)


def test_a_camera_without_observations_is_named():
    cameras = _ring()
    pixels, _ = _frames(cameras)
    for frame in pixels:
        frame[:, 4] = np.nan
    with pytest.raises(ValueError, match=r"'cam04' \(0\)"):
        self_calibrate(cameras, pixels)


def test_too_few_points_are_refused():
    cameras = _ring()
    pixels, _ = _frames(cameras, frames=1, n=400)
    with pytest.raises(ValueError, match=r"frames \[7\]: 10 crosspoints.*fewer than the 50"):
        self_calibrate(cameras, [pixels[0][:10]], SelfCalibrationConfig(min_points=50, min_observations=1), frames=[7])


def test_bad_shapes_and_settings_are_refused():
    cameras = _ring()
    with pytest.raises(ValueError, match=r"frame 0's pixels must be \(N, 6, 2\)"):
        self_calibrate(cameras, [np.zeros((10, 5, 2))])
    with pytest.raises(ValueError, match="reference camera 'nope'"):
        self_calibrate(cameras, _frames(cameras)[0], SelfCalibrationConfig(reference="nope"))
    with pytest.raises(ValueError, match="loss"):
        SelfCalibrationConfig(loss="l2")


@pytest.mark.slow  # the session's shared capture
def test_the_cli_refines_the_cameras_of_a_reconstruction_folder(capture_folder, tmp_path, capsys):
    from reconstruction import pipeline
    from reconstruction.__main__ import main
    from reconstruction.cameras import read_cameras

    exact = read_cameras(capture_folder / "cameras.json")
    perturbed = _perturb(exact, seed=9, degrees=2.0, mm=20.0, focal=0.0)
    out = tmp_path / "rec"
    pipeline.start(out, pipeline.RunSettings(template=str(capture_folder / "template.npz"), detections="groundtruth"))
    pipeline.detect(out, capture_folder, cameras=perturbed, progress=False)  # ground truth seen by a rig that is off
    argv = ["cameras", "selfcalibrate", "--run", str(out), "--out", str(tmp_path / "refined.json"),
            "--report", str(tmp_path / "report.json"), "--max-points", "3000"]
    assert main(argv) == 0
    assert "cameras written to" in capsys.readouterr().out
    refined = read_cameras(tmp_path / "refined.json")
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["frames"] == [3, 4] and [c.name for c in refined] == [c.name for c in exact]
    assert report["rms_before_px"] > 2.0 and report["rms_after_px"] < 0.01  # exact pixels
    assert report["points"] == 3000
    assert main([*argv[:4], "--frames", "3,9", "--out", str(tmp_path / "x.json")]) == 2
    assert "frames [9] have no detections" in capsys.readouterr().err
