"""Per-camera frame offsets of a video capture: read from a JSON file, or estimated from motion.

Offsets are integer frames: camera c's video frame ``k + offsets[c]`` shows the instant of capture
frame k.  The reference camera has offset 0, so capture frame numbers are its video frame numbers; a
camera that started recording 5 frames earlier than the reference has offset 5.  The file is a JSON
object ``{"camera name": offset_frames}``; a camera it does not name has offset 0.

Estimating (`estimate_offsets`): for each camera a **motion-energy signal** e[k] = mean absolute
difference of frames k - 1 and k, decoded grey and downscaled to 64 pixels wide (decoding spread over
worker processes, per chunk of frames); each camera's signal is cross-correlated with the reference
camera's (Pearson correlation over the overlapping frames, at every lag within `max_offset`), and the
lag of the highest correlation is its offset.  Per camera it reports that peak `correlation` and its
`margin` over the best lag more than two frames away: an offset is `confident` when the correlation
is at least 0.5 and the margin at least 0.1.

Limits: the motion must change over time (starts, stops, changes of speed) within the overlap; a
steady or periodic motion (walking in place) gives flat or repeating peaks, which the margin shows.
Every camera must see the same motion, though from any side (the energy is of the whole image; a
camera that sees mostly other movement, or flicker, or an auto-exposure change, misleads it).  Offsets
are whole frames (sub-frame shifts, rolling shutter and drifting clocks are not modelled: cameras
must be genlocked or run at the same rate), all videos must have the same frame rate, and lags with
less than half of the shorter video overlapping are not considered.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from reconstruction.video import chunks, probe, run_in_workers

log = logging.getLogger(__name__)

MIN_CORRELATION = 0.5
MIN_MARGIN = 0.1
_ENERGY_WIDTH = 64
_CHUNK_FRAMES = 300


@dataclass(frozen=True)
class OffsetEstimate:
    """One camera's estimated offset (frames), the peak correlation and its margin (module docstring)."""

    offset: int
    correlation: float
    margin: float

    @property
    def confident(self) -> bool:
        return self.correlation >= MIN_CORRELATION and self.margin >= MIN_MARGIN


def read_offsets(path: str | Path, cameras: Sequence[str]) -> dict[str, int]:
    """Camera name -> offset (frames) for every camera in `cameras` from the JSON file `path`
    (unnamed cameras 0); raises ValueError naming the file and the entry that is wrong."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable offsets JSON file ({exc})") from None
    return check_offsets(data, cameras, str(path))


def check_offsets(offsets: object, cameras: Sequence[str], where: str = "offsets") -> dict[str, int]:
    """Validate a mapping camera name -> integer offset (frames); returns it for every camera (0 where
    missing)."""
    if not isinstance(offsets, Mapping):
        raise ValueError(f'{where}: expected an object {{"camera name": offset_frames}}, got {type(offsets).__name__}')
    unknown = sorted(set(offsets) - set(cameras))
    if unknown:
        raise ValueError(f"{where}: offsets for unknown camera(s) {unknown} (cameras: {list(cameras)})")
    for name, value in offsets.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{where}: the offset of camera {name!r} must be a whole number of frames, got {value!r}")
    return {name: int(offsets.get(name, 0)) for name in cameras}


def write_offsets(path: str | Path, offsets: Mapping[str, int]) -> Path:
    """Write `offsets` as the JSON file `path`, atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".partial")
    temporary.write_text(json.dumps({name: int(v) for name, v in offsets.items()}, indent=2) + "\n")
    temporary.replace(path)
    return path


def check_rates(rates: Mapping[str, float]) -> None:
    """Raise unless every video (name -> frames per second) runs at one rate: offsets are in frames."""
    if max(rates.values()) / min(rates.values()) - 1 > 1e-6:
        listed = ", ".join(f"{name} {float(rate):g} fps" for name, rate in rates.items())
        raise ValueError(f"the videos' frame rates differ ({listed}); offsets in frames need one rate: "
                         f"re-encode them to one")


def overlap(num_frames: Mapping[str, int], offsets: Mapping[str, int]) -> range:
    """The capture frames that every video (name -> its number of frames) holds after its offset;
    raises ValueError when they share none."""
    first = max(-offsets[name] for name in num_frames)
    stop = min(n - offsets[name] for name, n in num_frames.items())
    if stop <= first:
        spans = "; ".join(f"{name} {-offsets[name]}-{n - 1 - offsets[name]}" for name, n in num_frames.items())
        raise ValueError(f"the videos share no frame after their offsets (capture frames: {spans})")
    return range(first, stop)


def motion_energy(path: str | Path, first: int = 0, stop: int | None = None) -> np.ndarray:
    """(stop - first,) float64 e[k] for frames k = first .. stop - 1 of the video at `path`: mean
    absolute difference of frames k - 1 and k, grey, downscaled to 64 pixels wide (e[0] = 0)."""
    from reconstruction.video import VideoReader

    with VideoReader(path) as reader:
        stop = reader.info.num_frames if stop is None else stop
        width, height = reader.info.size
        small = (_ENERGY_WIDTH, max(2, round(height * _ENERGY_WIDTH / width)))
        previous = None
        energy = np.zeros(stop - first)
        for k, grey in enumerate(reader.frames(max(first - 1, 0), stop, "gray", *small), start=max(first - 1, 0)):
            grey = grey.astype(np.float32)
            if previous is not None and k >= first:
                energy[k - first] = np.abs(grey - previous).mean()
            previous = grey
    return energy


def motion_energies(videos: Mapping[str, str | Path], workers: int | None = None,
                    progress: bool = True) -> dict[str, np.ndarray]:
    """Camera name -> its video's `motion_energy`, decoded in worker processes (per chunk of frames)."""
    jobs, owners = [], []
    for name, path in videos.items():
        for first, stop in chunks(probe(path).num_frames, _CHUNK_FRAMES):
            jobs.append((str(path), first, stop))
            owners.append(name)
    parts = run_in_workers(motion_energy, jobs, [stop - first for _, first, stop in jobs], workers,
                           "motion energy", progress)
    return {name: np.concatenate([p for p, owner in zip(parts, owners) if owner == name]) for name in videos}


def estimate_offsets(videos: Mapping[str, str | Path], reference: str | None = None, max_offset: int | None = None,
                     workers: int | None = None, progress: bool = True) -> dict[str, OffsetEstimate]:
    """Camera name -> `OffsetEstimate` against `reference` (default the first camera, whose estimate is
    offset 0, correlation 1), from the videos' motion energies (module docstring); `max_offset`
    bounds |offset| (default: any lag leaving half of the shorter video overlapping)."""
    names = list(videos)
    reference = names[0] if reference is None else reference
    if reference not in videos:
        raise ValueError(f"reference camera {reference!r} is not among the videos' cameras {names}")
    check_rates({Path(path).name: probe(path).fps for path in videos.values()})
    energies = motion_energies(videos, workers, progress)
    estimates = {}
    for name in names:
        if name == reference:
            estimates[name] = OffsetEstimate(0, 1.0, 1.0)
            continue
        estimates[name] = align(energies[reference][1:], energies[name][1:], max_offset)
        if not estimates[name].confident:
            log.warning("%s: offset %+d frames is not confident (correlation %.2f, margin %.2f)", name,
                        estimates[name].offset, estimates[name].correlation, estimates[name].margin)
    return estimates


def align(reference: np.ndarray, signal: np.ndarray, max_offset: int | None = None) -> OffsetEstimate:
    """The lag o maximising the Pearson correlation of reference[k] with signal[k + o] over the frames
    k both have; (n,) and (m,) float arrays, lags with fewer than half of min(n, m) frames overlapping
    (or |o| > `max_offset`) are not considered."""
    n, m = len(reference), len(signal)
    min_overlap = max(3, min(n, m) // 2)
    lags = np.arange(-(n - min_overlap), m - min_overlap + 1)
    if max_offset is not None:
        lags = lags[np.abs(lags) <= max_offset]
    if not len(lags):
        raise ValueError(f"no lag leaves {min_overlap} frames overlapping between signals of {n} and {m} frames")
    scores = np.array([_pearson(reference[max(0, -o):min(n, m - o)], signal[max(0, o):min(n + o, m)]) for o in lags])
    best = int(np.argmax(scores))
    others = scores[np.abs(lags - lags[best]) > 2]
    margin = float(scores[best] - others.max()) if len(others) else float(scores[best])
    return OffsetEstimate(int(lags[best]), float(scores[best]), margin)


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    norm = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / norm) if norm > 0 else 0.0
