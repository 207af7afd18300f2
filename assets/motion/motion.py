"""`Motion`: a body pose sequence in SMPL's 24-joint layout, and the operations every motion needs.

A motion is what drives a body: axis-angle poses ``(T, 24, 3)`` per SMPL joint (in the project's Z-up
world, see `assets.body.model`), the root joint's world position ``(T, 3)`` in metres, the shape it was
captured with (``betas`` in ``shape_space``, applied only to a body of the same shape space), and the
frame rate.  Motions from SMPL+H/SMPL-X data keep their finger poses in ``hand_poses (T, 30, 3)``.

Here: saving and loading, resampling to the simulation rate with quaternion slerp (120 Hz, the
reference's 1/120 s timestep), and the transition from the dressing pose (T or A) into the first frame.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from assets.body.model import NUM_BODY_JOINTS, NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, BodyModel, PosedBody
from assets.fileio import check_limit, load_npz, npz_headers, save_npz
from assets.rotations import quat_to_rotvec, rotvec_to_quat, slerp

#: The reference simulates at the motion-capture rate: timestep 1/120 s.
SIMULATION_FPS = 120.0
#: How long the default transition from the dressing pose into a motion's first frame lasts.
TRANSITION_SECONDS = 1.0
#: The A-pose lowers each arm from the T-pose by this angle (degrees).
A_POSE_ARM_DEG = 45.0
NUM_HAND_JOINTS = 30
#: Frame rates a motion may have (Hz): below or above is a broken file, not a capture.
MIN_FPS, MAX_FPS = 1.0, 1000.0
#: Default bound on a motion's frame count, ten minutes at the simulation rate (`max_frames` raises it).
MAX_FRAMES = int(SIMULATION_FPS * 600)
#: The most shape values a motion carries (SMPL-X's 300 shape and 100 expression components).
MAX_BETAS = 400


def check_fps(fps: float, source: str) -> float:
    """`fps` as a float if it lies in [MIN_FPS, MAX_FPS], else a ValueError naming `source`."""
    if not MIN_FPS <= fps <= MAX_FPS:
        raise ValueError(f"{source}: frame rate {fps:g} Hz is outside {MIN_FPS:g} to {MAX_FPS:g} Hz")
    return float(fps)


def check_frames(count: int, source: str, max_frames: int = MAX_FRAMES) -> None:
    """Refuse a frame count above `max_frames` before the frames are allocated."""
    check_limit(count, max_frames, "the frame count", source, "--max-frames (max_frames=)")


def check_finite(arrays: dict[str, np.ndarray], source: str) -> None:
    """Refuse NaN or infinite values, naming `source` and the field."""
    for field, array in arrays.items():
        if array is not None and not np.isfinite(array).all():
            raise ValueError(f"{source}: {field} holds NaN or infinite values")


def dressing_pose(name: str = "T") -> np.ndarray:
    """Poses (24, 3) of a dressing pose: 'T' (the rest pose) or 'A' (arms lowered by 45 degrees).

    In the Z-up frame the left arm points along +X in the rest pose; turning it about +Y by a positive
    angle lowers it (and the right arm about -Y)."""
    poses = np.zeros((NUM_SMPL_JOINTS, 3))
    if name.upper() == "T":
        return poses
    if name.upper() == "A":
        angle = np.deg2rad(A_POSE_ARM_DEG)
        poses[SMPL_JOINT_NAMES.index("left_shoulder")] = (0.0, angle, 0.0)
        poses[SMPL_JOINT_NAMES.index("right_shoulder")] = (0.0, -angle, 0.0)
        return poses
    raise ValueError(f"unknown dressing pose {name!r} (expected 'T' or 'A')")


@dataclass(frozen=True, eq=False)
class Motion:
    """A pose sequence (see the module docstring).  Arrays: poses (T, 24, 3) radians, trans (T, 3)
    metres, betas (B,), hand_poses (T, 30, 3) or None; fps in frames per second."""

    poses: np.ndarray
    trans: np.ndarray
    fps: float
    betas: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    shape_space: str = ""
    gender: str = "neutral"
    hand_poses: np.ndarray | None = None
    name: str = ""
    source: str = ""

    def __post_init__(self):
        poses = np.asarray(self.poses, dtype=np.float64)
        trans = np.asarray(self.trans, dtype=np.float64)
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "trans", trans)
        object.__setattr__(self, "betas", np.asarray(self.betas, dtype=np.float64).ravel())
        label = f"motion {self.name!r}" if self.name else "motion"
        if poses.ndim != 3 or poses.shape[1:] != (NUM_SMPL_JOINTS, 3):
            raise ValueError(f"{label}: poses must be (T, {NUM_SMPL_JOINTS}, 3), got {poses.shape}")
        if trans.shape != (len(poses), 3):
            raise ValueError(f"{label}: trans must be ({len(poses)}, 3), got {trans.shape}")
        if len(poses) == 0:
            raise ValueError(f"{label}: has no frames")
        check_fps(self.fps, label)
        hands = None if self.hand_poses is None else np.asarray(self.hand_poses, dtype=np.float64)
        if hands is not None and hands.shape != (len(poses), NUM_HAND_JOINTS, 3):
            raise ValueError(f"{label}: hand_poses must be ({len(poses)}, {NUM_HAND_JOINTS}, 3), got {hands.shape}")
        object.__setattr__(self, "hand_poses", hands)
        check_finite({"poses": poses, "trans": trans, "betas": self.betas, "hand_poses": hands}, label)

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def replace(self, **changes) -> "Motion":
        return dataclasses.replace(self, **changes)

    def frames(self, start: int, stop: int | None = None) -> "Motion":
        """The frames [start, stop) as a motion."""
        cut = slice(start, stop)
        hands = None if self.hand_poses is None else self.hand_poses[cut]
        return self.replace(poses=self.poses[cut], trans=self.trans[cut], hand_poses=hands)

    # -- files ---------------------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> None:
        """Write the motion as `.npz` (poses, trans, betas, fps and metadata)."""
        meta = {"name": self.name, "source": self.source, "shape_space": self.shape_space, "gender": self.gender}
        arrays = {
            "poses": self.poses,
            "trans": self.trans,
            "betas": self.betas,
            "fps": np.array(float(self.fps)),
            "meta": np.array(json.dumps(meta)),
        }
        if self.hand_poses is not None:
            arrays["hand_poses"] = self.hand_poses
        save_npz(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike, max_frames: int = MAX_FRAMES) -> "Motion":
        """Read a motion written by `save`; errors name the file.  The frame count is checked against
        `max_frames` from the file's headers, before anything is decompressed."""
        path = Path(path)
        headers = npz_headers(path)
        for key in ("poses", "trans", "hand_poses"):
            if key in headers and headers[key][0]:
                check_frames(headers[key][0][0], f"{path}: {key}", max_frames)
        for key, most in (("betas", MAX_BETAS), ("fps", 1), ("meta", 1)):
            if key in headers and int(np.prod(headers[key][0])) > most:
                raise ValueError(f"{path}: {key} has shape {headers[key][0]}, expected at most {most} values")
        known = tuple(k for k in ("poses", "trans", "fps", "betas", "meta", "hand_poses") if k in headers)
        arrays = load_npz(path, required=("poses", "trans", "fps"), only=known)
        try:
            meta = json.loads(str(arrays["meta"])) if "meta" in arrays else {}
            return cls(
                poses=arrays["poses"],
                trans=arrays["trans"],
                fps=float(arrays["fps"]),
                betas=arrays.get("betas", np.zeros(0)),
                shape_space=meta.get("shape_space", ""),
                gender=meta.get("gender", "neutral"),
                hand_poses=arrays.get("hand_poses"),
                name=meta.get("name", path.stem),
                source=meta.get("source", str(path)),
            )
        except (ValueError, TypeError, AttributeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: {exc}") from exc


def resample(motion: Motion, fps: float = SIMULATION_FPS, max_frames: int = MAX_FRAMES) -> Motion:
    """The motion at `fps` over the same time span (to the nearest frame): joint rotations by
    quaternion slerp between the two nearest source frames, root positions linearly.  The first
    frame is kept exactly; more than `max_frames` frames are refused before they are allocated."""
    source = f"resampling motion {motion.name!r}"
    fps = check_fps(fps, source)
    if motion.num_frames == 1 or fps == motion.fps:
        return motion.replace(fps=fps)
    # Round (not floor) the span so a 1/120.0048 s BVH frame time does not lose the last frame; the
    # last sample may then land up to half a frame past the end and holds the last pose.
    count = int(np.round(motion.duration * fps)) + 1
    check_frames(count, f"{source} from {motion.fps:g} to {fps:g} Hz", max_frames)
    position = np.minimum(np.arange(count) * (motion.fps / fps), motion.num_frames - 1)  # in source frames
    lo = np.minimum(np.floor(position).astype(int), motion.num_frames - 2)
    frac = position - lo

    def rotations(poses: np.ndarray) -> np.ndarray:
        q = rotvec_to_quat(poses)
        t = np.broadcast_to(frac[:, None], (count, poses.shape[1]))
        return quat_to_rotvec(slerp(q[lo], q[lo + 1], t))

    trans = motion.trans[lo] * (1.0 - frac[:, None]) + motion.trans[lo + 1] * frac[:, None]
    hands = None if motion.hand_poses is None else rotations(motion.hand_poses)
    return motion.replace(poses=rotations(motion.poses), trans=trans, fps=float(fps), hand_poses=hands)


def with_transition(
    motion: Motion,
    pose: str | np.ndarray = "T",
    seconds: float = TRANSITION_SECONDS,
    start_trans: np.ndarray | None = None,
    max_frames: int = MAX_FRAMES,
) -> Motion:
    """Prepend a transition from the dressing `pose` ('T', 'A' or poses (24, 3)) into the first frame.

    The body starts in the dressing pose with no root rotation at `start_trans` (default: the first
    frame's root position) and eases (smoothstep, so velocity is zero at both ends of the transition)
    into the first frame over `seconds`; the motion follows unchanged.  The result has
    ``round(seconds * fps)`` extra frames at the motion's rate (with the motion's, at most `max_frames`)."""
    start = dressing_pose(pose) if isinstance(pose, str) else np.asarray(pose, dtype=np.float64)
    if start.shape != (NUM_SMPL_JOINTS, 3):
        raise ValueError(f"dressing pose must be (24, 3), got {start.shape}")
    if not (np.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"transition seconds must be a finite number >= 0, got {seconds}")
    extra = int(round(seconds * motion.fps))
    check_frames(motion.num_frames + extra, f"motion {motion.name!r} with a {seconds:g} s transition", max_frames)
    if extra <= 0:
        return motion
    start_trans = motion.trans[0] if start_trans is None else np.asarray(start_trans, dtype=np.float64)
    s = np.arange(extra) / extra
    ease = s * s * (3.0 - 2.0 * s)
    q0 = rotvec_to_quat(start)
    q1 = rotvec_to_quat(motion.poses[0])
    poses = quat_to_rotvec(slerp(q0[None], q1[None], np.broadcast_to(ease[:, None], (extra, NUM_SMPL_JOINTS))))
    trans = start_trans + ease[:, None] * (motion.trans[0] - start_trans)
    hands = None
    if motion.hand_poses is not None:
        h1 = rotvec_to_quat(motion.hand_poses[0])
        h0 = rotvec_to_quat(np.zeros_like(motion.hand_poses[0]))
        hand_lead = quat_to_rotvec(slerp(h0[None], h1[None], np.broadcast_to(ease[:, None], (extra, NUM_HAND_JOINTS))))
        hands = np.concatenate([hand_lead, motion.hand_poses])
    return motion.replace(
        poses=np.concatenate([poses, motion.poses]),
        trans=np.concatenate([trans, motion.trans]),
        hand_poses=hands,
    )


def body_poses(body: BodyModel, motion: Motion) -> np.ndarray:
    """The motion's poses laid out for `body`'s joints: (T, J, 3).

    SMPL (24 joints) takes them as they are; SMPL+H (52) and SMPL-X (55) take the 22 body joints, then
    the finger poses (zero when the motion has none); SMPL-X's jaw and eyes stay at rest."""
    t = motion.num_frames
    if body.num_joints == NUM_SMPL_JOINTS:
        return motion.poses
    hands = motion.hand_poses if motion.hand_poses is not None else np.zeros((t, NUM_HAND_JOINTS, 3))
    body_part = motion.poses[:, :NUM_BODY_JOINTS]
    if body.num_joints == NUM_BODY_JOINTS + NUM_HAND_JOINTS:
        return np.concatenate([body_part, hands], axis=1)
    if body.num_joints == NUM_BODY_JOINTS + 3 + NUM_HAND_JOINTS:
        return np.concatenate([body_part, np.zeros((t, 3, 3)), hands], axis=1)
    raise ValueError(f"body model {body.name!r} has {body.num_joints} joints; motions drive 24, 52 or 55")


def motion_betas(body: BodyModel, motion: Motion) -> np.ndarray | None:
    """The motion's shape when it is in the body's shape space, else None (the body's default)."""
    if motion.shape_space and motion.shape_space == body.shape_space and len(motion.betas):
        return motion.betas
    return None


def pose_motion(body: BodyModel, motion: Motion, betas: np.ndarray | None = None) -> PosedBody:
    """Pose `body` through every frame of `motion`; `betas` overrides the shape."""
    shape = betas if betas is not None else motion_betas(body, motion)
    return body.pose(body_poses(body, motion), motion.trans, shape)
