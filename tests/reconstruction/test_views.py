"""Input views: folders of frames and videos per camera, synchronisation and size checks."""

import cv2
import numpy as np
import pytest

from assets.cameras import Camera
from reconstruction.views import Views


def _camera(name, width=32, height=24):
    return Camera.look_at((0.0, -3.0, 1.0), (0.0, 0.0, 1.0), width=width, height=height, name=name)


def _image(camera_index, frame, width=32, height=24):
    """A recognisable RGB image: red = camera, green = frame, a blue pixel at the top-left."""
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[..., 0], rgb[..., 1] = 40 * camera_index, 10 * frame
    rgb[0, 0] = (0, 0, 255)
    return rgb


def _folder(path, camera_index, frames, name="f{:06d}.png", size=(32, 24)):
    path.mkdir(parents=True, exist_ok=True)
    for f in frames:
        cv2.imwrite(str(path / name.format(f)), _image(camera_index, f, *size)[:, :, ::-1])
    return path


def test_folders_named_after_the_cameras_or_numbered(tmp_path):
    cameras = [_camera("left"), _camera("right")]
    _folder(tmp_path / "left", 0, [3, 4, 12])
    _folder(tmp_path / "cam01", 1, [3, 4, 12], name="img_{}.png")  # numbered folder, other file names
    (tmp_path / "left" / "f000003_depth.exr").write_bytes(b"not an image we read")
    (tmp_path / "left" / "f000003_gt.npz").write_bytes(b"nor this")
    views = Views.open(tmp_path, cameras)
    assert views.frames == (3, 4, 12) and len(views) == 3
    image = views.image(12, "right")
    assert image.dtype == np.uint8 and image.shape == (24, 32, 3)
    np.testing.assert_array_equal(image, _image(1, 12))  # RGB, the right camera, the right frame
    frames = [(frame, [im[1, 1].tolist() for im in images]) for frame, images in views]
    assert frames == [(3, [[0, 30, 0], [40, 30, 0]]), (4, [[0, 40, 0], [40, 40, 0]]), (12, [[0, 120, 0], [40, 120, 0]])]
    assert Views.open(tmp_path, cameras, frames=[4]).frames == (4,)
    with pytest.raises(ValueError, match=r"frames 5 were asked for but the views hold 3-4, 12"):
        Views.open(tmp_path, cameras, frames=[4, 5])


def test_missing_frames_are_listed_per_camera(tmp_path):
    cameras = [_camera("cam00"), _camera("cam01"), _camera("cam02")]
    _folder(tmp_path / "cam00", 0, range(10))
    _folder(tmp_path / "cam01", 1, [0, 1, 2, 3, 7, 8, 9])
    _folder(tmp_path / "cam02", 2, range(11))
    with pytest.raises(ValueError, match=r"not synchronised: cam00 lacks frame\(s\) 10; "
                                         r"cam01 lacks frame\(s\) 4-6, 10"):
        Views.open(tmp_path, cameras)


def test_image_sizes_and_names_are_checked(tmp_path):
    _folder(tmp_path / "a", 0, [1, 2], size=(40, 24))
    with pytest.raises(ValueError, match=r"camera 'a' is calibrated for 32 x 24 pixels but its images are 40 x 24"):
        Views.open(tmp_path, [_camera("a")])
    _folder(tmp_path / "b", 0, [1, 2])
    cv2.imwrite(str(tmp_path / "b" / "f000002.png"), np.zeros((10, 10, 3), np.uint8))  # a later frame differs
    views = Views.open(tmp_path, [_camera("b")])
    with pytest.raises(ValueError, match=r"f000002\.png: image is 10 x 10 pixels, camera 'b' is calibrated"):
        views.image(2, 0)
    _folder(tmp_path / "c", 0, [1])
    cv2.imwrite(str(tmp_path / "c" / "thumbnail.png"), np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match=r"image names must end in the frame number, got \['thumbnail.png'\]"):
        Views.open(tmp_path, [_camera("c")])
    _folder(tmp_path / "d", 0, [1])
    _folder(tmp_path / "d", 0, [1], name="g{:03d}.jpg")
    with pytest.raises(ValueError, match=r"f000001.png and g001.jpg are both frame 1"):
        Views.open(tmp_path, [_camera("d")])
    with pytest.raises(ValueError, match=r"no folder or video for camera 0 'e' \(looked for e or cam00"):
        Views.open(tmp_path, [_camera("e")])


def test_one_video_per_camera(tmp_path):
    for c in range(2):
        writer = cv2.VideoWriter(str(tmp_path / f"cam{c:02d}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (32, 24))
        for f in range(6):
            writer.write(np.full((24, 32, 3), 40 * f + c, np.uint8))
        writer.release()
    views = Views.open({"cam00": tmp_path / "cam00.avi", "cam01": tmp_path / "cam01.avi"},
                       [_camera("cam00"), _camera("cam01")])
    assert views.frames == tuple(range(6))
    with views:
        seen = [float(images[1].mean()) for _, images in views]  # sequential reading
        assert np.allclose(seen, [40 * f + 1 for f in range(6)], atol=3)  # MJPG is lossy
        assert abs(views.image(2, 0).mean() - 80) < 3  # and going back
    writer = cv2.VideoWriter(str(tmp_path / "short.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (32, 24))
    for f in range(4):
        writer.write(np.zeros((24, 32, 3), np.uint8))
    writer.release()
    shorter = Views.open({"cam00": tmp_path / "cam00.avi", "cam01": tmp_path / "short.avi"},
                         [_camera("cam00"), _camera("cam01")])  # videos stop at different moments
    assert shorter.frames == tuple(range(4))
