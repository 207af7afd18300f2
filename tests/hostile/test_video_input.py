"""Hostile video captures: files that are not videos, a variable frame rate, a video larger than its
camera, and offsets files of the wrong shape, through `python -m reconstruction video` and `Views`."""

import json
from fractions import Fraction

import av
import numpy as np
import pytest

from assets.cameras import Camera
from reconstruction.views import Views
from tests.hostile.conftest import assert_refused, files_under


def _video(path, size=(64, 48), pts=None, frames=10):
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=30)
        stream.width, stream.height, stream.pix_fmt = *size, "yuv420p"
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(np.full((size[1], size[0], 3), 20 * i, np.uint8), format="rgb24")
            frame.pts, frame.time_base = (i if pts is None else pts[i]), Fraction(1, 30)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return path


def _camera(name="cam00"):
    return Camera.look_at((0.0, -3.0, 1.0), (0.0, 0.0, 1.0), width=64, height=48, name=name)


@pytest.mark.hostile("traceback")
def test_a_file_named_like_a_video_that_is_not_one_is_a_clear_error(tmp_path, cli):
    (tmp_path / "cam00.mp4").write_bytes(np.random.default_rng(0).bytes(4096))
    assert_refused(cli("reconstruction", "video", "offsets", tmp_path, "--no-progress"),
                   "cam00.mp4: not a readable video")


@pytest.mark.hostile("silent")
def test_a_variable_frame_rate_is_refused_by_name_and_nothing_is_written(tmp_path, cli):
    _video(tmp_path / "a.mkv")
    _video(tmp_path / "b.mkv", pts=[0, 1, 2, 3, 5, 6, 7, 9, 10, 11])  # frames dropped: times, not numbers
    before = files_under(tmp_path)
    assert_refused(cli("reconstruction", "video", "extract", tmp_path, "--out", tmp_path / "frames", "--no-progress"),
                   "b.mkv: variable frame rate")
    assert files_under(tmp_path) == before


@pytest.mark.hostile("memory")
def test_a_video_larger_than_its_camera_is_refused_before_decoding(tmp_path):
    _video(tmp_path / "cam00.mp4", size=(640, 480), frames=2)
    with pytest.raises(ValueError, match=r"calibrated for 64 x 48 pixels but its images are 640 x 480"):
        Views.open(tmp_path, [_camera()])


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("offsets, message", [([3], r'expected an object \{"camera name": offset_frames\}, got list'),
                                              ({"cam00": "5"}, r"the offset of camera 'cam00' must be a whole number"),
                                              ("{not json", r"not a readable offsets JSON file")])
def test_offsets_of_the_wrong_shape_are_a_clear_error(tmp_path, offsets, message):
    _video(tmp_path / "cam00.mp4", frames=2)
    text = offsets if isinstance(offsets, str) else json.dumps(offsets)
    (tmp_path / "offsets.json").write_text(text)
    with pytest.raises(ValueError, match=r"offsets\.json: " + message):
        Views.open(tmp_path, [_camera()])
