"""Calibration files (cameras.json, OpenCV YAML / XML), their validation, and undistortion."""

import numpy as np
import pytest

from assets.cameras import Camera, save_cameras
from reconstruction.cameras import pinhole, read_cameras, undistort_pixels, validate_cameras, write_opencv


def _ring(count=3, dist=(0.0, 0.0, 0.0, 0.0, 0.0)):
    cameras = []
    for i in range(count):
        a = 2 * np.pi * i / count
        base = Camera.look_at((3 * np.cos(a), 3 * np.sin(a), 1.4), (0.0, 0.0, 1.0), focal_mm=30.0, width=640,
                              height=480, name=f"cam{i:02d}")
        K = base.K.copy()
        K[0, 1], K[1, 1], K[0, 2] = 0.3, K[1, 1] * 1.01, 317.25  # skew, non-square pixels, off-centre
        cameras.append(Camera(K=K, R=base.R, t=base.t, width=640, height=480, dist=np.asarray(dist),
                              name=base.name))
    return cameras


def _assert_same(a, b):
    assert (a.name, a.width, a.height) == (b.name, b.width, b.height)
    for key in ("K", "R", "t", "dist"):
        np.testing.assert_allclose(getattr(a, key), getattr(b, key), rtol=0, atol=1e-12)


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_opencv_files_round_trip(tmp_path, suffix):
    cameras = _ring(dist=(-0.21, 0.05, 0.001, -0.0005, 0.002))
    path = tmp_path / f"calibration{suffix}"
    write_opencv(path, cameras)
    again = read_cameras(path, pixel_centre=0.5)
    assert len(again) == 3
    for a, b in zip(cameras, again):
        _assert_same(a, b)


def test_cameras_json_is_read_and_validated(tmp_path):
    cameras = _ring()
    save_cameras(tmp_path / "cameras.json", cameras)
    for a, b in zip(cameras, read_cameras(tmp_path / "cameras.json")):
        _assert_same(a, b)


def test_an_opencv_calibration_of_one_camera_per_file(tmp_path):
    """OpenCV's own conventions: integer pixel centres, rvec / tvec, a 1 x 5 distortion row, sizes as
    image_size, translation in millimetres; the file's name names the camera."""
    camera = _ring(1, dist=(0.1, -0.02, 0.0, 0.0, 0.0))[0]
    rvec = np.array([0.1, -0.2, 0.3])
    import cv2

    R = cv2.Rodrigues(rvec)[0]
    K_cv = camera.K.copy()
    K_cv[:2, 2] -= 0.5
    (tmp_path / "left.yml").write_text(
        "%YAML:1.0\n---\n"
        f"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: {K_cv.reshape(-1).tolist()}\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        f"   data: {camera.dist.tolist()}\n"
        f"rvec: {rvec.tolist()}\n"
        "tvec: [100.0, -50.0, 2500.0]\n"
        "image_size: [640, 480]\n")
    (read,) = read_cameras(tmp_path / "left.yml", translation_scale=0.001)
    assert read.name == "left" and (read.width, read.height) == (640, 480)
    np.testing.assert_allclose(read.K, camera.K, atol=1e-12)
    np.testing.assert_allclose(read.R, R, atol=1e-12)
    np.testing.assert_allclose(read.t, [0.1, -0.05, 2.5], atol=1e-12)
    np.testing.assert_allclose(read.dist, camera.dist)
    # a list of such files gives the cameras in order; two with one name are refused
    (tmp_path / "right.yml").write_text((tmp_path / "left.yml").read_text())
    assert [c.name for c in read_cameras([tmp_path / "left.yml", tmp_path / "right.yml"])] == ["left", "right"]
    (tmp_path / "again.yml").write_text((tmp_path / "left.yml").read_text() + 'name: "left"\n')
    with pytest.raises(ValueError, match=r"duplicate camera names \['left'\]"):
        read_cameras([tmp_path / "left.yml", tmp_path / "again.yml"])


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("data: [1000.0, 0.0", "data: [0.0, 0.0"), r"bad\.yaml.*K must be .*invertible"),
    (lambda t: t.replace("image_width: 640\n", ""), r"bad\.yaml.*missing image_size / imageSize"),
    (lambda t: t.replace("R: [", "Rx: ["), r"bad\.yaml.*missing rvec / rotation_vector"),
    (lambda t: t.replace("data: [0.0, 0.0, 0.0, 0.0, 0.0]", "data: [0.0, 0.0, 0.0, 0.0, 0.0, 0.1]")
     .replace("cols: 5", "cols: 6"), r"bad\.yaml.*expected 4, 5, 8, 12 or 14 OpenCV distortion coefficients, got 6"),
    (lambda t: t.replace("T: [0.0, 0.0, 3.0]", "T: [0.0, 3.0]"), r"bad\.yaml.*T: expected 3 numbers, got 2"),
    (lambda t: t.replace("R: [1.0, 0.0, 0.0", "R: [2.0, 0.0, 0.0"), r"bad\.yaml.*R must be a rotation"),
])
def test_bad_opencv_files_name_the_file_and_field(tmp_path, edit, message):
    text = ("%YAML:1.0\n---\n"
            "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            "   data: [1000.0, 0.0, 320.0, 0.0, 1000.0, 240.0, 0.0, 0.0, 1.0]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
            "   data: [0.0, 0.0, 0.0, 0.0, 0.0]\n"
            "R: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]\n"
            "T: [0.0, 0.0, 3.0]\n"
            "image_width: 640\nimage_height: 480\n")
    (tmp_path / "good.yaml").write_text(text)
    assert read_cameras(tmp_path / "good.yaml")[0].K[0, 2] == 320.5
    (tmp_path / "bad.yaml").write_text(edit(text))
    with pytest.raises(ValueError, match=message):
        read_cameras(tmp_path / "bad.yaml")


def test_unreadable_and_unknown_files(tmp_path):
    (tmp_path / "broken.yaml").write_text("%YAML:1.0\n---\ncamera_matrix: [1, 2\n")
    with pytest.raises(ValueError, match="broken.yaml: not a readable OpenCV"):
        read_cameras(tmp_path / "broken.yaml")
    (tmp_path / "calibration.txt").write_text("fx 1000")
    with pytest.raises(ValueError, match="unknown calibration format"):
        read_cameras(tmp_path / "calibration.txt")
    with pytest.raises(FileNotFoundError, match="missing.json"):
        read_cameras(tmp_path / "missing.json")


def test_validation_names_the_camera_and_what_is_wrong():
    cameras = _ring()
    validate_cameras(cameras, "rig", image_sizes={"cam01": (640, 480)})
    with pytest.raises(ValueError, match=r"rig: camera 'cam01' is calibrated for 640 x 480 pixels but its images "
                                         r"are 1280 x 720"):
        validate_cameras(cameras, "rig", image_sizes={"cam01": (1280, 720)})
    with pytest.raises(ValueError, match=r"rig: images for camera 'cam09', which is not calibrated"):
        validate_cameras(cameras, "rig", image_sizes={"cam09": (640, 480)})
    twins = [cameras[0], Camera(K=cameras[1].K, R=cameras[1].R, t=cameras[1].t, width=640, height=480, name="cam00")]
    with pytest.raises(ValueError, match=r"rig: duplicate camera names \['cam00'\]"):
        validate_cameras(twins, "rig")
    nameless = Camera(K=cameras[0].K, R=cameras[0].R, t=cameras[0].t, width=640, height=480)
    with pytest.raises(ValueError, match="camera 0 has no name"):
        validate_cameras([nameless], "rig")
    tiny = cameras[0].K.copy()
    tiny[0, 0] = tiny[1, 1] = 1e-5  # invertible in exact arithmetic, useless in floating point
    with pytest.raises(ValueError, match="'cam00': K is not invertible"):
        validate_cameras([Camera(K=tiny, R=cameras[0].R, t=cameras[0].t, width=640, height=480, name="cam00")],
                         "rig")


def test_undistortion_gives_the_pinhole_camera_s_pixels():
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.8, 0.8, (500, 3)) + [0.0, 0.0, 1.0]
    for camera in _ring(dist=(-0.28, 0.09, 0.0012, -0.0008, -0.012)):
        distorted, depth = camera.project(points)
        inside = (depth > 0) & (distorted >= 0).all(axis=1) & (distorted < [640, 480]).all(axis=1)
        assert inside.sum() > 300
        expected, _ = pinhole(camera).project(points[inside])
        assert np.abs(distorted[inside] - expected).max() > 5  # the lens bends by several pixels
        undistorted = undistort_pixels(camera, distorted[inside])
        np.testing.assert_allclose(undistorted, expected, rtol=0, atol=1e-6)
    with_nan = undistort_pixels(camera, np.array([[np.nan, 3.0], [320.0, 240.0]]))
    assert np.isnan(with_nan[0]).all() and np.isfinite(with_nan[1]).all()
    plain = _ring(1)[0]
    assert pinhole(plain) is plain
    np.testing.assert_array_equal(undistort_pixels(plain, [[1.5, 2.5]]), [[1.5, 2.5]])
