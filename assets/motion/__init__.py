"""Motions: SMPL-layout pose sequences that drive bodies (see `Motion`)."""

from assets.motion.amass import read_amass
from assets.motion.builtin import BUILTIN_MOTIONS, builtin_motion, list_builtin_motions
from assets.motion.bvh import SKELETON_MAPS, parse_bvh, read_bvh, resolve_mapping, retarget_to_smpl
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
    "BUILTIN_MOTIONS",
    "builtin_motion",
    "list_builtin_motions",
    "read_amass",
    "read_bvh",
    "parse_bvh",
    "retarget_to_smpl",
    "resolve_mapping",
    "SKELETON_MAPS",
]
