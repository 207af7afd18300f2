"""Video capture -> folders of frames: every camera's video decoded in worker processes, resumable.

`extract_frames` writes capture frame k of camera N (its video frame k + offset, `video_sync`) to
``out/N/f<k:06d>.png``, so ``out`` reads as folders of frames with no offsets left to apply.  The
work is cut into chunks of consecutive frames per camera (each decoded after one seek) spread over
worker processes, with a progress bar.  Each image is written under a temporary name and renamed, so
an interrupted run leaves no half image; a rerun skips the images already there and decodes only the
rest.  `find_videos` finds the videos of a capture folder.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

from reconstruction.video import VIDEO_SUFFIXES, VideoReader, probe, run_in_workers
from reconstruction.video_sync import check_rates, overlap

_CHUNK_FRAMES = 120


def find_videos(root: str | Path, cameras: Sequence[str] | None = None) -> dict[str, Path]:
    """Camera name -> video file in the folder `root`: ``root/N.<video>`` for each camera N of
    `cameras` (or ``root/camII.<video>``, II its position), or, without `cameras`, every video in
    `root` named by its stem, sorted by name."""
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"{root}: not a folder of videos")
    found = {p.stem: p for p in sorted(root.iterdir()) if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES}
    if cameras is None:
        if not found:
            raise ValueError(f"{root}: no videos ({', '.join(VIDEO_SUFFIXES)})")
        return found
    videos = {}
    for index, name in enumerate(cameras):
        stem = next((s for s in (name, f"cam{index:02d}") if s in found), None)
        if stem is None:
            raise ValueError(f"{root}: no video for camera {index} {name!r} (looked for {name} or cam{index:02d} "
                             f"with {'/'.join(VIDEO_SUFFIXES)}; found {sorted(found)[:12]})")
        videos[name] = found[stem]
    return videos


def frame_path(out: str | Path, camera: str, frame: int) -> Path:
    """Where `extract_frames` writes capture frame `frame` of `camera`."""
    return Path(out) / camera / _name(frame)


def _name(frame: int) -> str:
    return f"f{frame:06d}.png"


def extract_frames(videos: Mapping[str, str | Path], out: str | Path, offsets: Mapping[str, int] | None = None,
                   frames: Sequence[int] | None = None, workers: int | None = None, progress: bool = True) -> int:
    """Write every camera's capture `frames` (default: all that every video holds after `offsets`)
    as PNG images under `out` (module docstring); returns how many images were written (0 when all
    were there)."""
    offsets = {name: int((offsets or {}).get(name, 0)) for name in videos}
    infos = {name: probe(path) for name, path in videos.items()}
    check_rates({info.path.name: info.fps for info in infos.values()})
    held = overlap({name: info.num_frames for name, info in infos.items()}, offsets)
    frames = list(held) if frames is None else sorted(set(frames))
    outside = [f for f in frames if f not in held]
    if outside:
        raise ValueError(f"frames {outside[:8]} were asked for but the videos share frames {held.start}-{held.stop - 1}")
    if frames and frames[0] < 0:
        raise ValueError(f"capture frame {frames[0]} is negative: give the offsets relative to a camera that "
                         f"started last (offset 0), so that capture frames start at 0")
    jobs = []
    for name, path in videos.items():
        todo = [f for f in frames if not frame_path(out, name, f).exists()]
        for first in range(0, len(todo), _CHUNK_FRAMES):
            jobs.append((str(path), str(Path(out) / name), offsets[name], todo[first:first + _CHUNK_FRAMES]))
    written = run_in_workers(_extract_chunk, jobs, [len(job[3]) for job in jobs], workers, "extract frames", progress)
    return sum(written)


def _extract_chunk(path: str, folder: str, offset: int, frames: list[int]) -> int:
    """Decode capture `frames` (sorted) of one video and write each PNG atomically; returns the count."""
    import cv2

    os.makedirs(folder, exist_ok=True)
    with VideoReader(path) as reader:
        for frame in frames:
            ok, png = cv2.imencode(".png", reader.frame(frame + offset, "bgr24"))
            if not ok:
                raise ValueError(f"{path} frame {frame + offset}: cannot be encoded as PNG")
            target = Path(folder) / _name(frame)
            temporary = target.with_name(target.name + ".partial")
            temporary.write_bytes(png.tobytes())
            temporary.replace(target)
    return len(frames)
