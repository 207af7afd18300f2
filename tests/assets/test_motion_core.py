"""Motion: validation, files, slerp resampling and the transition from the dressing pose."""

import numpy as np
import pytest

from assets.body import default_body
from assets.motion import Motion, dressing_pose, pose_motion, resample, with_transition
from assets.rotations import rotvec_to_matrix


def elbow_swing(frames=31, fps=30.0):
    """Left elbow turning about Z from 0 to 1.5 rad, root moving along -Y."""
    poses = np.zeros((frames, 24, 3))
    poses[:, 18, 2] = np.linspace(0.0, 1.5, frames)
    trans = np.zeros((frames, 3))
    trans[:, 1] = -np.linspace(0.0, 1.0, frames)
    trans[:, 2] = 0.9
    return Motion(poses=poses, trans=trans, fps=fps, name="swing")


def test_validation_names_the_problem():
    with pytest.raises(ValueError, match=r"motion 'x': poses must be \(T, 24, 3\)"):
        Motion(poses=np.zeros((5, 23, 3)), trans=np.zeros((5, 3)), fps=30, name="x")
    with pytest.raises(ValueError, match=r"trans must be \(5, 3\)"):
        Motion(poses=np.zeros((5, 24, 3)), trans=np.zeros((4, 3)), fps=30)
    with pytest.raises(ValueError, match="frame rate 0 Hz is outside 1 to 1000 Hz"):
        Motion(poses=np.zeros((5, 24, 3)), trans=np.zeros((5, 3)), fps=0)
    with pytest.raises(ValueError, match="NaN"):
        Motion(poses=np.full((5, 24, 3), np.nan), trans=np.zeros((5, 3)), fps=30)


def test_save_load_round_trip(tmp_path):
    motion = elbow_swing().replace(betas=np.arange(3.0), shape_space="anny-default", hand_poses=np.ones((31, 30, 3)))
    motion.save(tmp_path / "m.npz")
    back = Motion.load(tmp_path / "m.npz")
    for field in ("poses", "trans", "betas", "hand_poses"):
        np.testing.assert_array_equal(getattr(back, field), getattr(motion, field))
    assert (back.fps, back.name, back.shape_space) == (30.0, "swing", "anny-default")
    (tmp_path / "bad.npz").write_bytes(b"nope")
    with pytest.raises(ValueError, match=r"bad\.npz"):
        Motion.load(tmp_path / "bad.npz")


def test_resample_slerps_rotations_and_keeps_the_span():
    motion = elbow_swing()
    fast = resample(motion, 120.0)
    assert fast.fps == 120.0 and fast.num_frames == 121 and fast.duration == pytest.approx(motion.duration)
    np.testing.assert_allclose(fast.poses[::4], motion.poses, atol=1e-12)  # source frames kept
    # Between frames the angle about the fixed axis grows linearly (slerp of a one-axis rotation).
    np.testing.assert_allclose(fast.poses[:, 18, 2], np.linspace(0.0, 1.5, 121), atol=1e-12)
    np.testing.assert_allclose(fast.trans[:, 1], -np.linspace(0.0, 1.0, 121), atol=1e-12)
    slow = resample(motion, 10.0)
    assert slow.num_frames == 11
    np.testing.assert_allclose(slow.poses[:, 18, 2], motion.poses[::3, 18, 2], atol=1e-12)
    # A frame time of 1/120.0048 s (as BVH files write 0.008333) keeps every frame at 120 Hz.
    almost = resample(motion.replace(fps=120.0048), 120.0)
    assert almost.num_frames == motion.num_frames
    np.testing.assert_allclose(almost.poses[-1], motion.poses[-1], atol=1e-12)


def test_resample_takes_the_short_way_round():
    poses = np.zeros((2, 24, 3))
    poses[0, 0, 2], poses[1, 0, 2] = np.deg2rad(170), np.deg2rad(-170)
    mid = resample(Motion(poses=poses, trans=np.zeros((2, 3)), fps=1.0), 2.0).poses[1, 0]
    np.testing.assert_allclose(rotvec_to_matrix(mid), rotvec_to_matrix(np.array([0, 0, np.pi])), atol=1e-9)


@pytest.mark.parametrize("pose", ["T", "A"])
def test_transition_from_the_dressing_pose(pose):
    motion = resample(elbow_swing(), 120.0).frames(60)  # starts with the elbow bent
    moved = with_transition(motion, pose, seconds=0.5)
    assert moved.num_frames == motion.num_frames + 60
    np.testing.assert_allclose(moved.poses[0], dressing_pose(pose))
    np.testing.assert_allclose(moved.trans[0], motion.trans[0])
    np.testing.assert_array_equal(moved.poses[60:], motion.poses)
    # Eased: the step into the first motion frame is small, the largest step is mid-transition.
    steps = np.linalg.norm(np.diff(moved.poses[:61], axis=0), axis=(1, 2))
    assert steps[-1] < 0.2 * steps.max() and steps[0] < 0.2 * steps.max()


def test_a_pose_lowers_the_arms():
    body = default_body()
    joints = body.pose(dressing_pose("A")).joints[0]
    rest = body.rest()[1]
    for shoulder, wrist in ((16, 20), (17, 21)):
        arm = joints[wrist] - joints[shoulder]
        assert np.degrees(np.arctan2(-arm[2], abs(arm[0]))) == pytest.approx(45.0, abs=0.5)
        assert joints[shoulder] == pytest.approx(rest[shoulder])


def test_zero_pose_returns_the_rest_mesh():
    body = default_body()
    rest_v, rest_j = body.rest()
    motion = Motion(poses=np.zeros((3, 24, 3)), trans=np.tile(rest_j[0], (3, 1)), fps=30.0)
    posed = pose_motion(body, motion)
    np.testing.assert_allclose(posed.vertices, np.broadcast_to(rest_v, posed.vertices.shape), atol=1e-5)
    np.testing.assert_allclose(posed.joints[1], rest_j, atol=1e-12)
    # trans is where the root lands, whatever the body's shape.
    tall = body.pose(np.zeros((1, 24, 3)), np.array([[0.1, 0.2, 1.3]]), betas=(0.5, 0.5, 1.0))
    np.testing.assert_allclose(tall.joints[0, 0], [0.1, 0.2, 1.3])
