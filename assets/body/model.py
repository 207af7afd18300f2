"""`BodyModel`: one skinned body interface for SMPL-family files and the free default body.

A body is linear blend skinning over a kinematic tree, exactly as SMPL (Loper et al. 2015) defines it:

    v_shaped = template + sum_s c_s(betas) shape_dirs[s]          (V, 3)
    joints   = joint_template + sum_s c_s(betas) joint_shape_dirs[s]  (J, 3)
    v_posed  = v_shaped + sum_k (R_k - I) . pose_dirs[k]            (pose blend shapes, k >= 1)
    v        = sum_j w_vj G_j (v_posed - joints_j)                  (G_j: world transform of joint j)

For SMPL the shape coefficients are the betas themselves and ``joint_*`` is the joint regressor applied
to the template and shape directions (exact, since both are linear).  The default body has no linear
shape space: its betas are a few phenotype values (for example height) and the coefficients are the
multilinear interpolation weights over a grid of corner shapes (``shape_anchors``).

Frames and units: the project's world (Z up, metres, the person facing -Y in the rest pose).  Poses are
axis-angle per joint in that frame, ``(T, J, 3)``.  Unlike SMPL's ``transl`` (added to the rest-frame
pelvis offset), ``trans`` here is the world position of the root joint, so one motion drives bodies of
any shape along the same pelvis path.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from assets.fileio import check_limit, load_npz, npz_headers, save_npz
from assets.rotations import rotvec_to_matrix

SMPL_JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)  # fmt: skip
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
NUM_SMPL_JOINTS = 24
#: SMPL+H and SMPL-X share SMPL's first 22 joints (the body without the two hand joints).
NUM_BODY_JOINTS = 22

#: Default bounds on what a body file may declare, checked before its arrays are decompressed (vertices:
#: ten times SMPL-X's 10,475; faces: four per vertex).
MAX_VERTICES = 100_000
MAX_JOINTS = 200
MAX_SHAPE_DIRS = 1024
_FRAMES_PER_CHUNK = 64  # bounds the (frames, V, 12) skinning buffer to tens of MB


def _hat_weights(value: float, anchors: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation weights (len(anchors),) of `value` over sorted `anchors`."""
    weights = np.zeros(len(anchors))
    if len(anchors) == 1:
        weights[0] = 1.0
        return weights
    i = int(np.clip(np.searchsorted(anchors, value) - 1, 0, len(anchors) - 2))
    frac = (value - anchors[i]) / (anchors[i + 1] - anchors[i])
    weights[i], weights[i + 1] = 1.0 - frac, frac
    return weights


@dataclass(frozen=True)
class PosedBody:
    """A body posed over T frames: vertices (T, V, 3) float32 and joints (T, J, 3) float64, world metres."""

    vertices: np.ndarray
    joints: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True, eq=False)
class BodyModel:
    """Arrays of a skinned body (see the module docstring for the formula and frames).

    Shapes: ``faces (F, 3) int32``, ``parents (J,)`` (parent before child, root -1), ``weights (V, J)``
    rows summing to 1, ``template (V, 3)``, ``shape_dirs (S, V, 3)``, ``joint_template (J, 3)``,
    ``joint_shape_dirs (S, J, 3)``, ``pose_dirs ((J - 1) * 9, V, 3)`` or None, ``default_betas (B,)``.
    ``shape_anchors`` is None for a linear shape space (S == B) or one anchor array per beta
    (S == product of their lengths) for a multilinear grid of corner shapes.
    """

    name: str
    shape_space: str
    faces: np.ndarray
    parents: np.ndarray
    joint_names: tuple[str, ...]
    weights: np.ndarray
    template: np.ndarray
    shape_dirs: np.ndarray
    joint_template: np.ndarray
    joint_shape_dirs: np.ndarray
    pose_dirs: np.ndarray | None
    shape_names: tuple[str, ...]
    default_betas: np.ndarray
    shape_anchors: tuple[np.ndarray, ...] | None = None
    gender: str = "neutral"

    def __post_init__(self):
        v, j, s = len(self.template), len(self.parents), len(self.shape_dirs)
        expect = {
            "faces": (self.faces, (None, 3)),
            "weights": (self.weights, (v, j)),
            "template": (self.template, (v, 3)),
            "shape_dirs": (self.shape_dirs, (s, v, 3)),
            "joint_template": (self.joint_template, (j, 3)),
            "joint_shape_dirs": (self.joint_shape_dirs, (s, j, 3)),
            "default_betas": (self.default_betas, (len(self.shape_names),)),
        }
        if self.pose_dirs is not None:
            expect["pose_dirs"] = (self.pose_dirs, ((j - 1) * 9, v, 3))
        for field, (array, shape) in expect.items():
            got = np.shape(array)
            if len(got) != len(shape) or any(e is not None and e != g for e, g in zip(shape, got)):
                raise ValueError(f"body model {self.name!r}: {field} has shape {got}, expected {shape}")
        if len(self.joint_names) != j:
            raise ValueError(f"body model {self.name!r}: {len(self.joint_names)} joint names for {j} joints")
        parents = np.asarray(self.parents)
        if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, j)):
            raise ValueError(f"body model {self.name!r}: parents must list each joint after its parent, root -1")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= v):
            raise ValueError(f"body model {self.name!r}: faces index outside the {v} vertices")
        if self.shape_anchors is None:
            if s != len(self.shape_names):
                raise ValueError(f"body model {self.name!r}: {s} shape directions for {len(self.shape_names)} betas")
        elif int(np.prod([len(a) for a in self.shape_anchors])) != s or len(self.shape_anchors) != len(self.shape_names):
            raise ValueError(f"body model {self.name!r}: shape grid does not match its {s} corner shapes")

    @property
    def num_vertices(self) -> int:
        return len(self.template)

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def num_betas(self) -> int:
        return len(self.shape_names)

    # -- shape ---------------------------------------------------------------------------------------

    def shape_coefficients(self, betas: np.ndarray | None = None) -> np.ndarray:
        """Betas (B,) -> coefficients (S,) of the shape directions; None means the default shape.

        A linear space takes the first B betas given (missing ones are 0, as SMPL does); a grid needs
        every beta inside its anchors' range."""
        betas = self.default_betas if betas is None else np.asarray(betas, dtype=np.float64).ravel()
        if not np.isfinite(betas).all():
            raise ValueError(f"body model {self.name!r}: betas must be finite numbers, got {betas}")
        if self.shape_anchors is None:
            coef = np.zeros(self.num_betas)
            n = min(len(betas), self.num_betas)
            coef[:n] = betas[:n]
            return coef
        if len(betas) != self.num_betas:
            raise ValueError(
                f"body model {self.name!r} takes {self.num_betas} shape values ({', '.join(self.shape_names)}), got {len(betas)}"
            )
        coef = np.ones(1)
        for name, value, anchors in zip(self.shape_names, betas, self.shape_anchors):
            if not anchors[0] - 1e-9 <= value <= anchors[-1] + 1e-9:
                raise ValueError(f"body model {self.name!r}: {name}={value:g} is outside [{anchors[0]:g}, {anchors[-1]:g}]")
            coef = np.outer(coef, _hat_weights(value, anchors)).ravel()
        return coef

    def rest(self, betas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Rest-pose vertices (V, 3) and joints (J, 3) for shape `betas` (None: the default shape)."""
        coef = self.shape_coefficients(betas)
        vertices = self.template + np.tensordot(coef, self.shape_dirs, axes=1)
        joints = self.joint_template + np.tensordot(coef, self.joint_shape_dirs, axes=1)
        return vertices, joints

    # -- pose ----------------------------------------------------------------------------------------

    def joint_transforms(
        self, poses: np.ndarray, trans: np.ndarray | None, joints: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (T, J, 3, 3) and joint positions (T, J, 3) of every joint.

        ``poses (T, J, 3)`` axis-angle; ``trans (T, 3)`` root joint positions (None: where it rests);
        ``joints`` rest joint positions, (J, 3) or one skeleton per frame (T, J, 3)."""
        rotations = rotvec_to_matrix(poses)
        joints = np.broadcast_to(joints, poses.shape[:2] + (3,))
        world_r = np.empty_like(rotations)
        world_t = np.empty(poses.shape[:2] + (3,))
        for j, parent in enumerate(self.parents):  # over joints (tens), vectorised over frames
            if parent < 0:
                world_r[:, j] = rotations[:, j]
                world_t[:, j] = joints[:, j] if trans is None else trans
            else:
                world_r[:, j] = world_r[:, parent] @ rotations[:, j]
                bone = joints[:, j] - joints[:, parent]
                world_t[:, j] = world_t[:, parent] + np.einsum("tab,tb->ta", world_r[:, parent], bone)
        return world_r, world_t

    def pose(self, poses: np.ndarray, trans: np.ndarray | None = None, betas: np.ndarray | None = None) -> PosedBody:
        """Pose the body for T frames at once.

        poses: (T, J, 3) axis-angle radians (or (J, 3) for one frame); trans: (T, 3) world position of
        the root joint in metres (None: the root stays at its rest position); betas: (B,) shape, None
        for the default.  Returns vertices (T, V, 3) float32 and joints (T, J, 3)."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim == 2:
            poses = poses[None]
        if poses.ndim != 3 or poses.shape[1:] != (self.num_joints, 3):
            raise ValueError(f"body model {self.name!r}: poses must be (T, {self.num_joints}, 3), got {poses.shape}")
        frames = len(poses)
        if trans is not None:
            trans = np.broadcast_to(np.asarray(trans, dtype=np.float64).reshape(-1, 3), (frames, 3))
        v_shaped, joints = self.rest(betas)
        world_r, world_t = self.joint_transforms(poses, trans, joints)
        # Skinning transform of joint j: x -> R_j x + (t_j - R_j J_j), flattened to 12 numbers.
        offsets = world_t - np.einsum("tjab,jb->tja", world_r, joints)
        blend = np.concatenate([world_r.reshape(frames, -1, 9), offsets], axis=2).astype(np.float32)
        weights = self.weights.astype(np.float32)
        v_shaped32 = v_shaped.astype(np.float32)
        out = np.empty((frames, self.num_vertices, 3), dtype=np.float32)
        eye = np.eye(3)
        for start in range(0, frames, _FRAMES_PER_CHUNK):
            stop = min(start + _FRAMES_PER_CHUNK, frames)
            n = stop - start
            per_vertex = (weights @ blend[start:stop].transpose(1, 0, 2).reshape(self.num_joints, n * 12))
            per_vertex = per_vertex.reshape(-1, n, 12).transpose(1, 0, 2)  # (n, V, 12)
            v = np.broadcast_to(v_shaped32, (n,) + v_shaped32.shape)
            if self.pose_dirs is not None:
                feature = (rotvec_to_matrix(poses[start:stop, 1:]) - eye).reshape(n, -1).astype(np.float32)
                v = v + (feature @ self.pose_dirs.reshape(len(self.pose_dirs), -1)).reshape(n, -1, 3)
            r = per_vertex[..., :9]
            for axis in range(3):
                out[start:stop, :, axis] = (
                    r[..., 3 * axis] * v[..., 0] + r[..., 3 * axis + 1] * v[..., 1] + r[..., 3 * axis + 2] * v[..., 2]
                    + per_vertex[..., 9 + axis]
                )
        return PosedBody(vertices=out, joints=world_t, faces=self.faces)

    def zero_pose(self, frames: int = 1) -> np.ndarray:
        """Poses (frames, J, 3) of the rest pose."""
        return np.zeros((frames, self.num_joints, 3))

    # -- files ---------------------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> None:
        """Write the model as one `.npz` (float32 geometry, metadata as JSON)."""
        meta = {
            "name": self.name,
            "shape_space": self.shape_space,
            "joint_names": list(self.joint_names),
            "shape_names": list(self.shape_names),
            "gender": self.gender,
            "shape_anchors": None if self.shape_anchors is None else [list(map(float, a)) for a in self.shape_anchors],
        }
        arrays = {
            "meta": np.array(json.dumps(meta)),
            "faces": self.faces.astype(np.int32),
            "parents": self.parents.astype(np.int32),
            "weights": self.weights.astype(np.float32),
            "template": self.template.astype(np.float32),
            "shape_dirs": self.shape_dirs.astype(np.float32),
            "joint_template": self.joint_template.astype(np.float32),
            "joint_shape_dirs": self.joint_shape_dirs.astype(np.float32),
            "default_betas": self.default_betas.astype(np.float64),
        }
        if self.pose_dirs is not None:
            arrays["pose_dirs"] = self.pose_dirs.astype(np.float32)
        save_npz(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike, max_vertices: int = MAX_VERTICES) -> "BodyModel":
        """Read a model written by `save`; errors name the file.  The arrays' shapes are checked from
        the file's headers (at most `max_vertices` vertices) before anything is decompressed."""
        path = Path(path)
        _check_saved_shapes(npz_headers(path), path, max_vertices)
        arrays = load_npz(path, required=("meta", "faces", "parents", "weights", "template", "shape_dirs",
                                          "joint_template", "joint_shape_dirs", "default_betas"))
        try:
            meta = json.loads(str(arrays["meta"]))
            anchors = meta["shape_anchors"]
            return cls(
                name=meta["name"],
                shape_space=meta["shape_space"],
                faces=arrays["faces"].astype(np.int64),
                parents=arrays["parents"].astype(np.int64),
                joint_names=tuple(meta["joint_names"]),
                weights=arrays["weights"].astype(np.float64),
                template=arrays["template"].astype(np.float64),
                shape_dirs=arrays["shape_dirs"].astype(np.float64),
                joint_template=arrays["joint_template"].astype(np.float64),
                joint_shape_dirs=arrays["joint_shape_dirs"].astype(np.float64),
                pose_dirs=arrays["pose_dirs"].astype(np.float32) if "pose_dirs" in arrays else None,
                shape_names=tuple(meta["shape_names"]),
                default_betas=arrays["default_betas"],
                shape_anchors=None if anchors is None else tuple(np.asarray(a, dtype=np.float64) for a in anchors),
                gender=meta.get("gender", "neutral"),
            )
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: not a body model file ({exc!r})") from exc
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc

    def replace(self, **changes) -> "BodyModel":
        return dataclasses.replace(self, **changes)


def _check_saved_shapes(headers: dict[str, tuple[tuple[int, ...], np.dtype]], path: Path, max_vertices: int) -> None:
    """Refuse the shapes of a saved model's arrays (.npy headers) unless they fit together and stay within
    the vertex, joint and shape-direction bounds; missing arrays are `load_npz`'s to report."""
    shapes = {k: shape for k, (shape, _) in headers.items()}
    if not all(len(shapes.get(k, (0,) * n)) == n for k, n in (("template", 2), ("parents", 1), ("shape_dirs", 3))):
        raise ValueError(f"{path}: template, parents and shape_dirs must be 2-, 1- and 3-D arrays")
    v = shapes.get("template", (0,))[0]
    j = shapes.get("parents", (0,))[0]
    s = shapes.get("shape_dirs", (0,))[0]
    check_limit(v, max_vertices, "the vertex count (template)", str(path), "max_vertices")
    check_limit(j, MAX_JOINTS, "the joint count (parents)", str(path), f"MAX_JOINTS ({__name__})")
    check_limit(s, MAX_SHAPE_DIRS, "the shape direction count (shape_dirs)", str(path), f"MAX_SHAPE_DIRS ({__name__})")
    expect = {"faces": (None, 3), "weights": (v, j), "shape_dirs": (s, v, 3), "joint_template": (j, 3),
              "joint_shape_dirs": (s, j, 3), "default_betas": (None,), "pose_dirs": ((j - 1) * 9, v, 3), "meta": ()}
    for key, want in expect.items():
        got = shapes.get(key)
        if got is not None and (len(got) != len(want) or any(w is not None and w != g for w, g in zip(want, got))):
            raise ValueError(f"{path}: {key} has shape {got}, expected {tuple('*' if w is None else w for w in want)}")
    check_limit(shapes.get("faces", (0,))[0], 4 * max_vertices, "the face count (faces)", str(path), "max_vertices")
    check_limit(shapes.get("default_betas", (0,))[0], MAX_SHAPE_DIRS, "the beta count (default_betas)", str(path),
                f"MAX_SHAPE_DIRS ({__name__})")
