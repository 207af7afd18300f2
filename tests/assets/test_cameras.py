import json

import cv2
import numpy as np
import pytest

from assets.cameras import Camera, load_cameras, save_cameras


def oblique_camera(**overrides) -> Camera:
    """A camera with every parameter non-trivial: rotated, off-centre principal point, W != H."""
    base = Camera.look_at(eye=(1.2, -2.5, 1.7), target=(0.1, 0.2, 0.9), focal_mm=35.0, width=640, height=480, name="cam0")
    K = base.K.copy()
    K[0, 2] += 11.25
    K[1, 2] -= 7.5
    params = dict(K=K, R=base.R, t=base.t, width=640, height=480, name="cam0")
    params.update(overrides)
    return Camera(**params)


def test_look_at_puts_the_target_at_the_image_centre_with_up_up_and_right_right():
    cam = Camera.look_at(eye=(0.0, -2.0, 1.0), target=(0.0, 0.0, 1.0), focal_mm=50.0, sensor_mm=36.0, width=640, height=480)
    np.testing.assert_allclose(cam.center, [0.0, -2.0, 1.0], atol=1e-12)
    f = 50.0 / 36.0 * 640
    points = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.0, 1.1], [0.0, 1.0, 1.0]])
    pixels, depth = cam.project(points)
    np.testing.assert_allclose(pixels[0], [320.0, 240.0], atol=1e-9)  # pixel centres at +0.5: W/2 is the middle
    np.testing.assert_allclose(pixels[1], [320.0 + f * 0.1 / 2.0, 240.0], atol=1e-9)  # +x world is image right
    np.testing.assert_allclose(pixels[2], [320.0, 240.0 - f * 0.1 / 2.0], atol=1e-9)  # up is image up (y down)
    np.testing.assert_allclose(depth, [2.0, 2.0, 2.0, 3.0], atol=1e-12)
    with pytest.raises(ValueError, match="parallel"):
        Camera.look_at(eye=(0, 0, 3), target=(0, 0, 0))
    with pytest.raises(ValueError, match="coincide"):
        Camera.look_at(eye=(1, 1, 1), target=(1, 1, 1))


def test_project_matches_opencv_with_distortion_and_unproject_inverts_it():
    dist = np.array([-0.21, 0.07, 1.5e-3, -8e-4, -0.012])
    cam = oblique_camera(dist=dist)
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (200, 3)) + [0.1, 0.2, 0.9]
    pixels, depth = cam.project(points)
    expected, _ = cv2.projectPoints(points, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, dist)
    np.testing.assert_allclose(pixels, expected[:, 0], atol=1e-9)
    np.testing.assert_allclose(depth, (points @ cam.R.T + cam.t)[:, 2], atol=1e-12)
    with pytest.raises(ValueError, match="distortion"):
        cam.unproject(pixels, depth)
    plain = oblique_camera()
    pixels, depth = plain.project(points)
    np.testing.assert_allclose(plain.unproject(pixels, depth), points, atol=1e-12)
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        plain.project(points[:, :2])


@pytest.mark.parametrize(
    "overrides, message",
    [
        (dict(K=[[500, 0, 320], [0, 500, 240], [0, 0.1, 1]]), "last row"),
        (dict(K=[[0, 0, 320], [0, 500, 240], [0, 0, 1]]), "invertible"),
        (dict(R=np.diag([1.0, 1.0, 2.0])), "rotation"),
        (dict(R=np.diag([1.0, 1.0, -1.0])), "rotation"),
        (dict(width=0), "width"),
        (dict(height=480.0), "height"),
        (dict(t=[0.0, 1.0]), r"t: expected a list of shape \[3\]"),
        (dict(dist=[0.0, 0.0, 0.0, np.nan, 0.0]), "dist: not finite"),
    ],
)
def test_invalid_cameras_are_refused_naming_the_problem(overrides, message):
    with pytest.raises(ValueError, match=message):
        oblique_camera(**overrides)


def test_cameras_json_round_trips_and_bad_fields_are_named(tmp_path):
    cams = [oblique_camera(dist=np.array([0.1, 0, 0, 0, 0])), Camera.look_at((3, 0, 1), (0, 0, 1), name="side")]
    path = tmp_path / "cameras.json"
    save_cameras(path, cams)
    loaded = load_cameras(path)
    assert [c.name for c in loaded] == ["cam0", "side"]
    for a, b in zip(cams, loaded):
        for key in ("K", "R", "t", "dist"):
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
        assert (a.width, a.height) == (b.width, b.height)
    assert not list(tmp_path.glob(".*part"))  # written atomically, no temporary left behind

    data = json.loads(path.read_text())
    data["cameras"][1]["K"] = [[1, 0, 0], [0, 1, 0]]
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"cameras\.json: cameras\[1\]: field 'K': expected a list of shape \[3, 3\]"):
        load_cameras(path)
    entry = cams[0].to_dict()
    del entry["R"]
    with pytest.raises(ValueError, match="rig.json: missing field 'R'"):
        Camera.from_dict(entry, "rig.json")
    with pytest.raises(ValueError, match="rig.json: field 'width' must be a positive integer"):
        Camera.from_dict({**cams[0].to_dict(), "width": 640.5}, "rig.json")
    with pytest.raises(ValueError, match="rig.json: Camera 'cam0': R must be a rotation"):
        Camera.from_dict({**cams[0].to_dict(), "R": np.eye(3).tolist()[::-1]}, "rig.json")


def test_blender_identity_camera_looks_down_minus_z_with_y_up_and_horizontal_sensor_fit():
    # Blender's camera object at the origin with no rotation looks down world -Z, +Y up in the image
    cam = Camera.from_blender(np.eye(4), lens_mm=50.0, sensor_width_mm=36.0, shift_x=0.0, shift_y=0.0,
                              width=640, height=480)
    np.testing.assert_allclose(cam.R, np.diag([1.0, -1.0, -1.0]))
    half_width = 18.0 / 50.0  # tan of half the horizontal field of view: the sensor spans the width
    half_height = half_width * 480 / 640  # square pixels
    pixels, depth = cam.project(np.array([[0.0, 0.0, -1.0], [half_width, 0.0, -1.0], [0.0, half_height, -1.0]]))
    np.testing.assert_allclose(pixels, [[320.0, 240.0], [640.0, 240.0], [320.0, 0.0]], atol=1e-9)
    np.testing.assert_allclose(depth, 1.0)
    # shifts are in units of the image width for both axes; +x moves the view right, +y up
    shifted = Camera.from_blender(np.eye(4), 50.0, 36.0, shift_x=0.1, shift_y=0.1, width=640, height=480)
    axis, _ = shifted.project(np.array([[0.0, 0.0, -1.0]]))
    np.testing.assert_allclose(axis[0], [320.0 - 64.0, 240.0 + 64.0], atol=1e-9)


def test_blender_params_round_trip_and_refuse_what_blender_cannot_render():
    cam = oblique_camera()
    params = cam.blender_params(sensor_width_mm=24.0)
    assert params["sensor_fit"] == "HORIZONTAL" and (params["resolution_x"], params["resolution_y"]) == (640, 480)
    matrix = np.array(params["matrix_world"])
    np.testing.assert_allclose(matrix[:3, 3], cam.center, atol=1e-12)
    np.testing.assert_allclose(-matrix[:3, 2], cam.R[2], atol=1e-12)  # Blender looks down local -Z
    np.testing.assert_allclose(matrix[:3, 1], -cam.R[1], atol=1e-12)  # local +Y is image up
    np.testing.assert_allclose(params["lens_mm"], cam.K[0, 0] * 24.0 / 640, rtol=1e-12)
    np.testing.assert_allclose([params["shift_x"], params["shift_y"]], [-11.25 / 640, -7.5 / 640], atol=1e-15)
    back = Camera.from_blender(**{k: v for k, v in params.items() if k not in ("sensor_fit", "resolution_x", "resolution_y")},
                               width=640, height=480, name="cam0")
    np.testing.assert_allclose(back.K, cam.K, rtol=1e-12)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-12)
    # object scale does not change what Blender renders
    scaled = matrix.copy()
    scaled[:3, :3] *= 2.5
    again = Camera.from_blender(scaled, params["lens_mm"], 24.0, params["shift_x"], params["shift_y"], 640, 480)
    np.testing.assert_allclose(again.R, cam.R, atol=1e-12)
    np.testing.assert_allclose(again.t, cam.t, atol=1e-12)

    K = cam.K.copy()
    K[1, 1] *= 1.01
    with pytest.raises(ValueError, match="square pixels"):
        oblique_camera(K=K).blender_params()
    K = cam.K.copy()
    K[0, 1] = 0.5
    with pytest.raises(ValueError, match="skew"):
        oblique_camera(K=K).blender_params()
    with pytest.raises(ValueError, match="distortion"):
        oblique_camera(dist=np.array([0.01, 0, 0, 0, 0])).blender_params()
    with pytest.raises(ValueError, match="sheared or mirrored"):
        Camera.from_blender(np.diag([1.0, 1.0, -1.0, 1.0]), 50.0, 36.0, 0.0, 0.0, 64, 64)


@pytest.mark.parametrize("count", [8, 12, 14])
def test_longer_opencv_distortion_models_project_as_opencv_and_keep_their_length(count):
    """Rational (8), thin-prism (12) and tilted-sensor (14) coefficients project as cv2.projectPoints;
    a camera keeps the shortest OpenCV length that holds its non-zero coefficients."""
    dist = np.array([-0.21, 0.07, 1.5e-3, -8e-4, -0.012, 0.1, -0.02, 0.004, 1e-3, -2e-3, 5e-4, -3e-4, 0.02, -0.01])[:count]
    cam = oblique_camera(dist=dist)
    assert cam.dist.shape == (count,)
    points = np.random.default_rng(1).uniform(-0.5, 0.5, (100, 3)) + [0.1, 0.2, 0.9]
    expected, _ = cv2.projectPoints(points, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, dist)
    np.testing.assert_allclose(cam.project(points)[0], expected[:, 0], atol=1e-9)
    padded = oblique_camera(dist=np.r_[dist[:5], np.zeros(9)])
    assert padded.dist.shape == (5,) and oblique_camera(dist=dist[:4]).dist.tolist() == dist[:4].tolist() + [0.0]
    with pytest.raises(ValueError, match="expected 4, 5, 8, 12 or 14 OpenCV distortion coefficients, got 6"):
        oblique_camera(dist=dist[:6])
