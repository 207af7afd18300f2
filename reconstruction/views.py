"""Input views: frame-synchronised images of every calibrated camera, from folders or videos.

`Views.open(root, cameras)` finds, for camera number i named N, in `root` (first match wins):
``root/N/`` (a folder of frames), ``root/N.<video>``, ``root/camII/``, ``root/camII.<video>`` (II the
camera's position in `cameras`, two digits: the factory's capture layout); or take an explicit
mapping camera name -> folder or video file.

* A folder of frames: every image file in it (``.png .jpg .jpeg .bmp .tif .tiff``) is one frame,
  numbered by the digits that end its name (``f000012.png`` is frame 12, ``img_7.jpg`` frame 7),
  sorted by that number.  Other files (the factory's ``_depth.exr`` and ``_gt.npz``) are ignored;
  an image whose name does not end in digits, or two images of one frame, are errors.
* A video (``.mp4 .avi .mov .mkv .webm .m4v``, read with PyAV through `reconstruction.video`): frame
  k is the frame with the k-th timestamp, from 0, found by seeking and checked against its timestamp;
  a variable frame rate, or videos of different frame rates, are refused.

Per-camera frame offsets (`reconstruction.video_sync`: ``{"camera name": offset_frames}``, from the
argument `offsets` or else ``root/offsets.json``) say that capture frame k is the camera's frame (or
image number) k + offset; they are estimated from motion by ``python -m reconstruction video offsets``.

Folders of frames must have the same frame numbers (the error lists what each camera misses); when
every camera is a video, the capture's frames are those all videos hold after their offsets (cameras
start and stop recording at different moments), and how many frames each video loses is logged.
Images must be of the camera's calibrated size (checked on the first frame when opening, and on every image read, from the
file's header before it is decoded, so a file claiming a huge image allocates nothing).  A JPEG
without its end marker (a truncated file, which OpenCV would decode with a grey lower part) is
refused.  Images are returned as (H, W, 3) uint8 RGB.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Mapping, Sequence

import cv2
import numpy as np
from PIL import Image

from assets.cameras import Camera
from reconstruction.cameras import validate_cameras
from reconstruction.video import VIDEO_SUFFIXES, VideoReader, probe
from reconstruction.video_sync import check_offsets, check_rates, overlap, read_offsets

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
OFFSETS_FILE = "offsets.json"
_TRAILING_NUMBER = re.compile(r"(\d+)$")


@dataclass(frozen=True)
class ImageFolder:
    """One camera's frames as image files: frame number -> path."""

    folder: Path
    files: Mapping[int, Path]

    @classmethod
    def scan(cls, folder: Path) -> "ImageFolder":
        files: dict[int, Path] = {}
        unnumbered = []
        for path in sorted(folder.iterdir()):
            if not path.is_file() or path.suffix.lower() not in IMAGE_SUFFIXES:
                continue
            match = _TRAILING_NUMBER.search(path.stem)
            if match is None:
                unnumbered.append(path.name)
                continue
            frame = int(match.group(1))
            if frame in files:
                raise ValueError(f"{folder}: {files[frame].name} and {path.name} are both frame {frame}")
            files[frame] = path
        if unnumbered:
            raise ValueError(f"{folder}: image names must end in the frame number, got {unnumbered[:5]}")
        if not files:
            raise ValueError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
        return cls(folder, dict(sorted(files.items())))

    @property
    def frames(self) -> list[int]:
        return list(self.files)

    def describe(self, frame: int) -> str:
        return str(self.files[frame])

    def shifted(self, offset: int) -> "ImageFolder":
        """The same images with capture frame k the image numbered k + `offset`."""
        return ImageFolder(self.folder, {frame - offset: path for frame, path in self.files.items()})


@dataclass(frozen=True)
class VideoFile:
    """One camera's frames as a video file: capture frame k is its frame k + offset (frames
    -offset .. num_frames - 1 - offset)."""

    path: Path
    num_frames: int
    size: tuple[int, int]
    fps: float
    offset: int = 0

    @classmethod
    def probe(cls, path: Path, offset: int = 0) -> "VideoFile":
        info = probe(path)
        return cls(path, info.num_frames, info.size, float(info.fps), offset)

    @property
    def frames(self) -> list[int]:
        return list(range(-self.offset, self.num_frames - self.offset))

    def describe(self, frame: int) -> str:
        return f"{self.path} frame {frame + self.offset}"


Source = ImageFolder | VideoFile


class Views:
    """Frame-synchronised images of every camera (module docstring).

    cameras: the calibrated cameras, in order; frames: the frame numbers every camera has, sorted;
    sources: per camera its `ImageFolder` or `VideoFile`."""

    def __init__(self, cameras: Sequence[Camera], sources: Sequence[Source], frames: Sequence[int] | None = None):
        if len(cameras) != len(sources):
            raise ValueError(f"{len(cameras)} cameras but {len(sources)} view sources")
        self.cameras = tuple(cameras)
        self.sources = tuple(sources)
        validate_cameras(self.cameras, "views")
        if all(isinstance(s, VideoFile) for s in self.sources):
            common = _overlap(self.cameras, self.sources)
        else:
            common = check_synchronised({c.name: s.frames for c, s in zip(self.cameras, self.sources)})
        if frames is not None:
            missing = sorted(set(frames) - set(common))
            if not len(frames):
                raise ValueError("an empty list of frames was asked for")
            if missing:
                raise ValueError(f"frames {_ranges(missing)} were asked for but the views hold {_ranges(common)}")
            common = sorted(set(frames))
        self.frames = tuple(common)
        self._videos: dict[int, VideoReader] = {}
        for camera, source in zip(self.cameras, self.sources):
            size = source.size if isinstance(source, VideoFile) else _size_of(source.files[self.frames[0]])
            validate_cameras(self.cameras, source.describe(self.frames[0]), image_sizes={camera.name: size})

    @classmethod
    def open(cls, views: str | Path | Mapping[str, str | Path], cameras: Sequence[Camera],
             frames: Sequence[int] | None = None,
             offsets: str | Path | Mapping[str, int] | None = None) -> "Views":
        """Find every camera's folder or video in the folder `views` (or take the mapping camera name
        -> path), check them, and keep `frames` (default: all); `offsets` (a JSON file or a mapping
        camera name -> frames; default ``views/offsets.json`` if there) shift each camera's frames."""
        if isinstance(views, Mapping):
            unknown = sorted(set(views) - {c.name for c in cameras})
            if unknown:
                raise ValueError(f"views given for unknown camera(s) {unknown}")
            paths = []
            for camera in cameras:
                if camera.name not in views:
                    raise ValueError(f"no views given for camera {camera.name!r}")
                paths.append(Path(views[camera.name]))
        else:
            root = Path(views)
            if not root.is_dir():
                raise ValueError(f"{root}: not a folder of views")
            paths = [_find(root, camera.name, i) for i, camera in enumerate(cameras)]
            if offsets is None and (root / OFFSETS_FILE).is_file():
                offsets = root / OFFSETS_FILE
        names = [camera.name for camera in cameras]
        if offsets is None:
            shifts = dict.fromkeys(names, 0)
        elif isinstance(offsets, Mapping):
            shifts = check_offsets(offsets, names)
        else:
            shifts = read_offsets(offsets, names)
        sources = []
        for name, path in zip(names, paths):
            if path.is_dir():
                sources.append(ImageFolder.scan(path).shifted(shifts[name]))
            elif path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES:
                sources.append(VideoFile.probe(path, shifts[name]))
            else:
                raise ValueError(f"{path}: neither a folder of frames nor a video ({', '.join(VIDEO_SUFFIXES)})")
        return cls(cameras, sources, frames)

    def __len__(self) -> int:
        return len(self.frames)

    def camera_index(self, camera: int | str) -> int:
        if isinstance(camera, str):
            names = [c.name for c in self.cameras]
            if camera not in names:
                raise ValueError(f"no camera named {camera!r} (cameras: {names})")
            return names.index(camera)
        if not 0 <= camera < len(self.cameras):
            raise ValueError(f"camera index {camera} outside [0, {len(self.cameras)})")
        return int(camera)

    def describe(self, frame: int, camera: int | str) -> str:
        """Where the image of (`frame`, `camera`) comes from, for messages."""
        return self.sources[self.camera_index(camera)].describe(frame)

    def image(self, frame: int, camera: int | str) -> np.ndarray:
        """The (H, W, 3) uint8 RGB image of `camera` (index or name) at frame number `frame`."""
        c = self.camera_index(camera)
        if frame not in self.frames:
            raise ValueError(f"frame {frame} is not among the views' frames {_ranges(self.frames)}")
        source, calibrated = self.sources[c], self.cameras[c]
        if isinstance(source, ImageFolder):
            bgr = _read_image(source.files[frame], calibrated)
        else:
            bgr = self._video_frame(c, source, frame)
        if bgr.shape[:2] != (calibrated.height, calibrated.width):
            raise ValueError(f"{source.describe(frame)}: image is {bgr.shape[1]} x {bgr.shape[0]} pixels, camera "
                             f"{calibrated.name!r} is calibrated for {calibrated.width} x {calibrated.height}")
        return np.ascontiguousarray(bgr[:, :, ::-1])

    def images(self, frame: int) -> list[np.ndarray]:
        """Every camera's image at `frame`, in camera order."""
        return [self.image(frame, c) for c in range(len(self.cameras))]

    def __iter__(self) -> Iterator[tuple[int, list[np.ndarray]]]:
        """(frame number, every camera's image) in frame order (videos are read sequentially)."""
        for frame in self.frames:
            yield frame, self.images(frame)

    def close(self) -> None:
        for reader in self._videos.values():
            reader.close()
        self._videos.clear()

    def __enter__(self) -> "Views":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _video_frame(self, c: int, source: VideoFile, frame: int) -> np.ndarray:
        if c not in self._videos:
            self._videos[c] = VideoReader(source.path)
        return self._videos[c].frame(frame + source.offset, "bgr24")


def check_synchronised(frames: Mapping[str, Sequence[int]]) -> list[int]:
    """Camera name -> its frame numbers; returns the shared sorted frame numbers, or raises listing
    what each camera misses of the others' frames."""
    sets = {name: set(f) for name, f in frames.items()}
    if not sets:
        raise ValueError("no cameras")
    union = set().union(*sets.values())
    missing = {name: sorted(union - s) for name, s in sets.items() if union - s}
    if missing:
        lines = "; ".join(f"{name} lacks frame(s) {_ranges(m)}" for name, m in missing.items())
        raise ValueError(f"the cameras' frames are not synchronised: {lines}")
    return sorted(union)


def _overlap(cameras: Sequence[Camera], videos: Sequence[VideoFile]) -> list[int]:
    """The capture frames every video holds after its offset (`video_sync.overlap`), after checking
    that they run at one rate; logs the frames each video loses."""
    check_rates({video.path.name: video.fps for video in videos})
    frames = overlap({c.name: v.num_frames for c, v in zip(cameras, videos)},
                     {c.name: v.offset for c, v in zip(cameras, videos)})
    for video in videos:
        if video.num_frames > len(frames):
            log.info("%s: %d of its %d frames lie outside the frames all cameras hold (%d-%d)", video.path,
                     video.num_frames - len(frames), video.num_frames, frames[0], frames[-1])
    return list(frames)


def _find(root: Path, name: str, index: int) -> Path:
    names = [name, f"cam{index:02d}"] if name != f"cam{index:02d}" else [name]
    for stem in names:
        if (root / stem).is_dir():
            return root / stem
        for suffix in VIDEO_SUFFIXES:
            if (root / f"{stem}{suffix}").is_file():
                return root / f"{stem}{suffix}"
    present = sorted(p.name for p in root.iterdir())[:12]
    raise ValueError(f"{root}: no folder or video for camera {index} {name!r} (looked for "
                     f"{' or '.join(names)}, as a folder or {'/'.join(VIDEO_SUFFIXES)}); found {present}")


def _size_of(path: Path) -> tuple[int, int]:
    """(width, height) of an image file from its header, without decoding it."""
    try:
        with Image.open(path) as image:
            return image.size
    except Image.DecompressionBombError as exc:
        raise ValueError(f"{path}: {exc}") from None
    except (OSError, SyntaxError) as exc:  # Pillow reports some malformed headers as SyntaxError
        raise ValueError(f"{path}: not a readable image ({exc})") from None


def _read_image(path: Path, camera: Camera) -> np.ndarray:
    """The (H, W, 3) uint8 BGR image at `path`, refused unless its header says `camera`'s size and,
    for a JPEG, the file is complete."""
    width, height = _size_of(path)
    if (width, height) != (camera.width, camera.height):
        raise ValueError(f"{path}: image is {width} x {height} pixels, camera {camera.name!r} is calibrated for "
                         f"{camera.width} x {camera.height}")
    if path.suffix.lower() in (".jpg", ".jpeg"):
        _check_jpeg_complete(path)
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{path}: not a readable image")
    return bgr


def _check_jpeg_complete(path: Path, tail: int = 4096) -> None:
    """Raise unless the JPEG at `path` ends with its end-of-image marker (FF D9), ignoring the zero
    padding (within the last `tail` bytes) some cameras append: libjpeg only warns about a truncated
    file and fills the rest grey."""
    with open(path, "rb") as file:
        file.seek(max(0, path.stat().st_size - tail))
        end = file.read().rstrip(b"\0")
    if not end.endswith(b"\xff\xd9"):
        raise ValueError(f"{path}: truncated JPEG (no end-of-image marker FF D9 at the end of the file)")


def _ranges(values: Sequence[int], limit: int = 8) -> str:
    """[1, 2, 3, 7, 9, 10] -> '1-3, 7, 9-10' (the first `limit` runs, then a count)."""
    values = sorted(values)
    runs: list[list[int]] = []
    for v in values:
        if runs and v == runs[-1][1] + 1:
            runs[-1][1] = v
        else:
            runs.append([v, v])
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:limit])
    return text + (f" and {len(runs) - limit} more runs" if len(runs) > limit else "")
