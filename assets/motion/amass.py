"""AMASS motion files (`.npz`) -> `Motion` in the project's frame.

AMASS stores per frame ``poses`` of an SMPL-family body (72 values for SMPL, 156 for SMPL+H: 22 body
joints then 2 x 15 finger joints, 165 for SMPL-X: 22 body, jaw, 2 eyes, 30 fingers), ``trans``, and per
sequence ``betas``, ``gender`` and the frame rate (``mocap_framerate``, ``mocap_frame_rate`` or
``fps`` depending on the release).

Axes are converted once, here.  AMASS's world is already Z up, but its poses act on SMPL's Y-up model;
the project's models are that model turned by ``C = Y_UP_TO_Z_UP``.  The same world motion is then
root rotation ``R0 C^T`` and child rotations ``C Rk C^T`` (the axis-angle axis turned by C).  AMASS's
``trans`` is SMPL's ``transl``: the pelvis ends at ``trans + J0(betas)``, J0 being the pelvis of the
capture model in its own rest frame; `Motion.trans` is that pelvis position.  Pass the capture model
(`body`) for the exact J0; without it the SMPL templates' pelvis offset is used (`SMPL_PELVIS_OFFSET`,
within about 2 cm for adult shapes).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from assets.body.model import NUM_BODY_JOINTS, BodyModel
from assets.fileio import load_npz, npz_headers
from assets.motion.motion import MAX_BETAS, MAX_FRAMES, NUM_HAND_JOINTS, Motion, check_finite, check_fps, check_frames
from assets.rotations import Y_UP_TO_Z_UP, conjugate_rotvec, matrix_to_rotvec, rotvec_to_matrix

FPS_KEYS = ("mocap_framerate", "mocap_frame_rate", "fps")
#: Width of AMASS's per-frame pose vector -> the model family it was fitted with.
POSE_WIDTHS = {72: "smpl", 156: "smplh", 165: "smplx"}
#: The pelvis joint of the SMPL templates in their own (Y-up) rest frame, metres.
SMPL_PELVIS_OFFSET = np.array([-0.0018, -0.2233, 0.0282])
_HAND_START = {"smplh": 66, "smplx": 75}


def _read(path: Path, max_frames: int) -> dict[str, np.ndarray]:
    """The numeric arrays of an AMASS file, the frame count and the shape size checked from the
    headers before anything is decompressed."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such AMASS file")
    headers = npz_headers(path)
    for key in ("poses", "trans"):
        if key in headers and headers[key][0]:
            check_frames(headers[key][0][0], f"{path}: {key}", max_frames)
    for key in ("poses", "trans"):
        if key in headers and int(np.prod(headers[key][0][1:])) > max(POSE_WIDTHS):
            raise ValueError(f"{path}: {key} has shape {headers[key][0]}; AMASS frames hold at most {max(POSE_WIDTHS)} values")
    for key, most in [("betas", MAX_BETAS), ("gender", 64)] + [(k, 1) for k in FPS_KEYS]:
        if key in headers and int(np.prod(headers[key][0])) > most:
            raise ValueError(f"{path}: {key} has shape {headers[key][0]}, expected at most {most} values")
    wanted = ("poses", "trans", "betas", "gender") + FPS_KEYS
    readable = tuple(k for k in wanted if k in headers and headers[k][1].kind in "biufSU")
    return load_npz(path, only=readable)


def _gender(value: np.ndarray | None) -> str:
    if value is None or value.size == 0:
        return "neutral"
    text = value.item() if value.ndim == 0 else value.ravel()[0]
    text = text.decode("latin1") if isinstance(text, bytes) else str(text)
    return text.strip().lower() or "neutral"


def read_amass(path: str | os.PathLike, body: BodyModel | None = None, max_frames: int = MAX_FRAMES) -> Motion:
    """Read an AMASS `.npz` as a `Motion` (Z up, trans = pelvis position); see the module docstring.

    `body`: the capture model (from `load_smpl`) for the exact pelvis offset of the file's betas;
    `max_frames`: the most frames the file may hold (checked before decompression)."""
    path = Path(path)
    data = _read(path, max_frames)
    missing = [k for k in ("poses", "trans") if k not in data]
    fps_key = next((k for k in FPS_KEYS if k in data), None)
    if fps_key is None:
        missing.append(" or ".join(FPS_KEYS))
    if missing:
        raise ValueError(f"{path}: not an AMASS motion, missing {', '.join(missing)}")
    poses, trans = data["poses"], data["trans"]
    if poses.ndim != 2 or poses.shape[1] not in POSE_WIDTHS or poses.dtype.kind not in "iuf":
        raise ValueError(f"{path}: poses must be (T, 72), (T, 156) or (T, 165) numbers, got {poses.shape} {poses.dtype}")
    frames = len(poses)
    if frames == 0:
        raise ValueError(f"{path}: poses has no frames")
    if trans.shape != (frames, 3) or trans.dtype.kind not in "iuf":
        raise ValueError(f"{path}: trans must be ({frames}, 3) numbers to match poses, got {trans.shape} {trans.dtype}")
    rate = data[fps_key]
    if rate.size != 1 or rate.dtype.kind not in "iuf":
        raise ValueError(f"{path}: {fps_key} must be one number, got {rate.shape} {rate.dtype}")
    fps = check_fps(float(rate.ravel()[0]), f"{path}: {fps_key}")
    family = POSE_WIDTHS[poses.shape[1]]
    betas = data.get("betas", np.zeros(0))
    if betas.dtype.kind not in "iuf":
        raise ValueError(f"{path}: betas must be numbers, got {betas.dtype}")
    betas = betas.astype(np.float64).ravel()
    check_finite({"poses": poses, "trans": trans, "betas": betas}, str(path))
    gender = _gender(data.get("gender"))

    c = Y_UP_TO_Z_UP
    if family == "smpl":
        smpl = poses.reshape(frames, 24, 3).astype(np.float64)
        hands = None
    else:
        smpl = np.zeros((frames, 24, 3))
        smpl[:, :NUM_BODY_JOINTS] = poses[:, : 3 * NUM_BODY_JOINTS].reshape(frames, NUM_BODY_JOINTS, 3)
        start = _HAND_START[family]
        hands = conjugate_rotvec(poses[:, start : start + 3 * NUM_HAND_JOINTS].reshape(frames, NUM_HAND_JOINTS, 3), c)
    converted = conjugate_rotvec(smpl, c)
    converted[:, 0] = matrix_to_rotvec(rotvec_to_matrix(smpl[:, 0]) @ c.T)

    if body is not None and body.shape_space == family:
        pelvis = c.T @ body.rest(betas)[1][0]  # back to the file's Y-up model frame
    else:
        pelvis = SMPL_PELVIS_OFFSET
    return Motion(
        poses=converted,
        trans=trans.astype(np.float64) + pelvis,
        fps=fps,
        betas=betas,
        shape_space=family,
        gender=gender,
        hand_poses=hands,
        name=path.stem,
        source=str(path),
    )
