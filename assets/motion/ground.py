"""Keeping a posed body on the ground: the root path that puts the soles on z = 0 and keeps planted
feet from sliding (used by the built-in motions, whose joint curves say nothing about where the pelvis
goes)."""

from __future__ import annotations

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.ndimage import gaussian_filter1d

from assets.body.model import BodyModel
from assets.motion.motion import Motion, body_poses

X, Y = 0, 1
#: Softness (metres) of the minimum over contact points that decides which foot is on the ground.
CONTACT_SOFTNESS = 0.005
#: A swinging foot counts this much (metres) higher than it is when finding the foot the body moves over.
SWING_CLEARANCE = 0.05
#: Standard deviation of the Gaussian that low-passes the root path (see `grounded_trans`).
ROOT_SMOOTHING_SECONDS = 0.03
_FOOT_SEGMENTS = ("ankle", "foot")


def _contact_points(body: BodyModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The soles' extreme points (heel, toe tip, inner and outer edge of each foot): their segments'
    joint indices (K,), rest positions (K, 3) metres, and feet (K,) 0 left, 1 right."""
    vertices, _ = body.rest()
    segment = np.argmax(body.weights, axis=1)
    joints, points = [], []
    for side in ("left", "right"):
        feet = [body.joint_names.index(f"{side}_{name}") for name in _FOOT_SEGMENTS]
        on_foot = np.isin(segment, feet)
        sole = on_foot & (vertices[:, 2] < vertices[on_foot, 2].min() + 0.01)
        index = np.flatnonzero(sole)
        for axis in (X, Y):
            for pick in (np.argmin, np.argmax):
                k = index[pick(vertices[index, axis])]
                joints.append(segment[k])
                points.append(vertices[k])
    return np.array(joints), np.array(points), np.repeat([0, 1], len(joints) // 2)


def _soft_min(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Soft minimum over the last axis (`CONTACT_SOFTNESS` metres) and the weights (sum 1) it gives
    each value: about 1 for the lowest, falling by e per `CONTACT_SOFTNESS` above it."""
    low = values.min(axis=-1, keepdims=True)
    weights = np.exp(-(values - low) / CONTACT_SOFTNESS)
    total = weights.sum(axis=-1, keepdims=True)
    return (low - CONTACT_SOFTNESS * np.log(total))[..., 0], weights / total


def grounded_trans(body: BodyModel, poses: np.ndarray, fps: float, lift: np.ndarray | float = 0.0,
                   planted: bool = True, support: np.ndarray | None = None) -> np.ndarray:
    """Root positions (T, 3) metres that keep `body`, posed by `poses` (T, 24, 3), on the ground.

    Height: the soft minimum of the soles' contact points on the ground, as when standing flat-footed
    at rest (so a flat stance stands exactly on z = 0), plus `lift` (T,) metres.  Horizontal: starting
    above the origin, the pelvis moves against the horizontal velocity of the contact points relative to
    it, weighted towards the lowest, so the feet on the ground do not slide (`planted`); otherwise it
    stays above the origin; a foot whose `support` (T, 2) is 0 counts `SWING_CLEARANCE` higher there,
    so a low swinging foot does not drag the body back.  Both are low-passed (Gaussian,
    `ROOT_SMOOTHING_SECONDS`): a change of supporting foot would otherwise jolt the pelvis, which a
    garment simulation feels as a force spike.  Frames are `1 / fps` seconds apart."""
    frames = len(poses)
    motion = Motion(poses=poses, trans=np.zeros((frames, 3)), fps=fps)
    _, rest_joints = body.rest()
    rotations, positions = body.joint_transforms(body_poses(body, motion), np.zeros((frames, 3)), rest_joints)
    segments, points, feet = _contact_points(body)
    offsets = points - rest_joints[segments]
    contacts = positions[:, segments] + np.einsum("tkab,kb->tka", rotations[:, segments], offsets)
    lowest, weights = _soft_min(contacts[..., 2])
    if support is not None:
        _, weights = _soft_min(contacts[..., 2] + SWING_CLEARANCE * (1.0 - support[:, feet]))
    sigma = ROOT_SMOOTHING_SECONDS * fps
    trans = np.zeros((frames, 3))
    trans[:, 2] = gaussian_filter1d(_soft_min(points[:, 2])[0] - lowest + lift, sigma, mode="nearest")
    if planted and frames > 1:
        velocity = -np.einsum("tk,tka->ta", weights, np.gradient(contacts[..., :2], 1.0 / fps, axis=0))
        velocity = gaussian_filter1d(velocity, sigma, axis=0, mode="nearest")
        trans[:, :2] = cumulative_trapezoid(velocity, dx=1.0 / fps, axis=0, initial=0.0)
    return trans
