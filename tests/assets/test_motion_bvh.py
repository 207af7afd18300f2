"""BVH files: parsing (channel orders, end sites, clear errors) and retargeting a CMU skeleton onto the
default body (bone directions follow the source exactly, whatever the source's rest pose), on a
synthetic skeleton and on real headers of two CMU conversions (cgspeed's MotionBuilder-friendly and
Daz-friendly releases), whose skeleton is recognised by its joint names."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.body import SMPL_JOINT_NAMES, SMPL_PARENTS, default_body
from assets.motion import Motion
from assets.motion.bvh import CMU_TO_SMPL, DAZ_TO_SMPL, parse_bvh, read_bvh, resolve_mapping, retarget_to_smpl
from assets.rotations import Y_UP_TO_Z_UP, align_vectors, rotvec_to_matrix

# The CMU skeleton as the cgspeed BVH conversion writes it: Y up, facing +Z, T-pose, CMU units; like
# the hips, neck and shoulders, FingerBase starts where its parent does (the shipped clip's layout).
CMU_SKELETON = (
    ("Hips", None, (0.0, 0.0, 0.0)),
    ("LHipJoint", "Hips", (0.0, 0.0, 0.0)),
    ("LeftUpLeg", "LHipJoint", (1.36306, -1.79463, 0.83929)),
    ("LeftLeg", "LeftUpLeg", (2.44811, -6.72613, 0.0)),
    ("LeftFoot", "LeftLeg", (2.5622, -7.03959, 0.0)),
    ("LeftToeBase", "LeftFoot", (0.15764, -0.43311, 2.32255)),
    ("RHipJoint", "Hips", (0.0, 0.0, 0.0)),
    ("RightUpLeg", "RHipJoint", (-1.30552, -1.79463, 0.83929)),
    ("RightLeg", "RightUpLeg", (-2.54253, -6.98555, 0.0)),
    ("RightFoot", "RightLeg", (-2.56826, -7.05623, 0.0)),
    ("RightToeBase", "RightFoot", (0.16473, -0.45259, 2.36315)),
    ("LowerBack", "Hips", (0.0, 0.0, 0.0)),
    ("Spine", "LowerBack", (0.02827, 2.03559, -0.19338)),
    ("Spine1", "Spine", (0.05675, 2.04945, -0.08597)),
    ("Neck", "Spine1", (0.0, 0.0, 0.0)),
    ("Neck1", "Neck", (-0.05417, 1.74624, 0.17202)),
    ("Head", "Neck1", (0.10407, 1.76136, -0.12497)),
    ("LeftShoulder", "Spine1", (0.0, 0.0, 0.0)),
    ("LeftArm", "LeftShoulder", (3.36241, 1.20089, -0.31121)),
    ("LeftForeArm", "LeftArm", (4.983, 0.0, 0.0)),
    ("LeftHand", "LeftForeArm", (3.48356, 0.0, 0.0)),
    ("LeftFingerBase", "LeftHand", (0.0, 0.0, 0.0)),
    ("LeftHandIndex1", "LeftFingerBase", (0.71526, 0.0, 0.0)),
    ("LThumb", "LeftHand", (0.0, 0.0, 0.0)),
    ("RightShoulder", "Spine1", (0.0, 0.0, 0.0)),
    ("RightArm", "RightShoulder", (-3.1366, 1.37405, -0.40465)),
    ("RightForeArm", "RightArm", (-5.2419, 0.0, 0.0)),
    ("RightHand", "RightForeArm", (-3.44417, 0.0, 0.0)),
    ("RightFingerBase", "RightHand", (0.0, 0.0, 0.0)),
    ("RightHandIndex1", "RightFingerBase", (-0.62253, 0.0, 0.0)),
    ("RThumb", "RightHand", (0.0, 0.0, 0.0)),
)
CMU_END_SITES = {
    "LeftToeBase": (0.0, 0.0, 1.17758), "RightToeBase": (0.0, 0.0, 1.1543), "Head": (0.0, 0.0, 0.0),
    "LeftHandIndex1": (0.4622, 0.0, 0.0), "LThumb": (0.5195, 0.0, 0.5195),
    "RightHandIndex1": (-0.4022, 0.0, 0.0), "RThumb": (-0.4455, 0.0, 0.4455),
}  # fmt: skip
FRAME_TIME = 0.008333
MOTIONS = Path(__file__).resolve().parents[2] / "assets" / "data" / "motions"
# Real headers (tests/assets/data):
# - cmu_05_04_cgspeed_first3.bvh: CMU trial 05_04 in Bruce Hahne's cgspeed "MotionBuilder-friendly"
#   conversion, from github.com/una-dinosauria/cmu-mocap, file 005/05_04.bvh at commit
#   62ac0fb0ec43cff2bf66426928f4fa6682d4bbdc: the hierarchy and the first 3 of its 1200 frames digit
#   for digit ('Frames: 3'); frame 1 is the conversion's added T-pose frame.  The file the issue
#   reported ("bone LeftHand -> LeftFingerBase ... has zero length at rest").
# - cmu_daz_friendly_skeleton.bvh: the skeleton of cgspeed's "Daz-friendly" release of the CMU database
#   (hip, abdomen, chest, lCollar, lShldr, rButtock, rThigh, ...), as published in
#   github.com/AmmarkoV/RGBDAcquisition, file opengl_acquisition_shared_library/
#   opengl_depth_and_color_renderer/Motions/DAZFriendlyCMU.bvh at commit
#   cc47865ff84692704ee44e0679e60f60773be134, verbatim with its one all-zero frame.
REAL = Path(__file__).resolve().parent / "data"
SHIPPED_CMU = {"cmu_93_03_charleston.bvh": 353, "cmu_144_05_front_kick.bvh": 304}  # file -> frames at 120 Hz
ARM_CHAINS = {  # joints below each shoulder, turned to hang at rest in the hanging-arm variant
    "Left": ("LeftForeArm", "LeftHand", "LeftFingerBase", "LeftHandIndex1", "LThumb"),
    "Right": ("RightForeArm", "RightHand", "RightFingerBase", "RightHandIndex1", "RThumb"),
}


def write_bvh(path, rotations, root, skeleton=CMU_SKELETON, end_sites=CMU_END_SITES, order="ZYX"):
    """A BVH file of `skeleton` driven by local rotations (T, J, 3, 3) and root positions (T, 3): the
    root gets 6 channels, every other joint 3, rotations written as intrinsic Euler angles in `order`."""
    rotation_channels = " ".join(f"{axis}rotation" for axis in order)
    lines = ["HIERARCHY"]

    def emit(j, depth):
        name, parent, offset = skeleton[j]
        pad = "\t" * depth
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(pad + "\tOFFSET " + " ".join(f"{v:.6f}" for v in offset))
        position = "6 Xposition Yposition Zposition " if parent is None else "3 "
        lines.append(f"{pad}\tCHANNELS {position}{rotation_channels}")
        for child, (_, child_parent, _) in enumerate(skeleton):
            if child_parent == name:
                emit(child, depth + 1)
        if name in end_sites:
            site = " ".join(f"{v:.6f}" for v in end_sites[name])
            lines.extend([pad + "\tEnd Site", pad + "\t{", f"{pad}\t\tOFFSET {site}", pad + "\t}"])
        lines.append(pad + "}")

    emit(0, 0)
    frames = len(root)
    euler = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_euler(order, degrees=True).reshape(frames, -1)
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {FRAME_TIME}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in np.concatenate([root, euler], axis=1)]
    path.write_text("\n".join(lines) + "\n")
    return path


def random_motion(frames=6, seed=7):
    """Local rotations (T, J, 3, 3) up to about 30 degrees per Euler angle and a walking root (T, 3)."""
    rng = np.random.default_rng(seed)
    angles = rng.uniform(-30.0, 30.0, (frames * len(CMU_SKELETON), 3))
    rotations = Rotation.from_euler("ZYX", angles, degrees=True).as_matrix().reshape(frames, -1, 3, 3)
    t = np.arange(frames) / 120.0
    root = np.stack([0.5 * np.sin(4 * t), 17.0 + 0.3 * np.sin(8 * t), 60.0 * t], axis=1)
    return rotations, root


def hanging_arms(rotations):
    """The same world motion for a CMU skeleton whose arms hang down at rest: skeleton, end sites and
    local rotations.  The arm below each shoulder is turned at rest by Q (about the facing axis, +Z), so
    its world rotations become G Q^T: locals L Q^T at the upper arm, Q L Q^T below."""
    names = [name for name, _, _ in CMU_SKELETON]
    skeleton, end_sites, rotations = list(CMU_SKELETON), dict(CMU_END_SITES), rotations.copy()
    for side, sign in (("Left", -1.0), ("Right", 1.0)):
        q = Rotation.from_euler("z", sign * 90.0, degrees=True).as_matrix()
        arm = names.index(f"{side}Arm")
        rotations[:, arm] = rotations[:, arm] @ q.T
        for name in ARM_CHAINS[side]:
            j = names.index(name)
            skeleton[j] = (name, skeleton[j][1], tuple(q @ skeleton[j][2]))
            rotations[:, j] = q @ rotations[:, j] @ q.T
            if name in end_sites:
                end_sites[name] = tuple(q @ end_sites[name])
    return tuple(skeleton), end_sites, rotations


def smpl(name):
    return SMPL_JOINT_NAMES.index(name)


def bone_end(name):
    """The SMPL joint at the far end of an SMPL joint's bone: its first child; spine3's is the neck."""
    return "neck" if name == "spine3" else SMPL_JOINT_NAMES[SMPL_PARENTS.index(smpl(name))]


def angle(a, b):
    """Angles (...,) in degrees between direction arrays (..., 3)."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def bone_errors(motion, bvh, body, mapping=None):
    """SMPL joint -> (T,) angle in degrees between the body's posed bone and the source's bone (axis
    converted), for every bone with a far source joint (as `resolve_mapping` resolves them), and the
    pelvis's hip line."""
    mapping = resolve_mapping(bvh, mapping)
    _, joints = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])
    positions = bvh.forward_kinematics()[0] @ Y_UP_TO_Z_UP.T
    src = {name: j for j, name in enumerate(bvh.names)}
    tgt = {name: k for k, name in enumerate(SMPL_JOINT_NAMES)}
    bones = {"pelvis": (("right_hip", "left_hip"), (mapping["right_hip"][0], mapping["left_hip"][0]))}
    bones.update({k: ((k, bone_end(k)), pair) for k, pair in mapping.items() if pair[1] is not None})
    errors = {}
    for name, ((t0, t1), (s0, s1)) in bones.items():
        errors[name] = angle(joints[:, tgt[t1]] - joints[:, tgt[t0]], positions[:, src[s1]] - positions[:, src[s0]])
    return errors


def leg_ratio(bvh, body):
    """The body's hip-to-ankle distance over the CMU source's (both legs' mean): metres per file unit."""
    rest, source_rest = body.rest()[1], bvh.rest_positions()
    legs = (("left", "Left"), ("right", "Right"))
    target = [np.linalg.norm(rest[smpl(f"{s}_hip")] - rest[smpl(f"{s}_ankle")]) for s, _ in legs]
    src = bvh.names.index
    source = [np.linalg.norm(source_rest[src(f"{s}UpLeg")] - source_rest[src(f"{s}Foot")]) for _, s in legs]
    return np.mean(target) / np.mean(source)


@pytest.fixture(scope="module")
def body():
    return default_body()


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    rotations, root = random_motion()
    path = write_bvh(tmp_path_factory.mktemp("bvh") / "walk.bvh", rotations, root)
    return path, rotations, root


# -- parsing ---------------------------------------------------------------------------------------

TINY = """HIERARCHY
ROOT Base
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Arm
  {
    OFFSET 0 1 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 2 0 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 0 0 0 0 0 0 0
5 6 7 90 0 0 30 40 50
"""


def elementary(axis, degrees):
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return {
        "X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def test_parse_honours_channel_order(tmp_path):
    (tmp_path / "tiny.bvh").write_text(TINY)
    bvh = parse_bvh(tmp_path / "tiny.bvh")
    assert bvh.names == ("Base", "Arm", "Arm_End") and list(bvh.parents) == [-1, 0, 1]
    assert bvh.channels[1] == ("Xrotation", "Zrotation", "Yrotation") and bvh.channels[2] == ()
    assert bvh.frame_time == 0.04 and bvh.rotations.shape == (2, 3, 3, 3)
    np.testing.assert_allclose(bvh.root_positions, [[0, 0, 0], [5, 6, 7]])  # channels replace the offset
    np.testing.assert_allclose(bvh.rest_positions(), [[1, 2, 3], [1, 3, 3], [3, 3, 3]])
    positions, rotations = bvh.forward_kinematics()
    np.testing.assert_allclose(positions[0], [[0, 0, 0], [0, 1, 0], [2, 1, 0]], atol=1e-12)
    # Rotations compose in the listed order, intrinsically: Arm is Rx(30) Rz(40) Ry(50).
    root = elementary("Z", 90)
    arm = elementary("X", 30) @ elementary("Z", 40) @ elementary("Y", 50)
    np.testing.assert_allclose(rotations[1, 1], root @ arm, atol=1e-12)
    expected = np.array([5, 6, 7]) + root @ (np.array([0, 1, 0]) + arm @ np.array([2, 0, 0]))
    np.testing.assert_allclose(positions[1, 2], expected, atol=1e-12)
    other_order = elementary("Z", 40) @ elementary("X", 30) @ elementary("Y", 50)
    assert np.linalg.norm(root @ other_order @ [2, 0, 0] - root @ arm @ [2, 0, 0]) > 0.1


def test_parse_cmu_skeleton(walk):
    path, rotations, root = walk
    bvh = parse_bvh(path)
    joints = [name for name, _, _ in CMU_SKELETON]
    assert len(bvh.names) == len(CMU_SKELETON) + len(CMU_END_SITES)
    assert [n for n in bvh.names if not n.endswith("_End")] == joints  # file order: depth first, as listed
    for name, parent, offset in CMU_SKELETON:
        j = bvh.names.index(name)
        assert (parent is None and bvh.parents[j] == -1) or bvh.names[bvh.parents[j]] == parent
        np.testing.assert_allclose(bvh.offsets[j], offset)
    for name, offset in CMU_END_SITES.items():
        end = bvh.names.index(f"{name}_End")
        assert bvh.names[bvh.parents[end]] == name
        np.testing.assert_allclose(bvh.offsets[end], offset)
    assert bvh.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert bvh.frame_time == FRAME_TIME and bvh.rotations.shape == (len(root), len(bvh.names), 3, 3)
    np.testing.assert_allclose(bvh.root_positions, root, atol=1e-6)
    order = [bvh.names.index(n) for n in joints]
    np.testing.assert_allclose(bvh.rotations[:, order], rotations, atol=1e-6)


@pytest.mark.parametrize(
    "edit,message",
    [
        (lambda t: t.rstrip("\n").rsplit(" ", 1)[0] + "\n", r"tiny\.bvh: line 20: 8 values, expected 9"),
        (lambda t: t.split("MOTION")[0], r"tiny\.bvh: no MOTION section"),
        (lambda t: t.replace("OFFSET 0 1", "OFSET 0 1"), r"tiny\.bvh: line 8: unknown or misplaced keyword 'OFSET'"),
        (lambda t: t.replace("Frames: 2", "Frames: 3"), r"tiny\.bvh: 'Frames: 3' but 2 frame lines follow"),
        (lambda t: t.replace("n Xrotation Y", "n Wrotation Y"), r"tiny\.bvh: line 5: unknown or repeated channel 'Wrotation'"),
        (lambda t: t.replace("Time: 0.04", "Time 0.04"), r"tiny\.bvh: line 18: expected 'Frame Time: <seconds>'"),
    ],
)
def test_parse_errors_name_file_and_line(tmp_path, edit, message):
    (tmp_path / "tiny.bvh").write_text(edit(TINY))
    with pytest.raises(ValueError, match=message):
        parse_bvh(tmp_path / "tiny.bvh")


# -- retargeting -----------------------------------------------------------------------------------


def test_retarget_follows_source_bone_directions(walk, body):
    path, rotations, root = walk
    motion = read_bvh(path)
    assert isinstance(motion, Motion) and motion.poses.shape == (len(root), 24, 3)
    assert motion.fps == pytest.approx(1.0 / FRAME_TIME) and motion.name == "walk" and motion.source == str(path)
    bvh = parse_bvh(path)
    errors = bone_errors(motion, bvh, body)
    assert len(errors) == 1 + sum(far is not None for _, far in CMU_TO_SMPL.values())
    worst = max(float(e.max()) for e in errors.values())
    assert worst < 1e-4, {k: float(e.max()) for k, e in errors.items()}
    # Where the far joint is the source joint's child, the twist is the source's: G_tgt = G_src A.
    world_r = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])[0]
    source_r = Y_UP_TO_Z_UP @ bvh.forward_kinematics()[1] @ Y_UP_TO_Z_UP.T
    rest, source_rest = body.rest()[1], bvh.rest_positions() @ Y_UP_TO_Z_UP.T
    resolved = resolve_mapping(bvh).items()
    direct = {k: (bvh.names.index(s), bvh.names.index(f)) for k, (s, f) in resolved if f is not None}
    direct = {k: (s, f) for k, (s, f) in direct.items() if bvh.parents[f] == s}
    assert "left_knee" in direct and "neck" not in direct
    for name, (s, f) in direct.items():
        k, c = smpl(name), smpl(bone_end(name))
        align = align_vectors(rest[c] - rest[k], source_rest[f] - source_rest[s])
        np.testing.assert_allclose(world_r[:, k], source_r[:, s] @ align, atol=1e-6, err_msg=name)


def test_zero_rotations_on_a_t_posed_source(tmp_path, body):
    """At the source's rest pose each SMPL bone turns minimally onto the source's rest bone: joints whose
    rest bones already agree (pelvis hip line, arms) and joints without a bone keep no rotation."""
    frames = 2
    rotations = np.broadcast_to(np.eye(3), (frames, len(CMU_SKELETON), 3, 3))
    root = np.array([[0.0, 17.0, 0.0], [1.0, 17.0, 2.0]])
    bvh = parse_bvh(write_bvh(tmp_path / "rest.bvh", rotations, root))
    motion = retarget_to_smpl(bvh)
    world_r, joints = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])
    still = ["pelvis", "spine3", "head", "left_foot", "right_foot"] + [
        f"{side}_{joint}" for side in ("left", "right") for joint in ("elbow", "wrist", "hand")
    ]
    for name in still:  # (the body's arms, stored in float32, are along X to about 1e-7)
        np.testing.assert_allclose(motion.poses[:, smpl(name)], 0.0, atol=1e-6, err_msg=name)
    for side in ("left", "right"):
        np.testing.assert_allclose(world_r[:, smpl(f"{side}_shoulder")], np.tile(np.eye(3), (frames, 1, 1)), atol=1e-6)
    rest = body.rest()[1]
    source_rest = bvh.rest_positions() @ Y_UP_TO_Z_UP.T
    for name, (src, far) in resolve_mapping(bvh).items():
        if far is None:
            continue
        k, c = smpl(name), smpl(bone_end(name))
        rest_angle = angle(rest[c] - rest[k], source_rest[bvh.names.index(far)] - source_rest[bvh.names.index(src)])
        turn = np.degrees(np.linalg.norm(Rotation.from_matrix(world_r[:, k]).as_rotvec(), axis=-1))
        np.testing.assert_allclose(turn, rest_angle, atol=1e-6, err_msg=name)
    assert max(float(e.max()) for e in bone_errors(motion, bvh, body).values()) < 1e-4
    # The body's ankles stand where the scaled source's ankles stand.
    ankles = [smpl(n) for n in ("left_ankle", "right_ankle")]
    src_ankles = [bvh.names.index(n) for n in ("LeftFoot", "RightFoot")]
    source_ankle = (bvh.forward_kinematics()[0] @ Y_UP_TO_Z_UP.T)[:, src_ankles, 2].mean(axis=1)
    np.testing.assert_allclose(joints[:, ankles, 2].mean(axis=1), leg_ratio(bvh, body) * source_ankle, atol=1e-9)


def test_hanging_arm_rest_pose_gives_the_same_motion(tmp_path, walk, body):
    """A source whose arms hang at rest, moving exactly as the T-posed one, retargets to the same poses
    and its arm bones' directions are followed exactly."""
    path, rotations, root = walk
    skeleton, end_sites, hanging_rotations = hanging_arms(rotations)
    hanging_path = write_bvh(tmp_path / "hanging.bvh", hanging_rotations, root, skeleton, end_sites)
    hanging = parse_bvh(hanging_path)
    reference = parse_bvh(path)
    np.testing.assert_allclose(hanging.forward_kinematics()[0], reference.forward_kinematics()[0], atol=1e-4)
    rest = hanging.rest_positions()
    assert rest[hanging.names.index("LeftForeArm"), 1] < rest[hanging.names.index("LeftArm"), 1] - 4.0  # it hangs
    motion = retarget_to_smpl(hanging)
    expected = retarget_to_smpl(reference)
    np.testing.assert_allclose(rotvec_to_matrix(motion.poses), rotvec_to_matrix(expected.poses), atol=1e-5)
    np.testing.assert_allclose(motion.trans, expected.trans, atol=1e-9)
    errors = bone_errors(motion, hanging, body)
    arms = [f"{side}_{joint}" for side in ("left", "right") for joint in ("shoulder", "elbow", "wrist")]
    assert max(float(errors[name].max()) for name in arms) < 1e-4


@pytest.mark.parametrize("name, frames", SHIPPED_CMU.items())
def test_shipped_cmu_clip_follows_its_bones_and_floor(body, name, frames):
    """Real cgspeed CMU mocap (its FingerBase sits at the hand joint, so the wrist bone must end at
    HandIndex1): every mapped bone follows the source and the lowest joint stays near the floor."""
    bvh = parse_bvh(MOTIONS / name)
    motion = retarget_to_smpl(bvh, body)
    assert motion.poses.shape == (frames, 24, 3) and motion.fps == pytest.approx(1.0 / 0.0083333)
    worst = max(float(e.max()) for e in bone_errors(motion, bvh, body).values())
    assert worst < 1e-4
    lowest = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])[1][..., 2].min(axis=1)
    assert 0.0 < lowest.min() and lowest.max() < 0.1  # the ankles or toes, in metres


def test_root_path_is_scaled_and_axis_converted(walk, body):
    bvh = parse_bvh(walk[0])
    root = bvh.root_positions
    scale = leg_ratio(bvh, body)
    assert 0.05 < scale < 0.06  # CMU units are about 5.4 cm
    for given, expected_scale in ((None, scale), (0.05, 0.05)):
        motion = retarget_to_smpl(bvh, scale=given)
        expected = expected_scale * (root - root[0]) @ Y_UP_TO_Z_UP.T
        np.testing.assert_allclose(motion.trans - motion.trans[0], expected, atol=1e-9)
    assert motion.trans[-1, 1] < motion.trans[0, 1] - 0.1  # walking along the source's +Z is walking along -Y


def test_partial_map_and_z_up_source(tmp_path, walk, body):
    """A map may leave SMPL joints out (they turn with their parent); a Z-up file needs no conversion."""
    path, rotations, root = walk
    mapping = {name: pair for name, pair in CMU_TO_SMPL.items() if "collar" not in name}
    bvh = parse_bvh(path)
    errors = bone_errors(retarget_to_smpl(bvh, mapping=mapping), bvh, body, mapping)
    assert "left_collar" not in errors and max(float(e.max()) for e in errors.values()) < 1e-4
    # The same motion written in the project's frame (Z up) retargets to the same result with up='z'.
    c = Y_UP_TO_Z_UP
    z_skeleton = tuple((n, p, tuple(c @ o)) for n, p, o in CMU_SKELETON)
    z_ends = {n: tuple(c @ o) for n, o in CMU_END_SITES.items()}
    z_path = write_bvh(tmp_path / "z_up.bvh", c @ rotations @ c.T, root @ c.T, z_skeleton, z_ends)
    z_motion = read_bvh(z_path, up="z")
    y_motion = read_bvh(path)
    np.testing.assert_allclose(rotvec_to_matrix(z_motion.poses), rotvec_to_matrix(y_motion.poses), atol=1e-5)
    np.testing.assert_allclose(z_motion.trans, y_motion.trans, atol=1e-6)


def test_missing_mapped_joint_is_named(tmp_path):
    rename = {"LeftForeArm": "LeftElbow"}
    skeleton = tuple((rename.get(n, n), rename.get(p, p), o) for n, p, o in CMU_SKELETON)
    rotations, root = random_motion(frames=2)
    path = write_bvh(tmp_path / "renamed.bvh", rotations, root, skeleton)
    with pytest.raises(ValueError, match=r"renamed\.bvh: the skeleton lacks joint\(s\) LeftForeArm of the SMPL"):
        read_bvh(path)
    with pytest.raises(ValueError, match=r"must map \['left_ankle'\]"):
        read_bvh(path, mapping={k: v for k, v in CMU_TO_SMPL.items() if k != "left_ankle"})
    with pytest.raises(ValueError, match="up must be 'y' or 'z'"):
        read_bvh(path, up="x")


# -- real headers of two CMU conversions --------------------------------------------------------------


def with_frames(tmp_path, name, frames):
    """The real file `name` with its motion replaced by `frames` (rows of channel values)."""
    header = (REAL / name).read_text().split("MOTION")[0]
    frame_time = "Frame Time: " + (REAL / name).read_text().split("Frame Time:")[1].split()[0]
    rows = "\n".join(" ".join(f"{v:g}" for v in row) for row in frames)
    path = tmp_path / name
    path.write_text(f"{header}MOTION\nFrames: {len(frames)}\n{frame_time}\n{rows}\n")
    return path


def channel(bvh, joint, axis):
    """Column of `joint`'s `axis` rotation channel in a frame row."""
    column = sum(len(c) for c in bvh.channels[: bvh.names.index(joint)])
    return column + bvh.channels[bvh.names.index(joint)].index(f"{axis}rotation")


def world_turns(motion, body):
    """(T, 24) each SMPL joint's world rotation angle in degrees, away from the T-pose."""
    world = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])[0]
    return np.degrees(np.linalg.norm(Rotation.from_matrix(world.reshape(-1, 3, 3)).as_rotvec(), axis=-1)).reshape(
        len(motion.poses), -1)


def elevation(motion, body, joint, child):
    """(T,) degrees the bone joint -> child of the posed body points above the horizontal."""
    joints = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])[1]
    bone = joints[:, smpl(child)] - joints[:, smpl(joint)]
    return np.degrees(np.arcsin(bone[:, 2] / np.linalg.norm(bone, axis=1)))


LIMBS = [f"{side}_{joint}" for side in ("left", "right") for joint in ("hip", "knee", "shoulder", "elbow", "wrist")]


def test_real_cgspeed_header_walks_past_joints_stacked_on_their_parent(body):
    """The file the issue reported: cgspeed's FingerBase sits on the hand (offset 0 0 0), so the wrist's
    bone LeftHand -> LeftFingerBase has no length; the map walks on to HandIndex1 and the motion
    converts, every mapped bone following the source."""
    bvh = parse_bvh(REAL / "cmu_05_04_cgspeed_first3.bvh")
    np.testing.assert_array_equal(bvh.offsets[bvh.names.index("LeftFingerBase")], 0.0)
    assert CMU_TO_SMPL["left_wrist"] == ("LeftHand", "LeftFingerBase")
    resolved = resolve_mapping(bvh)
    assert resolved["left_wrist"] == ("LeftHand", "LeftHandIndex1")
    assert resolved["right_wrist"] == ("RightHand", "RightHandIndex1")
    others = {k: v for k, v in CMU_TO_SMPL.items() if "wrist" not in k}
    assert {k: v for k, v in resolved.items() if "wrist" not in k} == others
    motion = read_bvh(REAL / "cmu_05_04_cgspeed_first3.bvh", body)
    assert motion.poses.shape == (3, 24, 3) and np.isfinite(motion.poses).all()
    assert max(float(e.max()) for e in bone_errors(motion, bvh, body).values()) < 1e-4
    # Frame 1 is the conversion's T-pose (legs turned 21 degrees in to stand straight, arms 8 degrees
    # down): the body's pelvis does not turn and its limbs stay within 10 degrees of SMPL's T-pose.
    turns = world_turns(motion, body)
    assert turns[0, smpl("pelvis")] < 0.5
    assert max(turns[0, smpl(name)] for name in LIMBS) < 10.0
    for side in ("left", "right"):
        assert elevation(motion, body, f"{side}_shoulder", f"{side}_elbow")[0] == pytest.approx(-8.0, abs=0.5)


def test_real_cgspeed_arm_raise_reaches_the_left_shoulder(tmp_path, body):
    """The T-pose frame with LeftArm turned 60 degrees about the facing axis (Zrotation): the body's
    left upper arm rises 60 degrees, its right arm does not move."""
    bvh = parse_bvh(REAL / "cmu_05_04_cgspeed_first3.bvh")
    first_row = (REAL / "cmu_05_04_cgspeed_first3.bvh").read_text().split("Frame Time:")[1].splitlines()[1]
    tpose = np.array(first_row.split(), dtype=float)
    raised = tpose.copy()
    raised[channel(bvh, "LeftArm", "Z")] += 60.0
    motion = read_bvh(with_frames(tmp_path, "cmu_05_04_cgspeed_first3.bvh", [tpose, raised]), body)
    left = elevation(motion, body, "left_shoulder", "left_elbow")
    right = elevation(motion, body, "right_shoulder", "right_elbow")
    assert left[1] - left[0] == pytest.approx(60.0, abs=0.5)
    assert right[1] == pytest.approx(right[0], abs=1e-6)
    right_shoulder = motion.poses[:, smpl("right_shoulder")]
    np.testing.assert_allclose(right_shoulder[1], right_shoulder[0], atol=1e-9)


def test_real_daz_friendly_header_is_recognised_and_followed(tmp_path, body):
    """cgspeed's Daz-friendly skeleton (no CMU names) converts without a mapping: its rest frame keeps
    the pelvis and legs near SMPL's T-pose, a 60 degree lShldr raise lifts the left upper arm 60
    degrees and a 45 degree rShin bend bends the right knee 45 degrees."""
    bvh = parse_bvh(REAL / "cmu_daz_friendly_skeleton.bvh")
    assert resolve_mapping(bvh) == DAZ_TO_SMPL  # nothing stacked: no far joint to walk past
    rest = np.zeros(sum(len(c) for c in bvh.channels))
    raised, bent = rest.copy(), rest.copy()
    raised[channel(bvh, "lShldr", "Z")] = 60.0
    bent[channel(bvh, "rShin", "X")] = 45.0
    path = with_frames(tmp_path, "cmu_daz_friendly_skeleton.bvh", [rest, raised, bent])
    motion = read_bvh(path, body)
    assert motion.poses.shape == (3, 24, 3) and motion.fps == pytest.approx(25.0)
    assert max(float(e.max()) for e in bone_errors(motion, parse_bvh(path), body).values()) < 1e-4
    turns = world_turns(motion, body)
    legs = [f"{side}_{joint}" for side in ("left", "right") for joint in ("hip", "knee")]
    assert turns[0, smpl("pelvis")] < 0.5 and max(turns[0, smpl(name)] for name in legs) < 10.0
    left = elevation(motion, body, "left_shoulder", "left_elbow")
    assert left[1] - left[0] == pytest.approx(60.0, abs=0.5)
    joints = body.joint_transforms(motion.poses, motion.trans, body.rest()[1])[1]
    thigh, shin = (joints[:, smpl(b)] - joints[:, smpl(a)] for a, b in (("right_hip", "right_knee"),
                                                                        ("right_knee", "right_ankle")))
    flexion = angle(thigh, shin)
    assert flexion[2] - flexion[0] == pytest.approx(45.0, abs=2.0)
    np.testing.assert_allclose(motion.poses[1, smpl("right_knee")], motion.poses[0, smpl("right_knee")], atol=1e-9)


def test_a_bone_with_nothing_usable_below_is_refused_by_name(tmp_path):
    """A far joint stacked on its source with only stacked joints below it cannot give a bone."""
    text = (REAL / "cmu_05_04_cgspeed_first3.bvh").read_text()
    flat = text.replace("OFFSET 0.72750 -0.00000 0.00000", "OFFSET 0 0 0").replace(
        "OFFSET 0.58653 -0.00000 0.00000", "OFFSET 0 0 0")
    (tmp_path / "flat_hand.bvh").write_text(flat)
    with pytest.raises(ValueError, match=r"flat_hand\.bvh: bone LeftHand -> LeftFingerBase for SMPL left_wrist has "
                                         r"zero length at rest and no joint below LeftFingerBase lies away"):
        read_bvh(tmp_path / "flat_hand.bvh")
