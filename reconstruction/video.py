"""One camera's video, read frame-accurately with PyAV: probing, constant-rate check, seeking.

A video's frame k is the frame whose presentation timestamp (PTS) is the k-th smallest of the stream,
not the k-th frame a decoder happens to return: `probe` demuxes every packet once (no decoding) and
keeps the sorted PTS, the keyframes and the frame step; `VideoReader.frame(k)` seeks to the keyframe at
or before frame k by PTS, decodes forward and checks, from the decoded frame's PTS and the stream's
time base, that it returns frame k (reading on without a seek when no keyframe lies between the last
frame read and k, so sequential reading decodes every frame once).

Refused, each with a ValueError naming the file: a file PyAV cannot open or that holds no video
stream; a stream without timestamps; a **variable frame rate** (PTS steps that are not constant to a
quarter of a frame: phones and screen recorders write these; frame numbers would not be times, so
re-encode at a constant rate first, e.g. ``ffmpeg -i IN -fps_mode cfr -r 30 OUT``); a frame that
cannot be decoded.  Containers with a millisecond time base (Matroska, WebM) round each PTS to the
tick; the step is the mean over the stream, so that rounding is no variable rate.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")
_RATE_TOLERANCE = 0.25  # of a frame step: how far a PTS may sit from the constant-rate grid


@dataclass(frozen=True)
class VideoInfo:
    """What `probe` learnt of a video's first video stream.

    pts: (n,) int64 the frames' PTS, sorted (frame k has pts[k]); keyframes: (m,) int64 sorted frame
    indices of the keyframes; time_base: seconds per PTS tick; step: PTS ticks per frame (a Fraction,
    the mean over the stream); fps: frames per second (the stream's declared rate where it agrees
    with the step to 0.1%, else 1 / step: a millisecond time base cannot hold 30 fps exactly);
    size: (width, height) in pixels."""

    path: Path
    pts: np.ndarray
    keyframes: np.ndarray
    time_base: Fraction
    step: Fraction
    fps: Fraction
    size: tuple[int, int]

    @property
    def num_frames(self) -> int:
        return len(self.pts)

    def index_of(self, pts: int) -> int:
        """The frame index of a PTS: its position on the constant-rate grid from the first frame."""
        return round((Fraction(int(pts)) - int(self.pts[0])) / self.step)

    def keyframe_before(self, frame: int) -> int:
        """The index of the last keyframe at or before `frame` (0 when none is)."""
        at = np.searchsorted(self.keyframes, frame, side="right") - 1
        return int(self.keyframes[at]) if at >= 0 else 0


def probe(path: str | Path) -> VideoInfo:
    """Demux `path` (no decoding) and return its `VideoInfo`; raises ValueError for an unreadable file,
    a file without a video stream or timestamps, and a variable frame rate (module docstring).
    Cached per file version (path, size, modification time): opening a capture twice demuxes once."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the video ({exc.strerror or exc})") from None
    return _probe(path, stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _probe(path: Path, size: int, mtime_ns: int) -> VideoInfo:
    import av

    pts, keyframes = [], []
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise ValueError(f"{path}: holds no video stream")
            stream = container.streams.video[0]
            width, height = stream.codec_context.width, stream.codec_context.height
            time_base, declared = stream.time_base, stream.average_rate or stream.guessed_rate
            for packet in container.demux(stream):
                if packet.size == 0:  # the demuxer's final flush packet
                    continue
                if packet.pts is None:
                    raise ValueError(f"{path}: a packet without a timestamp (PTS); remux it into .mp4 or .mkv")
                pts.append(packet.pts)
                keyframes.append(packet.is_keyframe)
    except av.FFmpegError as exc:
        raise ValueError(f"{path}: not a readable video ({exc})") from None
    if not pts:
        raise ValueError(f"{path}: the video holds no frames")
    if time_base is None or width <= 0 or height <= 0:
        raise ValueError(f"{path}: the video stream has no time base or frame size")
    order = np.argsort(pts, kind="stable")
    pts_sorted = np.asarray(pts, np.int64)[order]
    if len(np.unique(pts_sorted)) != len(pts_sorted):
        raise ValueError(f"{path}: two frames share one timestamp (PTS); the file is damaged or not a plain video")
    step = Fraction(int(pts_sorted[-1] - pts_sorted[0]), max(len(pts_sorted) - 1, 1)) or Fraction(1)
    _check_constant_rate(path, pts_sorted, step, time_base)
    keyframe_frames = np.sort(np.flatnonzero(np.asarray(keyframes)[order]))
    fps = 1 / (step * Fraction(time_base))
    if declared and abs(Fraction(declared) / fps - 1) < 1e-3:
        fps = Fraction(declared)
    return VideoInfo(path, pts_sorted, keyframe_frames.astype(np.int64), Fraction(time_base), step, fps,
                     (width, height))


def _check_constant_rate(path: Path, pts: np.ndarray, step: Fraction, time_base: Fraction) -> None:
    """Raise unless every PTS is within a quarter frame of the constant-rate grid from the first."""
    if len(pts) < 3:
        return
    grid = pts[0] + np.arange(len(pts)) * float(step)
    off = np.abs(pts - grid) / float(step)
    if off.max() > _RATE_TOLERANCE:
        durations = np.diff(pts) * float(time_base)
        worst = int(np.argmax(off))
        raise ValueError(f"{path}: variable frame rate (frame durations from {durations.min() * 1000:.2f} to "
                         f"{durations.max() * 1000:.2f} ms; frame {worst} sits {off[worst]:.2f} frames off the "
                         f"constant-rate grid); only constant-frame-rate video is read: re-encode it, e.g. "
                         f"ffmpeg -i {path.name} -fps_mode cfr -r {float(1 / (step * time_base)):.6g} OUT")


class VideoReader:
    """Frame-accurate random access to one video (module docstring); a context manager.

    One open container and decoder; not shared between processes (open one per worker)."""

    def __init__(self, path: str | Path, info: VideoInfo | None = None):
        import av

        self.info = info or probe(path)
        self.path = self.info.path
        try:
            self._container = av.open(str(self.path))
        except av.FFmpegError as exc:
            raise ValueError(f"{self.path}: not a readable video ({exc})") from None
        self._stream = self._container.streams.video[0]
        self._stream.thread_type = "AUTO"
        self._decoded = None  # the decoding generator after the last seek
        self._next = None  # the frame index the generator returns next, when known

    def frame(self, index: int, format: str = "rgb24") -> np.ndarray:
        """Frame `index` as an (H, W, 3) uint8 array (`format` rgb24 or bgr24; gray gives (H, W))."""
        return self._decode(index).to_ndarray(format=format)

    def frames(self, first: int, stop: int, format: str = "rgb24", width: int | None = None,
               height: int | None = None):
        """Frames first .. stop - 1 in order as arrays, each optionally resized to `width` x `height`
        by the decoder's scaler (one seek at most)."""
        for index in range(first, stop):
            frame = self._decode(index)
            if width is not None:
                frame = frame.reformat(width=width, height=height)
            yield frame.to_ndarray(format=format)

    def close(self) -> None:
        self._decoded = None
        self._container.close()

    def __enter__(self) -> "VideoReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _decode(self, index: int):
        import av

        info = self.info
        if not 0 <= index < info.num_frames:
            raise ValueError(f"{self.path}: frame {index} outside the video's frames 0-{info.num_frames - 1}")
        keyframe = info.keyframe_before(index)
        seeked = self._next is None or not keyframe <= self._next <= index
        while True:
            if seeked:
                self._seek(keyframe)
            try:
                for frame in self._decoded:
                    at = info.index_of(frame.pts if frame.pts is not None else frame.dts)
                    self._next = at + 1
                    if at == index:
                        return frame
                    if at > index:
                        break
            except av.FFmpegError as exc:
                self._next = None
                raise ValueError(f"{self.path}: frame {index} cannot be decoded ({exc})") from None
            self._next = None
            if seeked and keyframe == 0:
                raise ValueError(f"{self.path}: frame {index} was not found where its timestamp says "
                                 f"(PTS {int(info.pts[index])}); the file is damaged or its index is wrong")
            if seeked:  # the demuxer landed after the frame: start from the keyframe before
                keyframe = info.keyframe_before(keyframe - 1)
            seeked = True

    def _seek(self, keyframe: int) -> None:
        """Seek to the keyframe of frame index `keyframe` (demuxers land at or before a PTS)."""
        self._container.seek(int(self.info.pts[keyframe]), stream=self._stream, backward=True, any_frame=False)
        self._decoded = self._container.decode(self._stream)
        self._next = None


def chunks(num_frames: int, size: int) -> list[tuple[int, int]]:
    """[first, stop) ranges of at most `size` frames covering 0 .. num_frames - 1."""
    return [(first, min(first + size, num_frames)) for first in range(0, num_frames, size)]


def run_in_workers(function, jobs: list[tuple], weights: list[int], workers: int | None, desc: str,
                   progress: bool) -> list:
    """`function(*job)` for every job in spawned worker processes (at most `workers`, default one per
    CPU core; in this process when that is one), a tqdm bar advancing by each finished job's weight; results in job order.  A failing
    job's error is raised in the caller after the others were cancelled."""
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from tqdm import tqdm

    if not jobs:
        return []
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    results: list = [None] * len(jobs)
    if workers == 1:  # no process to start
        with tqdm(total=sum(weights), desc=desc, unit="frame", disable=not progress) as bar:
            for i, job in enumerate(jobs):
                results[i] = function(*job)
                bar.update(weights[i])
        return results
    # spawn, not fork: the caller may hold threads (torch, PyAV's decoders) that a fork would copy locked
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool, \
            tqdm(total=sum(weights), desc=desc, unit="frame", disable=not progress) as bar:
        futures = {pool.submit(function, *job): i for i, job in enumerate(jobs)}
        try:
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                bar.update(weights[futures[future]])
        except BaseException:
            for future in futures:
                future.cancel()
            raise
    return results
