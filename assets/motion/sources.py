"""One way to name a motion everywhere (CLIs, the factory, the add-on): a built-in motion's name, an
AMASS `.npz`, a motion `.npz` written by `Motion.save`, or a `.bvh` file."""

from __future__ import annotations

import os
from pathlib import Path

from assets.body.model import BodyModel
from assets.fileio import npz_headers, safe_name
from assets.motion.amass import FPS_KEYS, read_amass
from assets.motion.motion import MAX_FRAMES, Motion


def _is_amass(path: Path) -> bool:
    """An AMASS file has 2-D poses and a frame-rate key; a saved `Motion` has (T, 24, 3) poses."""
    files = npz_headers(path)
    return "meta" not in files and any(k in files for k in FPS_KEYS)


def motion_label(spec: str | os.PathLike) -> str:
    """The name motion `spec` goes by in file and folder names: a built-in motion's own name, a motion
    file's stem; a ValueError unless it is one plain path component (`safe_name`)."""
    path = Path(spec)
    label = path.stem if path.suffix.lower() in (".npz", ".bvh") else str(spec)
    return safe_name(label, f"motion {str(spec)!r}")


def load_motion(
    spec: str | os.PathLike,
    body: BodyModel | None = None,
    seconds: float | None = None,
    speed: float = 1.0,
    amplitude: float = 1.0,
    fps: float | None = None,
    max_frames: int = MAX_FRAMES,
) -> Motion:
    """Resolve `spec` to a Motion.  `body` places built-in motions on its proportions and retargets BVH
    files onto it; `seconds`, `speed` and `amplitude` apply to built-in motions; `fps` is the rate a
    built-in motion is generated at (files keep their own rate); `max_frames` bounds the frames a file
    or a built-in motion may have."""
    from assets.motion.builtin import BUILTIN_MOTIONS, builtin_motion

    path = Path(spec)
    if path.suffix.lower() == ".bvh":
        from assets.motion.bvh import read_bvh

        return read_bvh(path, body=body, max_frames=max_frames)
    if path.suffix.lower() == ".npz":
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such motion file")
        return read_amass(path, max_frames=max_frames) if _is_amass(path) else Motion.load(path, max_frames)
    if str(spec) in BUILTIN_MOTIONS:
        kwargs = {} if fps is None else {"fps": fps}
        return builtin_motion(str(spec), seconds=seconds, speed=speed, amplitude=amplitude, body=body,
                              max_frames=max_frames, **kwargs)
    raise ValueError(
        f"unknown motion {str(spec)!r}: give a built-in motion ({', '.join(sorted(BUILTIN_MOTIONS))}) "
        "or a .npz (AMASS or saved motion) or .bvh file"
    )
