"""BVH motion-capture files -> `Motion` on SMPL's 24 joints, retargeted across rest-pose differences.

Reading (`parse_bvh`): a BVH file is a joint tree (``OFFSET`` from the parent in file units, a list of
``CHANNELS``) and one line of channel values per frame.  A joint's rotation channels, in the order
listed, compose intrinsically (``Zrotation Xrotation Yrotation`` is ``Rz Rx Ry``, degrees); its position
channels, where present, replace the matching components of its offset (usually only the root has them).
The rest pose is every rotation zero: all joint frames are then aligned with the file's axes.  Each
``End Site`` is kept as an extra leaf joint named ``<parent>_End`` without channels, so a leaf bone has an
end point that forward kinematics places and a retargeting map can name.

Retargeting (`retarget_to_smpl`): every SMPL joint that drives a bone (hip -> knee, spine3 -> neck,
wrist -> hand, ...) is mapped to a source joint and the source joint at the far end of the same bone
(`CMU_TO_SMPL`).  In the project's frame (axes converted once by ``C``), with ``d_tgt`` the body's rest
bone, ``d_src`` the source bone from forward kinematics and ``G_src`` the source joint's world rotation:

    A     = align(d_tgt, d_src at rest)                 rest alignment: T-pose bone -> source rest bone
    G_tgt = align(G_src A d_tgt, d_src) G_src A          world rotation of the SMPL joint

so the bone points exactly along the source's (intermediate source joints such as CMU's Neck1 are
covered by the correction, which is the identity when the far joint is a direct child) and its twist
follows the source joint.

Which map (`resolve_mapping`): without one, the first of `SKELETON_MAPS` whose joints the file all has
(CMU's cgspeed "MotionBuilder-friendly" skeleton, or the Daz/Poser skeleton of cgspeed's
"Daz-friendly" CMU release).  Converters often stack joints at one place (cgspeed puts FingerBase,
the thumb, the hip joints, the neck base and the shoulders on their parent, offset 0 0 0), so a far
joint that lies (nearly) on its source joint at rest is replaced by the first joint below it, breadth
first through its children and End Sites, that lies away from the source joint: every map's far joint
can name the anatomical joint, whatever the converter did.  Only a bone with no such joint is refused.  The pelvis does the same with the hip line (right hip -> left hip) as its
bone and the mapped root as its source joint: its left-right axis runs through the source's hip joints
whichever way the source's rest pose faces, and its tilt about that axis follows the source root.

An SMPL joint mapped without a far joint (feet, head, hands, and spine3 for CMU, whose neck base
coincides with Spine1) keeps the source's rotation relative to the source joint of its nearest mapped
ancestor, expressed through that ancestor's rest alignment (for a wrist turned down at rest, a hand
bent the same way); an SMPL joint left out of the map turns with its parent.  Local poses are then
``G_tgt(parent)^T G_tgt``.

The pelvis (`Motion.trans`) follows the mapped root's path scaled by the ratio of the body's leg length
(hip to ankle) to the source's, or by `scale` (metres per file unit), and shifted vertically so that the
body, posed as the source's rest pose, has its ankles where the scaled source has them: feet that touch
the source's floor touch the same floor.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from assets.body.default import default_body
from assets.body.model import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModel
from assets.motion.motion import MAX_FRAMES, Motion, check_finite, check_fps, check_frames
from assets.rotations import Y_UP_TO_Z_UP, align_vectors, matrix_to_rotvec

#: The most joints (End Sites included) a BVH skeleton may have; CMU's has 38.
MAX_BVH_JOINTS = 500
CHANNEL_NAMES = tuple(f"{axis}{kind}" for kind in ("position", "rotation") for axis in "XYZ")

#: SMPL joint -> (source joint, source joint at the far end of the SMPL joint's bone, or None), for the
#: CMU motion-capture skeleton as cgspeed's "MotionBuilder-friendly" BVH conversion names it (Y up,
#: facing +Z, T-pose at rest).  CMU's Neck and shoulders start at Spine1, so SMPL's upper-chest bone
#: (spine3 -> neck) has no source bone and takes Spine1's rotation.  The wrist's bone ends at
#: FingerBase, which that conversion puts on the hand joint (offset 0 0 0): `resolve_mapping` walks on
#: to HandIndex1 (the knuckles).
CMU_TO_SMPL: dict[str, tuple[str, str | None]] = {
    "pelvis": ("Hips", None),
    "left_hip": ("LeftUpLeg", "LeftLeg"),
    "right_hip": ("RightUpLeg", "RightLeg"),
    "spine1": ("LowerBack", "Spine"),
    "left_knee": ("LeftLeg", "LeftFoot"),
    "right_knee": ("RightLeg", "RightFoot"),
    "spine2": ("Spine", "Spine1"),
    "left_ankle": ("LeftFoot", "LeftToeBase"),
    "right_ankle": ("RightFoot", "RightToeBase"),
    "spine3": ("Spine1", None),
    "left_foot": ("LeftToeBase", None),
    "right_foot": ("RightToeBase", None),
    "neck": ("Neck", "Head"),
    "left_collar": ("LeftShoulder", "LeftArm"),
    "right_collar": ("RightShoulder", "RightArm"),
    "head": ("Head", None),
    "left_shoulder": ("LeftArm", "LeftForeArm"),
    "right_shoulder": ("RightArm", "RightForeArm"),
    "left_elbow": ("LeftForeArm", "LeftHand"),
    "right_elbow": ("RightForeArm", "RightHand"),
    "left_wrist": ("LeftHand", "LeftFingerBase"),
    "right_wrist": ("RightHand", "RightFingerBase"),
    "left_hand": ("LeftFingerBase", None),
    "right_hand": ("RightFingerBase", None),
}

#: The same for the Daz/Poser figure of cgspeed's "Daz-friendly" release of the CMU database (hip,
#: abdomen, chest, lCollar, lShldr, lThigh, lShin, lFoot, ...; Y up, facing +Z, arms out at rest).  It
#: has one chest bone for SMPL's spine2 and spine3 (spine3 turns with spine2), no toes (the ankle's
#: bone ends at the foot's End Site) and fingers instead of a hand joint (the wrist's bone ends at the
#: middle finger's base).
DAZ_TO_SMPL: dict[str, tuple[str, str | None]] = {
    "pelvis": ("hip", None),
    "left_hip": ("lThigh", "lShin"),
    "right_hip": ("rThigh", "rShin"),
    "spine1": ("abdomen", "chest"),
    "left_knee": ("lShin", "lFoot"),
    "right_knee": ("rShin", "rFoot"),
    "spine2": ("chest", "neck"),
    "left_ankle": ("lFoot", "lFoot_End"),
    "right_ankle": ("rFoot", "rFoot_End"),
    "neck": ("neck", "head"),
    "left_collar": ("lCollar", "lShldr"),
    "right_collar": ("rCollar", "rShldr"),
    "head": ("head", None),
    "left_shoulder": ("lShldr", "lForeArm"),
    "right_shoulder": ("rShldr", "rForeArm"),
    "left_elbow": ("lForeArm", "lHand"),
    "right_elbow": ("rForeArm", "rHand"),
    "left_wrist": ("lHand", "lMid1"),
    "right_wrist": ("rHand", "rMid1"),
}
#: Skeletons recognised by their joint names, tried in this order when no map is given.
SKELETON_MAPS: dict[str, dict[str, tuple[str, str | None]]] = {"cmu": CMU_TO_SMPL, "daz": DAZ_TO_SMPL}
#: A far joint closer than this fraction of the rest skeleton's size to its source joint is walked past.
MIN_BONE_FRACTION = 1e-3

_INDEX = {name: k for k, name in enumerate(SMPL_JOINT_NAMES)}
#: SMPL joint -> the joint at the far end of its bone: its only child; spine3's is the neck (its other
#: children are the collars).  The pelvis's bone is the hip line, handled apart.
_BONE_END = {p: c for c, p in enumerate(SMPL_PARENTS) if p > 0 and SMPL_PARENTS.count(p) == 1}
_BONE_END[_INDEX["spine3"]] = _INDEX["neck"]
#: Joints every map must name: the pelvis, and the hips and ankles that set its frame and the scale.
_REQUIRED = ("pelvis", "left_hip", "right_hip", "left_ankle", "right_ankle")
_FINGER_BASES = ("index1", "middle1", "ring1", "pinky1")


@dataclass(frozen=True, eq=False)
class BvhData:
    """A parsed BVH file, in the file's frame and units.

    ``names`` (J,) joints in file order with End Sites as ``<parent>_End``; ``parents (J,)`` (parent
    before child, root -1); ``offsets (J, 3)`` from the parent at rest; ``channels`` per joint (names
    from `CHANNEL_NAMES`, file order); ``frame_time`` seconds; ``translations (T, J, 3)`` each joint's
    position in its parent's frame per frame (the offset, or its position channels);
    ``rotations (T, J, 3, 3)`` each joint's rotation relative to its parent."""

    path: str
    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    translations: np.ndarray
    rotations: np.ndarray

    @property
    def root_positions(self) -> np.ndarray:
        """(T, 3) the root joint's position per frame, file units."""
        return self.translations[:, 0]

    def rest_positions(self) -> np.ndarray:
        """(J, 3) joint positions in the rest pose (every rotation zero, offsets only), file units."""
        rest = np.array(self.offsets, dtype=np.float64)
        for j, parent in enumerate(self.parents):
            if parent >= 0:
                rest[j] += rest[parent]
        return rest

    def forward_kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """World joint positions (T, J, 3) and world rotations (T, J, 3, 3), file frame and units."""
        world_r = np.empty_like(self.rotations)
        world_p = np.empty_like(self.translations)
        for j, parent in enumerate(self.parents):  # over joints, vectorised over frames
            if parent < 0:
                world_r[:, j] = self.rotations[:, j]
                world_p[:, j] = self.translations[:, j]
            else:
                world_r[:, j] = world_r[:, parent] @ self.rotations[:, j]
                offset = np.einsum("tab,tb->ta", world_r[:, parent], self.translations[:, j])
                world_p[:, j] = world_p[:, parent] + offset
        return world_p, world_r


class _Hierarchy:
    """Recursive-descent reader of the HIERARCHY section; errors name the file and line."""

    def __init__(self, path: Path, lines: list[str]):
        self.path = path
        self.tokens = [(token, n) for n, line in enumerate(lines, 1) for token in line.split()]
        self.pos = 0
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float] | None] = []
        self.channels: list[tuple[str, ...]] = []

    def error(self, line: int, message: str) -> ValueError:
        return ValueError(f"{self.path}: line {line}: {message}")

    def next(self, expected: str) -> tuple[str, int]:
        if self.pos == len(self.tokens):
            last = self.tokens[-1][1] if self.tokens else 1
            raise self.error(last, f"the hierarchy ends where {expected} was expected")
        self.pos += 1
        return self.tokens[self.pos - 1]

    def expect(self, keyword: str) -> None:
        token, line = self.next(repr(keyword))
        if token != keyword:
            raise self.error(line, f"expected {keyword!r}, got {token!r}")

    def number(self) -> float:
        token, line = self.next("a number")
        try:
            return float(token)
        except ValueError:
            raise self.error(line, f"expected a number, got {token!r}") from None

    def parse(self) -> None:
        self.expect("HIERARCHY")
        self.expect("ROOT")
        self.joint(*self.next("the root joint's name"), parent=-1)
        if self.pos < len(self.tokens):
            token, line = self.tokens[self.pos]
            raise self.error(line, "only one ROOT is supported" if token == "ROOT" else f"unexpected {token!r} after the root")

    def joint(self, name: str, line: int, parent: int, end_site: bool = False) -> None:
        if name in self.names:
            raise self.error(line, f"joint name {name!r} used twice")
        if len(self.names) == MAX_BVH_JOINTS:  # also bounds the recursion depth
            raise self.error(line, f"more than {MAX_BVH_JOINTS} joints and end sites")
        index = len(self.names)
        self.names.append(name)
        self.parents.append(parent)
        self.offsets.append(None)
        self.channels.append(())
        self.expect("{")
        while True:
            token, at = self.next("'}'")
            if token == "}":
                break
            if token == "OFFSET":
                self.offsets[index] = [self.number() for _ in range(3)]
            elif token == "CHANNELS" and not end_site:
                self.channels[index] = self.channel_list(at)
            elif token == "JOINT" and not end_site:
                self.joint(*self.next("a joint name"), parent=index)
            elif token == "End" and not end_site:
                self.expect("Site")
                self.joint(f"{name}_End", at, parent=index, end_site=True)
            else:
                raise self.error(at, f"unknown or misplaced keyword {token!r} in joint {name!r}")
        if self.offsets[index] is None:
            raise self.error(line, f"joint {name!r} has no OFFSET")

    def channel_list(self, line: int) -> tuple[str, ...]:
        count = self.number()
        if not (count.is_integer() and 0 <= count <= 6):
            raise self.error(line, f"CHANNELS count must be 0 to 6, got {count:g}")
        names = []
        for _ in range(int(count)):
            token, at = self.next("a channel name")
            if token not in CHANNEL_NAMES or token in names:
                expected = ", ".join(CHANNEL_NAMES)
                raise self.error(at, f"unknown or repeated channel {token!r} (expected one of {expected})")
            names.append(token)
        return tuple(names)


def _header_value(path: Path, lines: list[str], index: int, pattern: str, what: str, kind: type) -> float:
    """The number matched in line `index` (0-based) by `pattern` as `kind`, or a ValueError naming the line."""
    match = re.fullmatch(pattern, lines[index].strip()) if index < len(lines) else None
    try:
        return kind(match.group(1))
    except (AttributeError, ValueError):
        raise ValueError(f"{path}: line {index + 1}: expected {what!r}") from None


def parse_bvh(path: str | os.PathLike, max_frames: int = MAX_FRAMES) -> BvhData:
    """Read a BVH file (see the module docstring); ValueError naming the file and line on bad input,
    or when it declares more than `max_frames` frames or a frame rate outside `check_fps`'s range."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such BVH file")
    lines = path.read_text(encoding="latin-1").splitlines()
    motion_at = next((i for i, line in enumerate(lines) if line.split()[:1] == ["MOTION"]), None)
    if motion_at is None:
        raise ValueError(f"{path}: no MOTION section")
    hierarchy = _Hierarchy(path, lines[:motion_at])
    hierarchy.parse()

    frames = _header_value(path, lines, motion_at + 1, r"Frames:\s*(\S+)", "Frames: <count>", int)
    frame_time = _header_value(path, lines, motion_at + 2, r"Frame\s+Time:\s*(\S+)", "Frame Time: <seconds>", float)
    if not (frames > 0 and frame_time > 0):
        raise ValueError(f"{path}: needs a positive Frames count and Frame Time, got {frames} and {frame_time:g}")
    check_frames(frames, f"{path}: Frames", max_frames)
    check_fps(1.0 / frame_time, f"{path}: Frame Time {frame_time:g} s")
    width = sum(len(c) for c in hierarchy.channels)
    rows = [(n, line.split()) for n, line in enumerate(lines[motion_at + 3 :], motion_at + 4) if line.strip()]
    bad = next(((n, len(row)) for n, row in rows if len(row) != width), None)
    if bad is not None:
        raise ValueError(f"{path}: line {bad[0]}: {bad[1]} values, expected {width} (one per channel)")
    if len(rows) != frames:
        raise ValueError(f"{path}: 'Frames: {frames}' but {len(rows)} frame lines follow")
    try:
        values = np.array([row for _, row in rows], dtype=np.float64).reshape(frames, width)
    except ValueError as exc:
        raise ValueError(f"{path}: motion data: {exc}") from None

    offsets = np.array(hierarchy.offsets, dtype=np.float64)
    check_finite({"OFFSET": offsets, "motion data": values}, str(path))
    translations = np.repeat(offsets[None], frames, axis=0)
    rotations = np.repeat(np.eye(3)[None, None], frames, axis=0).repeat(len(offsets), axis=1)
    column = 0
    for j, channels in enumerate(hierarchy.channels):
        spin = [(c[0], column + i) for i, c in enumerate(channels) if c.endswith("rotation")]
        for i, c in enumerate(channels):
            if c.endswith("position"):
                translations[:, j, "XYZ".index(c[0])] = values[:, column + i]
        if spin:
            axes = "".join(axis for axis, _ in spin)  # uppercase: intrinsic, in the order listed
            rotations[:, j] = Rotation.from_euler(axes, values[:, [i for _, i in spin]], degrees=True).as_matrix()
        column += len(channels)
    return BvhData(
        path=str(path),
        names=tuple(hierarchy.names),
        parents=np.array(hierarchy.parents, dtype=np.int64),
        offsets=offsets,
        channels=tuple(hierarchy.channels),
        frame_time=frame_time,
        translations=translations,
        rotations=rotations,
    )


def _smpl_rest_joints(body: BodyModel) -> np.ndarray:
    """(24, 3) rest positions of SMPL's joints on `body`, metres.  SMPL+H and SMPL-X have finger joints
    instead of a hand joint: theirs is placed at the mean of the four finger bases (the knuckles)."""
    rest = body.rest()[1]
    index = {name: j for j, name in enumerate(body.joint_names)}
    out = np.empty((NUM_SMPL_JOINTS, 3))
    for k, name in enumerate(SMPL_JOINT_NAMES):
        fingers = [f"{name.split('_')[0]}_{finger}" for finger in _FINGER_BASES]
        if name in index:
            out[k] = rest[index[name]]
        elif all(f in index for f in fingers):
            out[k] = rest[[index[f] for f in fingers]].mean(axis=0)
        else:
            raise ValueError(f"body model {body.name!r} has no {name} joint to retarget onto")
    return out


def _check_map(mapping: Mapping[str, tuple[str, str | None]]) -> None:
    unknown = sorted(set(mapping) - set(SMPL_JOINT_NAMES))
    absent = [name for name in _REQUIRED if name not in mapping]
    no_bone = [name for name, (_, far) in mapping.items() if far is not None and _INDEX.get(name) not in _BONE_END]
    problems = [f"unknown SMPL joints {unknown}"] if unknown else []
    problems += [f"must map {absent}"] if absent else []
    problems += [f"{no_bone} have no SMPL bone, so their far joint must be None"] if no_bone else []
    if problems:
        raise ValueError(f"retargeting map: {'; '.join(problems)}")


def _map_joints(mapping: Mapping[str, tuple[str, str | None]]) -> set[str]:
    return {joint for pair in mapping.values() for joint in pair if joint is not None}


def _known_map(bvh: BvhData) -> Mapping[str, tuple[str, str | None]]:
    """The first of `SKELETON_MAPS` whose joints `bvh` all has; a ValueError names the nearest one's
    missing joints."""
    lacking = {name: sorted(_map_joints(m) - set(bvh.names)) for name, m in SKELETON_MAPS.items()}
    for name, missing in lacking.items():
        if not missing:
            return SKELETON_MAPS[name]
    nearest = min(lacking, key=lambda name: len(lacking[name]))
    raise ValueError(
        f"{bvh.path}: the skeleton lacks joint(s) {', '.join(lacking[nearest])} of the SMPL retargeting map "
        f"'{nearest}', the nearest of the known skeletons ({', '.join(SKELETON_MAPS)}; it has "
        f"{', '.join(bvh.names)}); pass a mapping for this skeleton"
    )


def resolve_mapping(
    bvh: BvhData, mapping: Mapping[str, tuple[str, str | None]] | None = None
) -> dict[str, tuple[str, str | None]]:
    """The map retargeting uses on `bvh`: `mapping`, or the first known skeleton's (`SKELETON_MAPS`)
    when None, with every far joint that lies on its source joint at rest (closer than
    `MIN_BONE_FRACTION` of the skeleton's size) replaced by the first joint below it, breadth first,
    that does not.  ValueError naming the file for a joint the skeleton lacks, or a bone with nothing
    usable below its far joint."""
    mapping = _known_map(bvh) if mapping is None else mapping
    _check_map(mapping)
    index = {name: j for j, name in enumerate(bvh.names)}
    missing = sorted(_map_joints(mapping) - set(index))
    if missing:
        raise ValueError(
            f"{bvh.path}: the skeleton lacks joint(s) {', '.join(missing)} of the SMPL retargeting map "
            f"(it has {', '.join(bvh.names)}); pass a mapping for this skeleton"
        )
    rest = bvh.rest_positions()
    tolerance = MIN_BONE_FRACTION * float(np.ptp(rest, axis=0).max())
    children: list[list[int]] = [[] for _ in bvh.names]
    for j, parent in enumerate(bvh.parents):
        if parent >= 0:
            children[parent].append(j)
    resolved = {}
    for name, (src, far) in mapping.items():
        if far is not None:
            queue = [index[far]]
            while queue and np.linalg.norm(rest[queue[0]] - rest[index[src]]) <= tolerance:
                queue = queue[1:] + children[queue[0]]
            if not queue:
                raise ValueError(
                    f"{bvh.path}: bone {src} -> {far} for SMPL {name} has zero length at rest and no joint below "
                    f"{far} lies away from {src}; map another far joint for {name}, or None"
                )
            far = bvh.names[queue[0]]
        resolved[name] = (src, far)
    return resolved


def _resolve(bvh: BvhData, mapping: Mapping[str, tuple[str, str | None]] | None) -> dict[int, tuple[int, int]]:
    """SMPL joint index -> (source joint index, far source joint index or -1), from `resolve_mapping`."""
    index = {name: j for j, name in enumerate(bvh.names)}
    return {
        _INDEX[name]: (index[src], -1 if far is None else index[far])
        for name, (src, far) in resolve_mapping(bvh, mapping).items()
    }


def _up_axis_conversion(up: str) -> np.ndarray:
    if up == "y":
        return Y_UP_TO_Z_UP
    if up == "z":
        return np.eye(3)
    raise ValueError(f"up must be 'y' or 'z', got {up!r}")


def _world_rotations(
    bvh: BvhData,
    joints: dict[int, tuple[int, int]],
    positions: np.ndarray,
    rotations: np.ndarray,
    source_rest: np.ndarray,
    target_rest: np.ndarray,
) -> np.ndarray:
    """World rotations (T, 24, 3, 3) of the SMPL joints (module docstring) from the source's world
    positions (T, J, 3) and rotations (T, J, 3, 3) and both rest skeletons, all in the project's axes."""
    world = np.empty((len(positions), NUM_SMPL_JOINTS, 3, 3))
    align = np.empty((NUM_SMPL_JOINTS, 3, 3))
    tracked = np.empty(NUM_SMPL_JOINTS, dtype=np.int64)  # source joint whose rotation each frame follows
    hips = (_INDEX["right_hip"], _INDEX["left_hip"])
    for k in range(NUM_SMPL_JOINTS):
        parent = SMPL_PARENTS[k]
        if k not in joints:
            world[:, k], align[k], tracked[k] = world[:, parent], align[parent], tracked[parent]
            continue
        src, far = joints[k]
        tracked[k] = src
        if k == 0 or far >= 0:
            tgt_ends = hips if k == 0 else (k, _BONE_END[k])
            src_ends = (joints[hips[0]][0], joints[hips[1]][0]) if k == 0 else (src, far)
            d_tgt = target_rest[tgt_ends[1]] - target_rest[tgt_ends[0]]
            d_rest = source_rest[src_ends[1]] - source_rest[src_ends[0]]
            if np.linalg.norm(d_rest) < 1e-9 or np.linalg.norm(d_tgt) < 1e-9:
                raise ValueError(
                    f"{bvh.path}: bone {bvh.names[src_ends[0]]} -> {bvh.names[src_ends[1]]} for SMPL "
                    f"{SMPL_JOINT_NAMES[k]} has zero length at rest; map a joint further along"
                )
            align[k] = align_vectors(d_tgt, d_rest)
            frame = rotations[:, src] @ align[k]
            d_src = positions[:, src_ends[1]] - positions[:, src_ends[0]]
            world[:, k] = align_vectors(frame @ d_tgt, d_src) @ frame
        else:
            relative = np.swapaxes(rotations[:, tracked[parent]], 1, 2) @ rotations[:, src]
            align[k] = align[parent]
            world[:, k] = world[:, parent] @ align[parent].T @ relative @ align[parent]
    return world


def _leg_length(rest: np.ndarray, legs: list[list[int]]) -> float:
    """Mean straight hip-to-ankle distance of rest joints (J, 3) over legs [[hip, ankle], ...]: unlike
    the hip height it does not depend on how far the rest pose spreads the legs."""
    return float(np.linalg.norm(np.diff(rest[legs], axis=1), axis=-1).mean())


def retarget_to_smpl(
    bvh: BvhData,
    body: BodyModel | None = None,
    up: str = "y",
    scale: float | None = None,
    mapping: Mapping[str, tuple[str, str | None]] | None = None,
) -> Motion:
    """Retarget a parsed BVH onto SMPL's 24 joints of `body` (default: the default body); see the module
    docstring for the method.

    `up`: the file's up axis, 'y' (Y up, facing +Z, as CMU) or 'z' (already the project's frame).
    `scale`: metres per file unit for the root path; None: the ratio of the body's leg length (hip to
    ankle) to the source's.
    `mapping`: SMPL joint name -> (source joint, far source joint of the SMPL joint's bone or None);
    None: the known skeleton the file's joint names match (`resolve_mapping`).
    Returns poses (T, 24, 3), trans (T, 3) metres, fps = 1 / frame time."""
    convert = _up_axis_conversion(up)
    body = default_body() if body is None else body
    joints = _resolve(bvh, mapping)
    target_rest = _smpl_rest_joints(body)
    source_rest = bvh.rest_positions() @ convert.T
    positions, rotations = bvh.forward_kinematics()
    # Frame 0 is the source's rest pose: it places the pelvis height below, then is dropped.
    positions = np.concatenate([source_rest[None], positions @ convert.T])
    rest_rotations = np.eye(3)[None, None].repeat(len(source_rest), axis=1)
    rotations = np.concatenate([rest_rotations, convert @ rotations @ convert.T])
    world = _world_rotations(bvh, joints, positions, rotations, source_rest, target_rest)
    local = world.copy()
    local[:, 1:] = np.swapaxes(world[:, np.array(SMPL_PARENTS[1:])], 2, 3) @ world[:, 1:]

    root = joints[0][0]
    src_legs = [[joints[_INDEX[f"{side}_{j}"]][0] for j in ("hip", "ankle")] for side in ("left", "right")]
    tgt_legs = [[_INDEX[f"{side}_{j}"] for j in ("hip", "ankle")] for side in ("left", "right")]
    if np.any(np.diff(source_rest[src_legs, 2], axis=1) >= 0):
        raise ValueError(f"{bvh.path}: the hips are not above the ankles along up={up!r} in the rest pose")
    if scale is None:
        scale = _leg_length(target_rest, tgt_legs) / _leg_length(source_rest, src_legs)
    elif not scale > 0:
        raise ValueError(f"scale must be positive metres per file unit, got {scale}")
    # Pose the body as the source's rest pose (frame 0) and lift the pelvis so that its ankles stand
    # where the scaled source's do.
    placed = target_rest.copy()
    for k in range(1, NUM_SMPL_JOINTS):
        parent = SMPL_PARENTS[k]
        placed[k] = placed[parent] + world[0, parent] @ (target_rest[k] - target_rest[parent])
    ankles = [legs[1] for legs in tgt_legs]
    src_ankles = [legs[1] for legs in src_legs]
    source_height = source_rest[root, 2] - source_rest[src_ankles, 2].mean()
    lift = (placed[0, 2] - placed[ankles, 2].mean()) - scale * source_height
    return Motion(
        poses=matrix_to_rotvec(local[1:]),
        trans=scale * positions[1:, root] + np.array([0.0, 0.0, lift]),
        fps=1.0 / bvh.frame_time,
        name=Path(bvh.path).stem,
        source=bvh.path,
    )


def read_bvh(path: str | os.PathLike, body: BodyModel | None = None, max_frames: int = MAX_FRAMES,
             **options) -> Motion:
    """Parse a BVH file (at most `max_frames` frames) and retarget it onto `body`; `options` go to
    `retarget_to_smpl` (up, scale, mapping).  Known skeletons (`SKELETON_MAPS`, Y up) need no mapping."""
    return retarget_to_smpl(parse_bvh(path, max_frames), body, **options)
