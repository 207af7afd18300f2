"""Rig calibration from ChArUco board images rendered through known cameras: OpenCV's board image,
warped by each camera's homography of the board plane (2x supersampled, then area-averaged)."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.cameras import Camera
from reconstruction.__main__ import main
from reconstruction.calibration_formats import read_calibration
from reconstruction.charuco import CharucoBoard, RigCalibrationConfig, calibrate_rig

BOARD = CharucoBoard(9, 7, 0.05, 0.037, "DICT_4X4_50")
_ART_PX = 80  # board image pixels per square


def _rig():
    """Four 1280 x 960 cameras 1.6 m from the board's volume, 80 degrees apart at the ends, each with
    its own focal length and off-centre principal point."""
    cameras = []
    for i, azimuth in enumerate(np.radians([-40, -14, 14, 40])):
        eye = (1.6 * np.sin(azimuth), -1.6 * np.cos(azimuth), 1.2 + 0.15 * (i % 2))
        base = Camera.look_at(eye, (0, 0, 1.2), focal_mm=26 + 2 * i, width=1280, height=960, name=f"cam{i}")
        K = base.K.copy()
        K[0, 2], K[1, 2], K[1, 1] = K[0, 2] + 7 * i - 10, K[1, 2] - 5 * i, K[1, 1] * (1 + 0.002 * i)
        cameras.append(Camera(K=K, R=base.R, t=base.t, width=1280, height=960, name=base.name))
    return cameras


def _board_poses(count, rng):
    """Board -> world (4, 4): the board faces the cameras (its z along world +y), centred near
    (0, 0, 1.2) within +-0.35 m across, +-0.25 m up, tilted up to 40 degrees."""
    facing = np.column_stack([[1, 0, 0], [0, 0, -1], [0, 1, 0]])  # board x, y (down), z (into it) in the world
    half = np.array([BOARD.squares_x, BOARD.squares_y, 0]) * BOARD.square_m / 2
    poses = []
    for _ in range(count):
        R = Rotation.from_rotvec(rng.uniform(-0.7, 0.7, 3) * [1, 0.4, 1]).as_matrix() @ facing
        pose = np.eye(4)
        pose[:3, :3] = R
        pose[:3, 3] = [0, 0, 1.2] + rng.uniform(-1, 1, 3) * [0.35, 0.2, 0.25] - R @ half
        poses.append(pose)
    return poses


def _render(camera, board_to_world, art):
    """The camera's 8-bit grey image of the board: the board plane's homography, 2x supersampled."""
    margin = _ART_PX // 2
    s = BOARD.square_m / _ART_PX
    art_to_board = np.array([[s, 0, (0.5 - margin) * s], [0, s, (0.5 - margin) * s], [0, 0, 1]])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = camera.R, camera.t
    board_to_camera = pose @ board_to_world
    K = camera.K.copy()
    K[:2, 2] -= 0.5  # OpenCV's image functions put pixel centres at integers
    up = np.array([[2, 0, 0.5], [0, 2, 0.5], [0, 0, 1]])  # pixel u covers supersampled pixels 2u, 2u + 1
    H = up @ K @ board_to_camera[:3][:, [0, 1, 3]] @ art_to_board
    big = cv2.warpPerspective(art, H, (2 * camera.width, 2 * camera.height), flags=cv2.INTER_LINEAR, borderValue=110)
    return cv2.resize(big, (camera.width, camera.height), interpolation=cv2.INTER_AREA)


@pytest.fixture(scope="module")
def rendered():
    """(cameras, {camera: {frame: image}}, board -> world poses) for 30 board poses."""
    art = BOARD.opencv().generateImage((BOARD.squares_x * _ART_PX, BOARD.squares_y * _ART_PX), marginSize=0)
    art = cv2.copyMakeBorder(art, *[_ART_PX // 2] * 4, cv2.BORDER_CONSTANT, value=255)
    cameras = _rig()
    poses = _board_poses(30, np.random.default_rng(0))
    images = {c.name: {f"{i:03d}": _render(c, pose, art) for i, pose in enumerate(poses)} for c in cameras}
    return cameras, images, poses


def _relative_errors(truth, got, reference):
    """Per camera: (rotation error in degrees, translation error in mm) of its pose in the reference
    camera's frame, the calibration's world."""
    def matrix(camera):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = camera.R, camera.t
        return m

    ref = matrix(reference)
    errors = []
    for t, g in zip(truth, got):
        expected = matrix(t) @ np.linalg.inv(ref)
        errors.append((np.degrees(Rotation.from_matrix(expected[:3, :3].T @ g.R).magnitude()),
                       1000 * np.linalg.norm(expected[:3, 3] - g.t)))
    return errors


@pytest.mark.slow
def test_calibrate_recovers_the_rig_from_board_images(rendered, tmp_path, capsys):
    cameras, images, _ = rendered
    for name, frames in images.items():
        (tmp_path / "boards" / name).mkdir(parents=True)
        for frame, image in frames.items():
            cv2.imwrite(str(tmp_path / "boards" / name / f"{frame}.png"), image)
    (tmp_path / "boards" / "cam0" / "notes.txt").write_text("not an image")
    argv = ["cameras", "calibrate", "--board", "9x7,0.05,0.037,DICT_4X4_50", "--images", str(tmp_path / "boards"),
            "--out", str(tmp_path / "rig.toml"), "--reference", "cam0"]
    assert main(argv) == 0, capsys.readouterr().err
    report = capsys.readouterr().out
    got = read_calibration(tmp_path / "rig.toml")
    assert [c.name for c in got] == ["cam0", "cam1", "cam2", "cam3"]
    for truth, camera in zip(cameras, got):
        assert (camera.width, camera.height) == (1280, 960)
        assert np.abs(camera.K - truth.K).max() < 0.01 * truth.K[0, 0], (camera.name, camera.K, truth.K)
        assert np.abs(camera.dist).max() < 0.05
    for name, (degrees, mm) in zip(["cam0", "cam1", "cam2", "cam3"], _relative_errors(cameras, got, cameras[0])):
        assert degrees < 0.5 and mm < 10.0, (name, degrees, mm)
    # one row per camera with its reprojection errors, the reference marked
    rows = {line.split()[0]: line.split() for line in report.splitlines()
            if line.split()[0] in ("cam0", "cam1", "cam2", "cam3")}
    assert set(rows) == {"cam0", "cam1", "cam2", "cam3"} and "(the reference)" in " ".join(rows["cam0"])
    assert all(0 < float(rows[n][3]) < 0.5 and 0 < float(rows[n][4]) < 0.5 for n in rows), report


@pytest.mark.slow
def test_refinement_lowers_the_rig_error_and_unjoined_cameras_are_named(rendered):
    cameras, images, _ = rendered
    subset = {name: dict(list(frames.items())[:10]) for name, frames in images.items() if name in ("cam1", "cam2")}
    chained, chained_reports = calibrate_rig(BOARD, subset, RigCalibrationConfig(refine=False))
    refined, refined_reports = calibrate_rig(BOARD, subset)
    for before, after in zip(chained_reports, refined_reports):
        assert after.rig_rms_px <= before.rig_rms_px + 1e-9, (before, after)
        assert after.intrinsic_rms_px == before.intrinsic_rms_px
    # cam3's frames taken at other instants (other names) share no view with the others
    lonely = dict(subset, cam3={f"x{frame}": image for frame, image in list(images["cam3"].items())[:10]})
    with pytest.raises(ValueError, match=r"cameras \['cam3'\] share no board view with cameras \['cam1', 'cam2'\]"):
        calibrate_rig(BOARD, lonely)
    blank = dict(subset, cam3={f"{i:03d}": np.full((960, 1280), 110, np.uint8) for i in range(10)})
    with pytest.raises(ValueError, match=r"camera 'cam3': the board was found \(>= 8 corners\) in 0 of 10 images"):
        calibrate_rig(BOARD, blank)


@pytest.mark.slow
def test_a_board_view_defines_the_world_with_z_up(rendered):
    """With origin_frame the world is that view's board turned Z up (x along its rows, y and z
    flipped): each camera's pose is its true world pose moved into that frame."""
    cameras, images, poses = rendered
    subset = {name: dict(list(frames.items())[:12]) for name, frames in images.items() if name in ("cam1", "cam2")}
    got, _ = calibrate_rig(BOARD, subset, RigCalibrationConfig(origin_frame="003"))
    board_world = poses[3] @ np.diag([1.0, -1.0, -1.0, 1.0])  # the Z-up world in the true world
    for truth, camera in zip(cameras[1:3], got):
        expected = Camera(K=truth.K, R=truth.R @ board_world[:3, :3], t=truth.R @ board_world[:3, 3] + truth.t,
                          width=1280, height=960)
        assert np.degrees(Rotation.from_matrix(expected.R.T @ camera.R).magnitude()) < 0.5, camera.name
        assert np.linalg.norm(expected.center - camera.center) < 0.01, (camera.name, expected.center, camera.center)
    with pytest.raises(ValueError, match=r"origin frame 'x': no camera found the board in it"):
        calibrate_rig(BOARD, subset, RigCalibrationConfig(origin_frame="x"))


@pytest.mark.parametrize("spec, message", [
    ("9x7,0.05", "expected COLSxROWS,SQUARE_M,MARKER_M"),
    ("9x7,0.05,0.06", r"the marker \(0.06 m\) must be smaller than the square"),
    ("9x7,0.05,0.037,DICT_9X9_1", "unknown ArUco dictionary 'DICT_9X9_1'"),
    ("30x30,0.05,0.037,DICT_4X4_50", "30 x 30 squares need 450 markers; DICT_4X4_50 has 50"),
])
def test_board_specs_are_parsed_or_refused_by_name(spec, message):
    with pytest.raises(ValueError, match=message):
        CharucoBoard.parse(spec)
    board = CharucoBoard.parse("5x4,0.04,0.03,DICT_5X5_100,legacy")
    assert board == CharucoBoard(5, 4, 0.04, 0.03, "DICT_5X5_100", legacy=True)
    assert board.corners.shape == (12, 3)
