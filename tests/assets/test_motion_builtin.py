"""Built-in motions on the real default body: valid, smooth, grounded, and arms clear of the torso."""

import numpy as np
import pytest

from assets.body import SMPL_JOINT_NAMES, default_body
from assets.motion import Motion
from assets.motion.builtin import BUILTIN_MOTIONS, builtin_motion, list_builtin_motions
from assets.rotations import matrix_to_rotvec, rotvec_to_matrix

NAMES = list_builtin_motions()
REQUIRED = {"walk", "run", "arm_raise", "arm_swing", "squat", "jump", "spin", "tpose"}
FRAME_STEP = 4  # pose every 4th frame (30 Hz at 120 Hz) for the geometric checks
#: Joint angular acceleration bound (rad/s^2).  A joint swinging +-A rad at f Hz peaks at A (2 pi f)^2:
#: natural motion stays in the tens to low hundreds (the jog's knee, 0.6 rad swings at 1.2 Hz with
#: sharper harmonics, measures 131; the jump's arm swing 109; the walk 55).  At 120 Hz the bound still
#: catches any kink: a 1.7 rad/s jump in angular velocity between two frames, or a one-frame 1 degree
#: step, exceeds it.
MAX_ANGULAR_ACCELERATION = 200.0
TORSO = ("pelvis", "spine1", "spine2", "spine3")
FOREARMS = tuple(f"{side}_{joint}" for side in ("left", "right") for joint in ("elbow", "wrist", "hand"))
SLICE_M = 0.02  # torso slices 2 cm high
SHRINK = 0.9  # each slice's ellipse shrunk by 10 %: skinning near joints and the ellipse fit are coarse


@pytest.fixture(scope="module")
def body():
    return default_body()


@pytest.fixture(scope="module")
def motions():
    return {name: builtin_motion(name) for name in NAMES}


def joint(name):
    return SMPL_JOINT_NAMES.index(name)


def angular_acceleration(motion):
    """(T - 2, 24) rad/s^2: the change, frame to frame, of each joint's angular velocity, taken from the
    relative rotation between consecutive frames."""
    rotations = rotvec_to_matrix(motion.poses)
    step = np.einsum("tjba,tjbc->tjac", rotations[:-1], rotations[1:])  # R_t^T R_t+1
    velocity = matrix_to_rotvec(step) * motion.fps
    return np.linalg.norm(np.diff(velocity, axis=0), axis=-1) * motion.fps


class TorsoModel:
    """A coarse articulated torso: each torso segment (pelvis, spine1..3) is a stack of horizontal
    slices in its joint's rest frame, each slice the axis-aligned ellipse through the extremes of that
    segment's rest vertices in it, shrunk by `SHRINK`.  A point is inside the torso when it is inside a
    slice of some segment, after moving it into that segment's rest frame."""

    def __init__(self, body):
        vertices, self.rest_joints = body.rest()
        segment = np.argmax(body.weights, axis=1)
        self.body = body
        self.slices = []
        for name in TORSO:
            j = joint(name)
            v = vertices[segment == j]
            bottom = v[:, 2].min()
            index = ((v[:, 2] - bottom) / SLICE_M).astype(int)
            low = np.full((index.max() + 1, 2), np.inf)
            high = np.full((index.max() + 1, 2), -np.inf)
            np.minimum.at(low, index, v[:, :2])
            np.maximum.at(high, index, v[:, :2])
            filled = np.isfinite(low).all(axis=1)
            centre = np.where(filled[:, None], (low + high) / 2.0, 0.0)
            axes = np.where(filled[:, None], SHRINK * (high - low) / 2.0, 0.0)  # empty slice: no ellipse
            self.slices.append((j, bottom, centre, axes))

    def gaps(self, vertices, poses, trans):
        """(T, N) metres from points `vertices` (T, N, 3) of a body posed by `poses`, `trans` to the
        nearest shrunk torso slice, measured along the ray from the slice's centre (negative: inside)."""
        rotations, positions = self.body.joint_transforms(poses, trans, self.rest_joints)
        gap = np.full(vertices.shape[:2], np.inf)
        for j, bottom, centre, axes in self.slices:
            local = np.einsum("tba,tnb->tna", rotations[:, j], vertices - positions[:, None, j]) + self.rest_joints[j]
            k = np.floor((local[..., 2] - bottom) / SLICE_M).astype(int)
            valid = (k >= 0) & (k < len(centre))
            k = np.clip(k, 0, len(centre) - 1)
            valid &= (axes[k] > 0).all(axis=-1)
            offset = local[..., :2] - centre[k]
            radius = np.sqrt(((offset / np.where(valid[..., None], axes[k], 1.0)) ** 2).sum(axis=-1))
            distance = np.linalg.norm(offset, axis=-1) * (1.0 - 1.0 / np.maximum(radius, 1e-9))
            gap = np.minimum(gap, np.where(valid, distance, np.inf))
        return gap


@pytest.fixture(scope="module")
def torso(body):
    return TorsoModel(body)


def forearm_gaps(body, torso, poses, trans):
    """(T, N) gaps of the forearm and hand vertices (skinning argmax) from the torso."""
    forearm = np.isin(np.argmax(body.weights, axis=1), [joint(name) for name in FOREARMS])
    vertices = body.pose(poses, trans).vertices[:, forearm].astype(np.float64)
    return torso.gaps(vertices, poses, trans)


# -- the registry and the Motion ------------------------------------------------------------------------


def test_registry_lists_every_required_motion():
    assert REQUIRED <= set(BUILTIN_MOTIONS)
    assert NAMES == sorted(BUILTIN_MOTIONS)
    assert all(3.0 <= entry.seconds <= 5.0 for entry in BUILTIN_MOTIONS.values())


@pytest.mark.parametrize("name", NAMES)
def test_motion_is_valid_with_its_defaults(motions, name):
    motion = motions[name]
    assert isinstance(motion, Motion)
    assert (motion.name, motion.source, motion.fps) == (name, "builtin", 120.0)
    assert motion.duration == pytest.approx(BUILTIN_MOTIONS[name].seconds)
    assert motion.poses.shape == (motion.num_frames, 24, 3) and motion.trans.shape == (motion.num_frames, 3)
    assert np.isfinite(motion.poses).all() and np.isfinite(motion.trans).all()


def test_seconds_and_fps_are_honoured_and_poses_do_not_depend_on_the_rate():
    slow = builtin_motion("walk", seconds=2.0, fps=30.0)
    fast = builtin_motion("walk", seconds=2.0, fps=120.0)
    assert (slow.num_frames, slow.duration, slow.fps) == (61, pytest.approx(2.0), 30.0)
    np.testing.assert_allclose(slow.poses, fast.poses[::4], atol=1e-9)
    np.testing.assert_allclose(slow.trans, fast.trans[::4], atol=0.03)  # the root path is integrated


def test_bad_arguments_raise_naming_the_problem():
    with pytest.raises(ValueError, match="unknown built-in motion 'moonwalk'; known: arm_raise, arm_swing"):
        builtin_motion("moonwalk")
    for kwargs, field in (({"speed": 0.0}, "speed"), ({"speed": -1.0}, "speed"), ({"seconds": 0.0}, "seconds"),
                          ({"seconds": -2.0}, "seconds"), ({"fps": 0.0}, "fps"), ({"amplitude": -0.5}, "amplitude")):
        with pytest.raises(ValueError, match=f"'walk': {field} must be"):
            builtin_motion("walk", **kwargs)
    with pytest.raises(ValueError, match="less than one frame interval"):
        builtin_motion("walk", seconds=0.001)


# -- amplitude and speed --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_amplitude_zero_holds_the_neutral_pose(motions, name):
    still = builtin_motion(name, amplitude=0.0)
    assert np.ptp(still.poses, axis=0).max() < 1e-9 and np.ptp(still.trans, axis=0).max() < 1e-9
    assert np.abs(motions[name].poses - still.poses[:1]).max() > 0.03  # while amplitude 1 does move


@pytest.mark.parametrize("name", sorted(set(NAMES) - {"walk", "run"}))
def test_motions_in_place_start_and_end_in_the_neutral_pose(motions, name):
    neutral = rotvec_to_matrix(builtin_motion(name, amplitude=0.0).poses[0])
    moving = rotvec_to_matrix(motions[name].poses)
    np.testing.assert_allclose(moving[0], neutral, atol=1e-9)
    np.testing.assert_allclose(moving[-1], neutral, atol=1e-9)  # a full turn for the spin


@pytest.mark.parametrize("name, tolerance", [("walk", 0.01), ("run", 0.03)])  # a run has no double support
def test_gaits_start_and_end_with_both_feet_on_the_ground(body, motions, name, tolerance):
    motion = motions[name]
    posed = body.pose(motion.poses[[0, -1]], motion.trans[[0, -1]])
    segment = np.argmax(body.weights, axis=1)
    for side in ("left", "right"):
        foot = np.isin(segment, [joint(f"{side}_ankle"), joint(f"{side}_foot")])
        assert np.abs(posed.vertices[:, foot, 2].min(axis=1)).max() < tolerance


@pytest.mark.parametrize("name", NAMES)
def test_motions_start_and_end_at_rest(motions, name):
    motion = motions[name]
    speed = np.linalg.norm(np.diff(motion.poses[[0, 1, -2, -1]], axis=0)[[0, 2]], axis=-1) * motion.fps
    assert speed.max() < 0.1  # rad/s over the first and the last frame interval (a few rad/s mid-motion)
    assert np.abs(np.diff(motion.trans[[0, 1, -2, -1]], axis=0)[[0, 2]]).max() * motion.fps < 0.01  # m/s


def test_neutral_pose_stands_with_arms_hanging_and_tpose_is_the_rest_pose(body):
    standing = builtin_motion("walk", amplitude=0.0)
    joints = body.pose(standing.poses[:1], standing.trans[:1]).joints[0]
    for side in ("left", "right"):
        arm = joints[joint(f"{side}_wrist")] - joints[joint(f"{side}_shoulder")]
        below_horizontal = np.degrees(np.arcsin(-arm[2] / np.linalg.norm(arm)))
        assert 65.0 < below_horizontal < 85.0
    np.testing.assert_allclose(builtin_motion("tpose", amplitude=0.0).poses, 0.0, atol=1e-12)


def dominant_hz(signal, fps):
    spectrum = np.abs(np.fft.rfft(signal - signal.mean()))
    return np.fft.rfftfreq(len(signal), 1.0 / fps)[np.argmax(spectrum)]


@pytest.mark.parametrize("name", ["walk", "run"])
def test_speed_doubles_the_strides_and_the_distance(motions, name):
    quick = builtin_motion(name, speed=2.0)
    assert quick.duration == motions[name].duration
    assert -quick.trans[-1, 1] / -motions[name].trans[-1, 1] == pytest.approx(2.0, rel=0.1)


@pytest.mark.parametrize("name, joint_name", [("squat", "left_knee"), ("arm_swing", "left_shoulder"),
                                              ("jump", "left_knee")])
def test_speed_doubles_the_dominant_frequency(motions, name, joint_name):
    slow = np.linalg.norm(motions[name].poses[:, joint(joint_name)], axis=-1)
    fast = np.linalg.norm(builtin_motion(name, speed=2.0).poses[:, joint(joint_name)], axis=-1)
    assert dominant_hz(fast, 120.0) == pytest.approx(2.0 * dominant_hz(slow, 120.0), rel=0.15)


def test_amplitude_scales_the_joint_angles(motions):
    half = builtin_motion("squat", amplitude=0.5)
    knee = joint("left_knee")
    deepest = np.linalg.norm(motions["squat"].poses[:, knee], axis=-1).max()
    assert np.linalg.norm(half.poses[:, knee], axis=-1).max() == pytest.approx(0.5 * deepest, rel=1e-6)


# -- smoothness -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_joint_angular_acceleration_is_bounded(motions, name):
    peak = angular_acceleration(motions[name]).max(axis=0)
    worst = int(np.argmax(peak))
    assert peak[worst] < MAX_ANGULAR_ACCELERATION, f"{name}: {SMPL_JOINT_NAMES[worst]} at {peak[worst]:.0f} rad/s^2"


def test_acceleration_measure_catches_a_kink():
    motion = builtin_motion("tpose", amplitude=0.0)
    kinked = motion.poses.copy()
    kinked[len(kinked) // 2:, joint("left_elbow"), 2] += np.radians(1.0)  # a one-degree step
    assert angular_acceleration(motion.replace(poses=kinked)).max() > MAX_ANGULAR_ACCELERATION


@pytest.mark.parametrize("name", NAMES)
def test_root_path_is_smooth(motions, name):
    motion = motions[name]
    acceleration = np.linalg.norm(np.diff(motion.trans, 2, axis=0), axis=1) * motion.fps**2
    assert acceleration.max() < 25.0  # m/s^2: below 2.5 g, even where a run changes feet


# -- arms and torso -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_forearms_and_hands_stay_out_of_the_torso(body, torso, motions, name):
    motion = motions[name]
    gaps = forearm_gaps(body, torso, motion.poses[::FRAME_STEP], motion.trans[::FRAME_STEP])
    assert gaps.min() > 0.02, f"{name}: forearm or hand {gaps.min():.3f} m from the torso"


def test_torso_check_catches_a_forearm_in_the_belly(body, torso):
    """Arm hanging, elbow bent 100 degrees, upper arm turned 90 degrees inwards: the forearm goes
    through the belly (about 10 cm deep)."""
    poses = np.zeros((2, 24, 3))
    for frame, inward in enumerate((0.0, 90.0)):
        shoulder = rotvec_to_matrix([0.0, 0.0, -np.radians(inward)]) @ rotvec_to_matrix([0.0, np.radians(80.0), 0.0])
        poses[frame, joint("left_shoulder")] = matrix_to_rotvec(shoulder)
        poses[frame, joint("left_elbow")] = (0.0, 0.0, -np.radians(100.0))
    gaps = forearm_gaps(body, torso, poses, np.zeros((2, 3)))
    assert gaps[0].min() > 0.02  # forearm straight ahead: clear
    assert (gaps[1] < 0.0).sum() > 100  # turned in: many forearm and hand vertices inside


# -- ground, travel, turning ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["walk", "run"])
def test_gaits_travel_forward_with_feet_on_the_ground(body, motions, name):
    motion = motions[name]
    posed = body.pose(motion.poses[::FRAME_STEP], motion.trans[::FRAME_STEP])
    lowest = posed.vertices[..., 2].min(axis=1)
    assert -0.03 < lowest.min() and lowest.max() < 0.1
    travel = motion.trans[-1] - motion.trans[0]
    assert travel[1] < -0.6 * motion.duration  # towards -Y, at least 0.6 m/s on average
    assert abs(travel[0]) < 0.05 * abs(travel[1])
    assert np.all(np.diff(motion.trans[:, 1]) <= 1e-9)  # never steps back


@pytest.mark.parametrize("name", ["squat", "bend", "arm_raise", "tpose"])
def test_planted_motions_stand_on_the_ground(body, motions, name):
    motion = motions[name]
    lowest = body.pose(motion.poses[::FRAME_STEP], motion.trans[::FRAME_STEP]).vertices[..., 2].min(axis=1)
    assert np.abs(lowest).max() < 0.01


def test_jump_leaves_the_ground_and_lands(body, motions):
    motion = motions["jump"]
    lowest = body.pose(motion.poses[::FRAME_STEP], motion.trans[::FRAME_STEP]).vertices[..., 2].min(axis=1)
    assert lowest.max() > 0.1 and lowest.min() > -0.02 and abs(lowest[-1]) < 0.01


def test_spin_turns_once_about_z_on_the_spot(body, motions):
    motion = motions["spin"]
    facing = rotvec_to_matrix(motion.poses[:, 0]) @ np.array([0.0, -1.0, 0.0])
    assert np.abs(facing[:, 2]).max() < 0.05
    turned = np.unwrap(np.arctan2(facing[:, 1], facing[:, 0]))
    assert np.degrees(turned[-1] - turned[0]) == pytest.approx(360.0, abs=1.0)
    assert np.degrees(np.diff(turned)).min() > -0.01  # always to the left (counter-clockwise from above)
    assert np.abs(motion.trans[:, :2]).max() < 1e-9


def test_other_body_shape_stands_on_its_own_feet(body):
    tall = body.replace(default_betas=np.array([0.5, 0.5, 1.0]))
    walk = builtin_motion("walk", seconds=3.0, body=tall)
    lowest = tall.pose(walk.poses[::FRAME_STEP], walk.trans[::FRAME_STEP]).vertices[..., 2].min(axis=1)
    assert -0.03 < lowest.min() and lowest.max() < 0.1
    squat = builtin_motion("squat", body=tall)
    assert squat.trans[0, 2] == pytest.approx(tall.rest()[1][0, 2], abs=1e-4)  # standing as at rest
    assert squat.trans[0, 2] > builtin_motion("squat").trans[0, 2] + 0.02
