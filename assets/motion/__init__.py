"""Motions: SMPL-layout pose sequences that drive bodies (see `Motion`)."""

from assets.motion.motion import (
    A_POSE_ARM_DEG,
    SIMULATION_FPS,
    TRANSITION_SECONDS,
    Motion,
    body_poses,
    dressing_pose,
    pose_motion,
    resample,
    with_transition,
)

__all__ = [
    "Motion",
    "SIMULATION_FPS",
    "TRANSITION_SECONDS",
    "A_POSE_ARM_DEG",
    "body_poses",
    "dressing_pose",
    "pose_motion",
    "resample",
    "with_transition",
]
