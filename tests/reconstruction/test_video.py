"""Synchronised video: frame-accurate seeking, offsets (from JSON and estimated from motion), the
variable-frame-rate and unreadable-file refusals, and resumable extraction in worker processes.

Every video is encoded here with PyAV: 64 x 48 pixels, a square that moves stop-and-go, and (where a
test reads frame numbers back) the scene time written as 8 binary blocks across the top, big enough
to survive the lossy codecs."""

import json
from fractions import Fraction

import av
import numpy as np
import pytest

from assets.cameras import Camera
from reconstruction.video import VideoReader, probe
from reconstruction.video_extract import extract_frames, find_videos, frame_path
from reconstruction.video_sync import estimate_offsets, read_offsets
from reconstruction.views import Views

WIDTH, HEIGHT = 64, 48


def _trajectory(seed=7, length=80):
    """Scene time -> x of the square: random stop-and-go speeds (pixels per frame) held for a few
    frames each; scene time t is index t + 20 (times -20 .. length - 21)."""
    rng = np.random.default_rng(seed)
    speeds = np.repeat(rng.choice([0, 0, 1, 3, 6], size=length // 4 + 1), 4)[:length]
    return np.cumsum(speeds) % (WIDTH - 12)


def _scene(t, code=True, mirrored=False, background=30):
    """The RGB image of scene time t (as a camera sees it)."""
    image = np.full((HEIGHT, WIDTH, 3), background, np.uint8)
    x = int(_trajectory()[t + 20])
    square = np.zeros((12, 12, 3), np.uint8)
    square[::2, :, 0], square[:, ::3, 1], square[..., 2] = 255, 220, 160  # a textured square
    image[24:36, x:x + 12] = square
    if code:
        bits = (t >> np.arange(8)) & 1
        image[:16] = np.repeat(bits * 255, 8)[None, :, None].astype(np.uint8)
    return image[:, ::-1].copy() if mirrored else image


def _code(rgb):
    """The scene time written in the top band of an image."""
    bits = rgb[:16].reshape(16, 8, 8, 3).mean(axis=(0, 2, 3)) > 127
    return int((bits * (1 << np.arange(8))).sum())


def _encode(path, images, codec="libx264", pts=None, gop=8):
    """Write RGB `images` as a 30 fps video (`pts`: the frames' timestamps in 1/30 s, default 0, 1, ...)."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=30)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.codec_context.gop_size = gop
        for i, image in enumerate(images):
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            frame.pts, frame.time_base = (i if pts is None else pts[i]), Fraction(1, 30)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return path


def _camera(name):
    return Camera.look_at((0.0, -3.0, 1.0), (0.0, 0.0, 1.0), width=WIDTH, height=HEIGHT, name=name)


@pytest.mark.parametrize("codec, suffix", [("libx264", ".mp4"), ("mpeg4", ".mkv")])
def test_seeking_returns_exactly_the_frame_asked_for(tmp_path, codec, suffix):
    # h264 with B-frames reorders frames in the file; Matroska rounds 30 fps timestamps to milliseconds
    path = _encode(tmp_path / f"clip{suffix}", [_scene(t) for t in range(30)], codec)
    info = probe(path)
    assert info.num_frames == 30 and info.size == (WIDTH, HEIGHT) and info.fps == 30
    assert len(info.keyframes) >= 3 and info.keyframes[0] == 0  # so seeks cross GOPs
    with VideoReader(path) as reader:
        order = [17, 3, 29, 0, 8, 9, 7, 16, 15, 24, 25, 26, 1]  # back, forward, across keyframes, neighbours
        assert [_code(reader.frame(k)) for k in order] == order
        assert [_code(image) for image in reader.frames(0, 30)] == list(range(30))
        with pytest.raises(ValueError, match=r"clip.*: frame 30 outside the video's frames 0-29"):
            reader.frame(30)


def test_variable_frame_rate_and_unreadable_files_are_refused_by_name(tmp_path):
    vfr = _encode(tmp_path / "phone.mp4", [_scene(t) for t in range(12)], pts=[0, 1, 2, 4, 5, 6, 9, 10, 11, 12, 14, 15])
    with pytest.raises(ValueError, match=r"phone\.mp4: variable frame rate \(frame durations from 33\.33 to 100\.00 ms"):
        probe(vfr)
    (tmp_path / "cam00.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a video" * 10)
    with pytest.raises(ValueError, match=r"cam00\.mp4: not a readable video"):
        Views.open(tmp_path, [_camera("cam00")])
    (tmp_path / "empty.mkv").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.mkv: not a readable video"):
        probe(tmp_path / "empty.mkv")
    with pytest.raises(ValueError, match=r"missing\.mp4: cannot read the video"):
        probe(tmp_path / "missing.mp4")
    vfr.rename(tmp_path / "cam00.mp4")
    with pytest.raises(ValueError, match=r"cam00\.mp4: variable frame rate"):
        Views.open(tmp_path, [_camera("cam00")])


def test_offsets_are_estimated_from_the_motion_both_cameras_see(tmp_path):
    # camera b started recording 4 frames before a: its video frame k + 4 is a's frame k
    _encode(tmp_path / "a.mp4", [_scene(t, code=False) for t in range(30)])
    _encode(tmp_path / "b.mp4", [_scene(t - 4, code=False, mirrored=True, background=90) for t in range(30)], "mpeg4")
    # and camera c started 3 frames after a, and stopped earlier
    _encode(tmp_path / "c.mp4", [_scene(t + 3, code=False, background=60) for t in range(26)])
    estimates = estimate_offsets(find_videos(tmp_path), reference="a", workers=2, progress=False)
    assert {name: e.offset for name, e in estimates.items()} == {"a": 0, "b": 4, "c": -3}
    assert all(e.confident for e in estimates.values()), estimates
    # a camera that sees no motion gives no confident offset
    _encode(tmp_path / "still.mp4", [_scene(0, code=False) for _ in range(30)])
    still = estimate_offsets({"a": tmp_path / "a.mp4", "still": tmp_path / "still.mp4"}, workers=1, progress=False)
    assert not still["still"].confident


def test_views_apply_offsets_and_extraction_resumes(tmp_path):
    views = tmp_path / "views"
    views.mkdir()
    _encode(views / "a.mp4", [_scene(t) for t in range(30)])
    _encode(views / "b.mkv", [_scene(t - 4) for t in range(28)], "mpeg4")  # b's frame k + 4 is a's frame k
    (views / "offsets.json").write_text(json.dumps({"b": 4}))
    cameras = [_camera("a"), _camera("b")]
    with Views.open(views, cameras) as opened:  # offsets.json is found beside the videos
        assert opened.frames == tuple(range(24))  # b's last 4 frames are past its end
        assert [[_code(image) for image in images] for _, images in opened] == [[k, k] for k in range(24)]
        assert _code(opened.image(5, "b")) == 5 and opened.describe(5, "b").endswith("b.mkv frame 9")
    assert Views.open(views, cameras, offsets={"b": 0}).frames == tuple(range(28))
    assert read_offsets(views / "offsets.json", ["a", "b"]) == {"a": 0, "b": 4}
    (tmp_path / "bad.json").write_text(json.dumps({"b": 2.5}))
    with pytest.raises(ValueError, match=r"bad\.json: the offset of camera 'b' must be a whole number of frames"):
        Views.open(views, cameras, offsets=tmp_path / "bad.json")
    with pytest.raises(ValueError, match=r"offsets for unknown camera\(s\) \['z'\]"):
        Views.open(views, cameras, offsets={"z": 1})

    out = tmp_path / "frames"
    videos = find_videos(views, ["a", "b"])
    assert extract_frames(videos, out, {"b": 4}, frames=range(0, 20), workers=2, progress=False) == 40
    with Views.open(out, cameras) as folders, Views.open(views, cameras, frames=range(0, 20)) as videos_view:
        assert folders.frames == videos_view.frames == tuple(range(20))
        for frame in (0, 7, 19):  # the folders read as the videos do
            for camera in ("a", "b"):
                np.testing.assert_array_equal(folders.image(frame, camera), videos_view.image(frame, camera))
    lost = [frame_path(out, "b", 3), frame_path(out, "a", 11)]
    for path in lost:
        path.unlink()
    kept = {p: p.stat().st_mtime_ns for p in out.rglob("*.png")}
    assert len(kept) == 38
    assert extract_frames(videos, out, {"b": 4}, frames=range(0, 20), workers=2, progress=False) == 2  # resumed
    assert all(p.stat().st_mtime_ns == t for p, t in kept.items()) and all(p.is_file() for p in lost)
    assert _code(Views.open(out, cameras).image(3, "b")) == 3 and not list(out.rglob("*.partial"))


def test_cli_writes_confident_offsets_and_extracts(tmp_path, capsys):
    from reconstruction.__main__ import main

    _encode(tmp_path / "a.mp4", [_scene(t, code=False) for t in range(30)])
    _encode(tmp_path / "b.mp4", [_scene(t - 4, code=False, mirrored=True) for t in range(30)])
    assert main(["video", "offsets", str(tmp_path), "--workers", "1", "--no-progress"]) == 0
    assert json.loads((tmp_path / "offsets.json").read_text()) == {"a": 0, "b": 4}
    assert "b                    +4" in capsys.readouterr().out
    _encode(tmp_path / "c.mp4", [_scene(0, code=False) for _ in range(30)])  # no motion to align
    assert main(["video", "offsets", str(tmp_path), "--out", str(tmp_path / "all.json"), "--workers", "1",
                 "--no-progress"]) == 1
    assert "offsets of ['c'] are not confident: nothing written" in capsys.readouterr().err
    assert not (tmp_path / "all.json").exists()
    (tmp_path / "c.mp4").unlink()
    argv = ["video", "extract", str(tmp_path), "--out", str(tmp_path / "frames"), "--first", "2", "--last", "5",
            "--workers", "1", "--no-progress"]
    assert main(argv) == 0 and "8 images written" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "frames" / "b").iterdir()) == [f"f{k:06d}.png" for k in range(2, 6)]
    assert main(argv) == 0 and "0 images written" in capsys.readouterr().out  # all there: nothing decoded
    assert main(["video", "extract", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    assert "nowhere: not a folder of videos" in capsys.readouterr().err

