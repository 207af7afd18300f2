"""Hostile and careless input to reconstruction: calibration files, views, cached stage files, exports."""

from __future__ import annotations

import errno
import json
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from assets.cameras import Camera
from assets.fileio import load_npz, save_npz
from reconstruction.cameras import read_cameras
from reconstruction.points import CapturedPoints
from reconstruction.views import Views
from tests.hostile.conftest import assert_refused, files_under, run_cli


def _camera(name: str = "cam00", width: int = 96, height: int = 64) -> Camera:
    return Camera.look_at((0.0, -2.0, 1.0), (0.0, 0.0, 1.0), width=width, height=height, name=name)


def _cameras_json(path: Path, **fields) -> Path:
    path.write_text(json.dumps({"cameras": [{**_camera().to_dict(), **fields}]}))
    return path


def _views(root: Path, suffix: str = ".png") -> Path:
    """A views folder of one camera, cam00, with frame 0: a 96 x 64 gradient."""
    (root / "cam00").mkdir(parents=True)
    image = np.broadcast_to(np.linspace(0, 255, 96, dtype=np.uint8)[None, :, None], (64, 96, 3))
    assert cv2.imwrite(str(root / "cam00" / f"f000000{suffix}"), np.ascontiguousarray(image))
    return root


_OPENCV_CAMERA = ("%YAML:1.0\nK: [100, 0, 48, 0, 100, 32, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
                  "T: [0, 0, 2]\nimage_size: [96, 64]\n")


@pytest.mark.hostile("outside")
def test_a_camera_name_that_climbs_out_of_the_folder_is_refused_by_the_cli(tmp_path):
    inputs = tmp_path / "a" / "b"
    views = _views(inputs / "views")
    cameras = _cameras_json(inputs / "cameras.json", name="../../escaped_cam")
    (views / "escaped_cam").mkdir()  # where the views of that name are looked for
    before = files_under(tmp_path)
    out = inputs / "out"
    result = run_cli("reconstruction", "detect", "--views", views, "--cameras", cameras, "--template", "shirt",
                     "--out", out, "--localizer", "l.pt", "--recognizer", "r.pt", "--crosspoints", "c.pt",
                     "--no-progress")
    assert_refused(result, "cameras.json: cameras[0].name", "../../escaped_cam")
    assert files_under(tmp_path) == before and not out.exists()


@pytest.mark.hostile("outside")
@pytest.mark.parametrize("name", ["../../escaped_cam", "/tmp/escaped", ".hidden"])
def test_camera_names_in_opencv_files_are_one_path_component(tmp_path, name):
    path = tmp_path / "calib.yaml"
    path.write_text(_OPENCV_CAMERA + f"name: \"{name}\"\n")
    with pytest.raises(ValueError, match=r"calib.yaml.name: name .* cannot be a file name"):
        read_cameras(path)


@pytest.mark.hostile("memory")
def test_a_calibration_declaring_a_huge_image_is_refused_and_the_bound_can_be_raised(tmp_path):
    path = _cameras_json(tmp_path / "cameras.json", width=1_000_000, height=1_000_000)
    with pytest.raises(ValueError, match=r"cameras.json: cameras\[0\]: width x height .* max_image_pixels"):
        read_cameras(path)
    assert read_cameras(path, max_image_pixels=10**12)[0].width == 1_000_000


@pytest.mark.hostile("traceback")
def test_an_opencv_matrix_whose_data_misses_its_size_is_a_clear_error(tmp_path):
    path = tmp_path / "calib.yaml"
    path.write_text("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
                    "  data: [100, 0, 48, 0, 100, 32, 0, 0]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nT: [0, 0, 2]\n"
                    "image_size: [96, 64]\n")
    with pytest.raises(ValueError, match="calib.yaml: camera_matrix: not a valid OpenCV matrix"):
        read_cameras(path)


@pytest.mark.hostile("silent")
def test_a_truncated_jpeg_is_refused_not_decoded_grey(tmp_path):
    views = _views(tmp_path / "views", ".jpg")
    image = views / "cam00" / "f000000.jpg"
    whole = image.read_bytes()
    image.write_bytes(whole + b"\0" * 64)  # zero padding after the end marker is harmless
    with Views.open(views, [_camera()]) as opened:
        assert opened.image(0, 0).shape == (64, 96, 3)
    image.write_bytes(whole[: len(whole) * 2 // 3])
    with Views.open(views, [_camera()]) as opened, pytest.raises(ValueError, match="f000000.jpg: truncated JPEG"):
        opened.image(0, 0)


@pytest.mark.hostile("memory")
def test_an_image_whose_header_claims_a_huge_size_is_refused_before_decoding(tmp_path):
    views = _views(tmp_path / "views")

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    side = 50_000  # 7.5 GB of RGB, in a file of a few hundred bytes
    (views / "cam00" / "f000000.png").write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(bytes(3 * side + 1))) + chunk(b"IEND", b""))
    with pytest.raises(ValueError, match="f000000.png: .*(decompression bomb|50000 x 50000)"):
        Views.open(views, [_camera()])


def _points(tmp_path: Path, **change) -> Path:
    path = tmp_path / "f000001.npz"
    CapturedPoints.empty(12, 3, frame=1).save(path)
    save_npz(path, {**load_npz(path), **change})
    return path


@pytest.mark.hostile("silent")
@pytest.mark.parametrize("field, value", [("source", np.zeros(3)), ("level_mm", np.array([12, 13])),
                                          ("frame", np.array("one")), ("level_mm", np.float64(12.5))])
def test_captured_points_scalars_of_the_wrong_kind_are_refused_by_name(tmp_path, field, value):
    with pytest.raises(ValueError, match=f"f000001.npz: {field}: expected"):
        CapturedPoints.load(_points(tmp_path, **{field: value}))


def _sequence():
    from reconstruction.exports import GarmentSequence

    positions = np.random.default_rng(0).random((2, 4, 3))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return GarmentSequence(positions=positions, faces=faces, corner_uv=np.zeros((2, 3, 2)),
                           captured=np.ones((2, 4), bool), frames=np.array([3, 4]), fps=30.0, source="test")


@pytest.mark.hostile("half")
def test_an_export_that_fails_part_way_leaves_the_previous_export_whole(tmp_path, monkeypatch):
    from reconstruction import exports

    folder = tmp_path / "export"
    formats = ("npz", "obj", "ply", "pc2")
    first = exports.export_sequence(folder, _sequence(), formats=formats, progress=False)
    assert all(p.is_file() and p.parent.is_relative_to(folder) for paths in first.values() for p in paths)
    before = files_under(folder)

    def disk_full(path, *args, **kwargs):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(b"POINTCACHE2\0 half")
        raise OSError(errno.ENOSPC, "No space left on device")

    changed = _sequence()
    object.__setattr__(changed, "positions", changed.positions + 1)
    monkeypatch.setattr(exports, "write_pc2", disk_full)
    with pytest.raises(OSError, match="No space left"):
        exports.export_sequence(folder, changed, formats=formats, progress=False)
    assert files_under(folder) == before  # no new npz, OBJ or PLY beside the old point cache, no staging left


@pytest.mark.hostile("memory")
def test_detections_that_would_expand_to_gigabytes_are_refused_before_decompressing(tmp_path):
    import io
    import zipfile

    from networks.detections import Detections

    path = tmp_path / "f000000.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, array in Detections.empty(5).to_dict().items():
            buffer = io.BytesIO()
            if name == "crosspoints_px":  # 10^8 markers' crosspoints: 20 GB, claimed by a header of 128 bytes
                np.lib.format.write_array_header_1_0(buffer, {"descr": "<f4", "fortran_order": False,
                                                              "shape": (10**8, 5, 5, 2)})
            else:
                np.save(buffer, array)
            archive.writestr(f"{name}.npy", buffer.getvalue())
    with pytest.raises(ValueError, match="f000000.npz: the arrays' size in bytes .*max_bytes"):
        Detections.load(path)
