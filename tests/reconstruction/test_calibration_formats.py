"""Other tools' calibration files: exact round trips, their real layouts, refusals by name, and
``python -m reconstruction cameras convert``."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.cameras import Camera, save_cameras
from reconstruction.__main__ import main
from reconstruction.calibration_formats import FORMATS, detect_format, read_calibration, write_calibration

#: what each format can hold: COLMAP has no skew and no thin-prism or tilt coefficients
_DISTORTIONS = [np.zeros(5), np.array([-0.21, 0.05, 1e-3, -5e-4, 0.0]), np.array([-0.1, 0.02, 1e-4, 2e-4, -3e-3]),
                np.array([0.3, -0.1, 1e-3, 2e-3, 0.01, 0.25, -0.05, 0.008])]
_FULL = [np.r_[_DISTORTIONS[2], 0.1, 0.01, -0.002, 1e-3, -2e-3, 3e-4, -4e-4],
         np.r_[_DISTORTIONS[2], 0.1, 0.01, -0.002, 1e-3, -2e-3, 3e-4, -4e-4, 0.01, -0.02]]


def _rig(skew=False, full=False, seed=0):
    """Cameras with random poses and off-centre, non-square intrinsics, each with another lens model."""
    rng = np.random.default_rng(seed)
    cameras = []
    for i, dist in enumerate(_DISTORTIONS + (_FULL if full else [])):
        K = np.array([[1400 + 100 * rng.random(), 0.3 if skew else 0.0, 640.123456789 + rng.random()],
                      [0.0, 1410 + 100 * rng.random(), 480.987654321 + rng.random()], [0.0, 0.0, 1.0]])
        R = Rotation.from_rotvec(rng.normal(size=3) * [1, 1, 3]).as_matrix()
        cameras.append(Camera(K=K, R=R, t=rng.normal(size=3) * 2, width=1280, height=960 + 2 * i, dist=dist,
                              name=f"cam{i:02d}"))
    return cameras


def _assert_same(expected, got, atol=1e-9):
    assert [c.name for c in got] == [c.name for c in expected]
    for a, b in zip(expected, got):
        assert (a.width, a.height) == (b.width, b.height), a.name
        for key in ("K", "dist", "R", "t"):
            assert getattr(a, key).shape == getattr(b, key).shape, (a.name, key)
            np.testing.assert_allclose(getattr(b, key), getattr(a, key), rtol=0, atol=atol, err_msg=f"{a.name} {key}")


def _refused(path, text, message):
    """`text` written to `path` is refused with a ValueError matching `message`."""
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_calibration(path)


@pytest.mark.parametrize("format, name", [("json", "cameras.json"), ("opencv", "calibration.yml"),
                                          ("easymocap", "easymocap"), ("toml", "calibration.toml"),
                                          ("multical", "calibration.json"), ("colmap", "sparse")])
def test_each_format_round_trips_exactly(tmp_path, format, name):
    cameras = _rig(skew=format != "colmap", full=format != "colmap")
    written = write_calibration(tmp_path / name, cameras, format)
    assert detect_format(written) == format
    _assert_same(cameras, read_calibration(written))
    # translations in millimetres both ways come back in metres
    write_calibration(tmp_path / "mm" / name, cameras, format, unit_m=0.001)
    millimetres = read_calibration(tmp_path / "mm" / name, format, unit_m=1.0)
    np.testing.assert_allclose(millimetres[1].t, cameras[1].t * 1000, rtol=1e-12)
    _assert_same(cameras, read_calibration(tmp_path / "mm" / name, format, unit_m=0.001))


def test_convert_chains_every_format_and_refuses_what_one_cannot_hold(tmp_path, capsys):
    cameras = _rig()
    save_cameras(tmp_path / "cameras.json", cameras)
    chain = [("cameras.json", None), ("em", "easymocap"), ("a.toml", None), ("m.json", "multical"),
             ("sparse", "colmap"), ("b.yaml", None), ("back.json", None)]
    for (source, _), (target, format) in zip(chain, chain[1:]):
        argv = ["cameras", "convert", str(tmp_path / source), str(tmp_path / target)]
        assert main(argv + (["--format", format] if format else [])) == 0, capsys.readouterr().err
        assert f"4 cameras from {tmp_path / source}" in capsys.readouterr().out
    _assert_same(cameras, read_calibration(tmp_path / "back.json"))
    # OpenCV's convention in the YAML: cx is ours minus half a pixel
    fs = cv2.FileStorage(str(tmp_path / "b.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("cameras").at(0).getNode("camera_matrix").mat()[0, 2] == pytest.approx(cameras[0].K[0, 2] - 0.5)
    # skew and thin-prism lenses have no COLMAP model: refused naming the camera
    save_cameras(tmp_path / "skewed.json", _rig(skew=True))
    assert main(["cameras", "convert", str(tmp_path / "skewed.json"), str(tmp_path / "c"), "--format", "colmap"]) == 2
    assert "camera 'cam00': COLMAP's camera models have no skew" in capsys.readouterr().err
    save_cameras(tmp_path / "prism.json", _rig(full=True))
    assert main(["cameras", "convert", str(tmp_path / "prism.json"), str(tmp_path / "c"), "--format", "colmap"]) == 2
    assert "camera 'cam04': COLMAP has no pinhole model with OpenCV's thin-prism" in capsys.readouterr().err
    assert not (tmp_path / "c" / "cameras.txt").exists()
    # a folder out needs its format named
    assert main(["cameras", "convert", str(tmp_path / "cameras.json"), str(tmp_path / "out")]) == 2
    assert "cannot tell the calibration format" in capsys.readouterr().err


def test_easymocap_files_as_easymocap_writes_them(tmp_path):
    """EasyMocap's own writer (mytools/camera_utils.py): CRLF lines, quoted names, 6 decimals,
    H_/W_ as plain integers, R_ a 3 x 1 Rodrigues vector and Rot_ its matrix, T_ 3 x 1."""
    rvec = np.array([0.1, -2.0, 0.3])
    R = cv2.Rodrigues(rvec)[0]

    def mat(key, rows, cols, values):
        return [f"{key}: !!opencv-matrix", f"  rows: {rows}", f"  cols: {cols}", "  dt: d",
                "  data: [{}]".format(", ".join(f"{v:.6f}" for v in np.ravel(values)))]

    K = [[1500.0, 0.0, 959.5], [0.0, 1502.0, 539.5], [0.0, 0.0, 1.0]]
    intri = ["%YAML:1.0", "---", "names:", '  - "01"', '  - "02"'] + mat("K_01", 3, 3, K) + \
        mat("dist_01", 1, 5, [-0.1, 0.05, 0.001, 0.0, 0.0]) + ["H_01: 1080", "W_01: 1920"] + mat("K_02", 3, 3, K) + \
        mat("dist_02", 1, 5, np.zeros(5)) + ["H_02: 1080", "W_02: 1920"]
    extri = ["%YAML:1.0", "---", "names:", '  - "01"', '  - "02"'] + mat("R_01", 3, 1, rvec) + mat("Rot_01", 3, 3, R) + \
        mat("T_01", 3, 1, [0.5, -0.25, 3.0]) + mat("R_02", 3, 1, np.zeros(3)) + mat("T_02", 3, 1, [0.0, 0.0, 2.0])
    folder = tmp_path / "calib"
    folder.mkdir()
    (folder / "intri.yml").write_bytes("\r\n".join(intri).encode() + b"\r\n")
    (folder / "extri.yml").write_bytes("\r\n".join(extri).encode() + b"\r\n")
    assert detect_format(folder) == detect_format(folder / "intri.yml") == "easymocap"
    first, second = read_calibration(folder)
    assert (first.name, first.width, first.height) == ("01", 1920, 1080)
    np.testing.assert_allclose(first.K, [[1500.0, 0.0, 960.0], [0.0, 1502.0, 540.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(first.R, np.round(R, 6), atol=1e-12)  # Rot_ is read, not R_
    np.testing.assert_allclose(first.t, [0.5, -0.25, 3.0])
    np.testing.assert_allclose(first.dist, [-0.1, 0.05, 0.001, 0.0, 0.0])
    np.testing.assert_allclose(second.R, np.eye(3), atol=1e-12)  # no Rot_: from R_
    # without H_ / W_ the image size must be given
    (folder / "intri.yml").write_text("\n".join(line for line in intri if not line.startswith(("H_", "W_"))) + "\n")
    with pytest.raises(ValueError, match=r"intri\.yml: camera '01' has no H_01 / W_01: give the image size"):
        read_calibration(folder)
    assert read_calibration(folder, image_size=(1920, 1080))[1].width == 1920
    (folder / "extri.yml").write_text("%YAML:1.0\n---\nnames:\n  - \"01\"\n")
    with pytest.raises(ValueError, match=r"extri\.yml: missing R_01"):
        read_calibration(folder, image_size=(1920, 1080))


def test_anipose_calibration_toml(tmp_path):
    """The first camera of aniposelib's tests/data/calib/7cam-allen-mouse/calibration.toml (millimetres)."""
    (tmp_path / "calibration.toml").write_text(
        '[cam_0]\nname = "cam088"\nsize = [ 1440, 1080,]\n'
        "matrix = [ [ 1852.4059883563652, 0.0, 719.5,], [ 0.0, 1852.4059883563652, 539.5,], [ 0.0, 0.0, 1.0,],]\n"
        "distortions = [ -0.03617269969805811, 0.0, 0.0, 0.0, 0.0,]\n"
        "rotation = [ -0.0017222068652836759, -0.0017660019086589327, -0.004590121306089567,]\n"
        "translation = [ 2.5517119183276713, -2.7696043565510524, -18.17036813575914,]\n\n"
        "[metadata]\nadjusted = true\nerror = 1.6680509250648916\n")
    (camera,) = read_calibration(tmp_path / "calibration.toml", unit_m=0.001)
    assert (camera.name, camera.width, camera.height) == ("cam088", 1440, 1080)
    np.testing.assert_allclose(camera.K[:2, 2], [720.0, 540.0])
    np.testing.assert_allclose(camera.R, cv2.Rodrigues(np.array([-0.0017222068652836759, -0.0017660019086589327,
                                                                 -0.004590121306089567]))[0], atol=1e-15)
    np.testing.assert_allclose(camera.t, [0.0025517119183276713, -0.0027696043565510524, -0.01817036813575914])
    np.testing.assert_allclose(camera.dist, [-0.03617269969805811, 0, 0, 0, 0])
    text = (tmp_path / "calibration.toml").read_text()
    _refused(tmp_path / "fisheye.toml", text.replace("[metadata]", "fisheye = true\n[metadata]")
             .replace("0.0, 0.0, 0.0, 0.0,]", "0.0, 0.0, 0.0,]"),
             r"fisheye\.toml: \[cam_0\]: camera 'cam088' uses the fisheye model")
    _refused(tmp_path / "bad.toml", text.replace("size = [ 1440, 1080,]", "size = [ 1440,]"),
             r"bad\.toml: \[cam_0\] \('cam088'\): image size: expected 2 numbers, got 1")


def test_caliscope_camera_array_toml(tmp_path):
    """caliscope's camera_array.toml: [cameras.<id>] tables, an ignored uncalibrated camera, rotation
    as a Rodrigues vector (tests/reference/base_data) or a matrix (tests/sessions/4_cam_recording)."""
    rotation = [0.37663907020176496, 2.221571756653206, -1.8829501231820573]
    (tmp_path / "camera_array.toml").write_text(
        "[cameras.0]\nport = 0\nrotation_count = 0\nexposure = -7.0\nignore = true\nsize = [1280, 720]\n"
        "verified_resolutions = [[640, 480], [1280, 720]]\n\n"
        "[cameras.1]\nport = 1\nrotation_count = 0\nerror = 0.371\nexposure = -9\ngrid_count = 59\nignore = false\n"
        "size = [1280, 720]\nmatrix = [[707.7725380251087, 0.0, 630.6308487130314], [0.0, 708.187442792615, "
        "373.44234818656673], [0.0, 0.0, 1.0]]\ndistortions = [0.19638278150771601, -0.3318919592446194, "
        "-0.0031676274251545623, -0.0015050307508214676, 0.2300194530965769]\n"
        "translation = [0.36584121836550093, 0.42506578316829713, 0.8792906982181679]\n"
        f"rotation = {rotation}\n\n"
        "[cameras.2]\ncam_id = 2\nsize = [1280, 720]\nmatrix = [[700.0, 0.0, 639.5], [0.0, 700.0, 359.5], [0.0, 0.0, 1.0]]\n"
        "distortions = [0.0, 0.0, 0.0, 0.0, 0.0]\ntranslation = [0.0, 0.0, 1.0]\n"
        f"rotation = {cv2.Rodrigues(np.array(rotation))[0].tolist()}\nfisheye = false\n")
    cam1, cam2 = read_calibration(tmp_path / "camera_array.toml")
    assert (cam1.name, cam2.name) == ("cam_1", "cam_2")
    np.testing.assert_allclose(cam1.K[0, 2], 630.6308487130314 + 0.5)
    np.testing.assert_allclose(cam1.R, cam2.R, atol=1e-15)
    np.testing.assert_allclose(cam2.K[:2, 2], [640.0, 360.0])


def test_multical_calibration_json(tmp_path):
    """multical's FORMAT.md layout: intrinsics per camera, then cam1's pose and cam2_to_cam1."""
    R2 = Rotation.from_rotvec([0.0, -0.01, 0.0]).as_matrix()
    (tmp_path / "calibration.json").write_text("""{
  "cameras": {
    "cam1": {"image_size": [2000.00, 1500.00],
             "K": [[2251.52, 0.00, 985.68], [0.00, 2252.80, 763.00], [0.00, 0.00, 1.00]],
             "dist": [-0.12, 0.32, -0.00, -0.00, -0.20]},
    "cam2": {"model": "standard", "image_size": [2000.00, 1500.00],
             "K": [[2257.19, 0.00, 983.84], [0.00, 2258.64, 754.08], [0.00, 0.00, 1.00]],
             "dist": [[-0.12, 0.39, -0.00, -0.00, -0.28]]}
  },
  "camera_poses": {
    "cam1": {"R": [[1.00, 0.00, 0.00], [0.00, 1.00, 0.00], [0.00, 0.00, 1.00]], "T": [0.00, 0.00, 0.00]},
    "cam2_to_cam1": {"R": %s, "T": [-0.05, 0.00, 0.00]}
  }
}""" % R2.tolist())
    assert detect_format(tmp_path / "calibration.json") == "multical"
    cam1, cam2 = read_calibration(tmp_path / "calibration.json")
    assert (cam2.name, cam2.width, cam2.height) == ("cam2", 2000, 1500)
    np.testing.assert_allclose(cam2.K[:2, 2], [984.34, 754.58])
    np.testing.assert_allclose(cam2.dist, [-0.12, 0.39, 0.0, 0.0, -0.28])
    np.testing.assert_allclose(cam2.R, R2, atol=1e-15)
    np.testing.assert_allclose(cam2.center, -R2.T @ [-0.05, 0.0, 0.0], atol=1e-15)  # 5 cm to cam1's right
    # a chain camX_to_camY_to... composes: camera 3 sits 5 cm right of camera 2
    text = (tmp_path / "calibration.json").read_text()
    chained = text.replace('"cam2": {"model"', '"cam3": {"model": "standard", "image_size": [2000, 1500], '
                           '"K": [[2000, 0, 999.5], [0, 2000, 749.5], [0, 0, 1]], "dist": [0, 0, 0, 0, 0]},\n'
                           '    "cam2": {"model"').replace(
        '"cam2_to_cam1"', '"cam3_to_cam2": {"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "T": [-0.05, 0, 0]},\n    "cam2_to_cam1"')
    (tmp_path / "chained.json").write_text(chained)
    cam3 = read_calibration(tmp_path / "chained.json")[1]
    np.testing.assert_allclose(cam3.t, [-0.1, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(cam3.R, R2, atol=1e-15)
    _refused(tmp_path / "fisheye.json", text.replace('"model": "standard"', '"model": "fisheye"'),
             r"fisheye\.json: cameras\.cam2: camera 'cam2' uses the lens model 'fisheye'")
    _refused(tmp_path / "unplaced.json", text.replace('"cam2_to_cam1"', '"cam2_to_cam9"'),
             r"unplaced\.json: camera_poses\.cam2_to_cam9: no camera 'cam9'")


def test_colmap_text_model(tmp_path):
    """COLMAP's documented example (docs/format.rst), one more image on its SIMPLE_RADIAL camera."""
    folder = tmp_path / "sparse"
    folder.mkdir()
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "# Number of cameras: 3\n1 SIMPLE_PINHOLE 3072 2304 2559.81 1536 1152\n"
        "2 PINHOLE 3072 2304 2560.56 2560.56 1536 1152\n3 SIMPLE_RADIAL 3072 2304 2559.69 1536 1152 -0.0218531\n")
    (folder / "images.txt").write_text(
        "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
        "#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: 2, mean observations per image: 2\n"
        "1 0.851773 0.0165051 0.503764 -0.142941 -0.737434 1.02973 3.74354 1 P1180141.JPG\n"
        "2362.39 248.498 58396 1784.7 268.254 59027 1784.7 268.254 -1\n"
        "2 0.851773 0.0165051 0.503764 -0.142941 -0.737434 1.02973 3.74354 1 P1180142.JPG\n"
        "1190.83 663.957 23056 1258.77 640.354 59027\n"
        "3 1 0 0 0 0 0 0 3 left/P1180143.JPG\n\n")
    assert detect_format(folder / "images.txt") == "colmap"
    first, second, third = read_calibration(folder)
    assert [c.name for c in (first, second, third)] == ["P1180141", "P1180142", "left_P1180143"]
    np.testing.assert_allclose(first.K, [[2559.81, 0, 1536], [0, 2559.81, 1152], [0, 0, 1]])
    q = np.array([0.851773, 0.0165051, 0.503764, -0.142941])
    np.testing.assert_allclose(first.R, Rotation.from_quat(np.roll(q / np.linalg.norm(q), -1)).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(first.t, [-0.737434, 1.02973, 3.74354])
    np.testing.assert_allclose(third.dist, [-0.0218531, 0, 0, 0, 0])
    cameras = (folder / "cameras.txt").read_text()
    for model, message in [("OPENCV_FISHEYE 3072 2304 1 1 1 1 0 0 0 0", "camera 3 uses the COLMAP model OPENCV_FISHEYE"),
                           ("FOV 3072 2304 1 1 1 1 0.1", "camera 3 uses the COLMAP model FOV"),
                           ("PINHOLE 3072 2304 1 1 1", "the PINHOLE model has 4 parameters, got 3"),
                           ("WARPED 3072 2304 1", "camera 3: unknown COLMAP model 'WARPED'")]:
        (folder / "cameras.txt").write_text(cameras.replace("SIMPLE_RADIAL 3072 2304 2559.69 1536 1152 -0.0218531", model))
        with pytest.raises(ValueError, match=r"cameras\.txt:6: " + message):
            read_calibration(folder)


def test_unknown_and_missing_inputs_are_named(tmp_path):
    (tmp_path / "rig.txt").write_text("")
    with pytest.raises(ValueError, match=r"rig\.txt: cannot tell the calibration format"):
        read_calibration(tmp_path / "rig.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"empty: a folder without intri\.yml"):
        read_calibration(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match=r"missing\.toml"):
        read_calibration(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="unknown calibration format 'vicon'"):
        write_calibration(tmp_path / "x", _rig(), "vicon")
    assert set(FORMATS) == {"json", "opencv", "easymocap", "toml", "multical", "colmap"}
