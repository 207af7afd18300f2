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

import logging
import os
import zipfile
from pathlib import Path

import numpy as np

from assets.body.model import NUM_BODY_JOINTS, BodyModel
from assets.motion.motion import NUM_HAND_JOINTS, Motion
from assets.rotations import Y_UP_TO_Z_UP, conjugate_rotvec, matrix_to_rotvec, rotvec_to_matrix

log = logging.getLogger(__name__)

FPS_KEYS = ("mocap_framerate", "mocap_frame_rate", "fps")
#: Width of AMASS's per-frame pose vector -> the model family it was fitted with.
POSE_WIDTHS = {72: "smpl", 156: "smplh", 165: "smplx"}
#: The pelvis joint of the SMPL templates in their own (Y-up) rest frame, metres.
SMPL_PELVIS_OFFSET = np.array([-0.0018, -0.2233, 0.0282])
_HAND_START = {"smplh": 66, "smplx": 75}


def _read(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such AMASS file")
    out = {}
    try:
        with np.load(path, allow_pickle=False) as data:
            for key in data.files:
                try:
                    out[key] = data[key]
                except ValueError:  # an object array: needs pickle, which untrusted files do not get
                    log.warning("%s: ignoring %r (a pickled object array)", path, key)
    except (OSError, zipfile.BadZipFile, ValueError) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from exc
    return out


def _gender(value: np.ndarray | None) -> str:
    if value is None:
        return "neutral"
    text = value.item() if value.ndim == 0 else value.ravel()[0]
    text = text.decode("latin1") if isinstance(text, bytes) else str(text)
    return text.strip().lower() or "neutral"


def read_amass(path: str | os.PathLike, body: BodyModel | None = None) -> Motion:
    """Read an AMASS `.npz` as a `Motion` (Z up, trans = pelvis position); see the module docstring.

    `body`: the capture model (from `load_smpl`) for the exact pelvis offset of the file's betas."""
    path = Path(path)
    data = _read(path)
    missing = [k for k in ("poses", "trans") if k not in data]
    fps_key = next((k for k in FPS_KEYS if k in data), None)
    if fps_key is None:
        missing.append(" or ".join(FPS_KEYS))
    if missing:
        raise ValueError(f"{path}: not an AMASS motion, missing {', '.join(missing)}")
    poses, trans = data["poses"], data["trans"]
    if poses.ndim != 2 or poses.shape[1] not in POSE_WIDTHS:
        raise ValueError(f"{path}: poses must be (T, 72), (T, 156) or (T, 165), got {poses.shape}")
    frames = len(poses)
    if trans.shape != (frames, 3):
        raise ValueError(f"{path}: trans must be ({frames}, 3) to match poses, got {trans.shape}")
    fps = float(np.asarray(data[fps_key]).ravel()[0]) if np.asarray(data[fps_key]).size else 0.0
    if not fps > 0:
        raise ValueError(f"{path}: {fps_key} must be a positive frame rate, got {data[fps_key]!r}")
    family = POSE_WIDTHS[poses.shape[1]]
    betas = np.asarray(data.get("betas", np.zeros(0)), dtype=np.float64).ravel()
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
