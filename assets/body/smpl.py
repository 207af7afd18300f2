"""SMPL-family model files (SMPL, SMPL+H, SMPL-X body) that users hold under their own licence.

`load_smpl(path)` reads the published `.npz` or `.pkl` files (keys ``v_template``, ``shapedirs``,
``posedirs``, ``J_regressor``, ``weights``, ``kintree_table``, ``f``) into a `BodyModel` that poses
exactly as the published model defines linear blend skinning (shape blend shapes, pose blend shapes on
``R_k - I`` of every non-root joint, the joint regressor applied to the shaped template), converted
once from the files' Y-up frame to the project's Z-up frame:

- geometry and every blend shape direction are rotated by ``C = Y_UP_TO_Z_UP``;
- a pose in the project's frame is ``R' = C R C^T`` of the file's; the pose blend shapes are re-indexed
  so that ``(R' - I)`` features give the same offsets as the file's ``(R - I)`` features.

Files are untrusted: a `.pkl` is read by `assets.body.safe_pickle` (numeric arrays, scipy sparse
matrices and chumpy arrays as plain data, nothing that runs code or forges numpy's state), and every
array's shape is checked against SMPL's layout and a vertex bound before use (an `.npz`'s from its
headers, before decompression, so a small file cannot ask for gigabytes).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from assets.body.model import MAX_VERTICES, NUM_BODY_JOINTS, SMPL_JOINT_NAMES, BodyModel
from assets.body.safe_pickle import Unreadable, load_pickle, plain
from assets.fileio import check_limit, load_npz, npz_headers
from assets.rotations import Y_UP_TO_Z_UP

_REQUIRED = ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table", "f")
_NDIM = {"v_template": 2, "shapedirs": 3, "posedirs": 3, "J_regressor": 2, "weights": 2, "kintree_table": 2, "f": 2}
_NUMERIC_KINDS = "biuf"
#: The most shape directions an SMPL-family file has (SMPL-X: 300 shape + 100 expression).
_MAX_SHAPE_DIRS = 400
_HAND_JOINTS = tuple(
    f"{side}_{finger}{i}" for side in ("left", "right")
    for finger in ("index", "middle", "pinky", "ring", "thumb") for i in (1, 2, 3)
)  # fmt: skip
#: SMPL-X's shape directions: 300 shape components, then 100 expression components (not used here).
_SMPLX_SHAPE_DIRS = 300


def _is_npz(path: Path) -> bool:
    """An `.npz` by name, or a zip archive by its first bytes."""
    if path.suffix == ".npz":
        return True
    with open(path, "rb") as file:
        return file.read(2) == b"PK"


def read_model_file(path: str | os.PathLike, keys: tuple[str, ...] | None = None) -> dict[str, object]:
    """The arrays of an SMPL-family `.npz` or `.pkl` file, without executing anything in it (`.pkl`:
    `safe_pickle`).  keys: read only these of an `.npz` (the others are never decompressed); a
    `.pkl` is read whole.  Arrays a model never needs (object, string) are skipped in an `.npz` and
    `Unreadable` in a `.pkl`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such body model file")
    if _is_npz(path):
        headers = npz_headers(path)
        wanted = [k for k in headers if (keys is None or k in keys) and headers[k][1].kind in _NUMERIC_KINDS]
        return load_npz(path, only=tuple(wanted))
    data = load_pickle(path.read_bytes(), str(path))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a model pickle holds a dict, found {type(data).__name__}")
    if not all(isinstance(k, str) for k in data):
        raise ValueError(f"{path}: a model pickle's keys must be strings")
    return {k: plain(v, f"{path}: {k}") for k, v in data.items()}


def _check_layout(shapes: dict[str, tuple], path: Path, max_vertices: int) -> None:
    """Refuse array shapes (from .npy headers or loaded arrays) that break SMPL's layout or ask for more
    than `max_vertices` vertices, before anything larger than the file is allocated."""
    for key in _REQUIRED + ("posedirs",):
        if key in shapes and len(shapes[key]) != _NDIM[key]:
            raise ValueError(f"{path}: {key} must be a {_NDIM[key]}-D array, got shape {shapes[key]}")
    verts, joints = shapes["v_template"][0], shapes["kintree_table"][-1]
    check_limit(verts, max_vertices, "the vertex count (v_template)", str(path), "max_vertices")
    check_limit(shapes["f"][0], 4 * max_vertices, "the face count (f)", str(path), "max_vertices")
    _joint_names(joints, path)
    expect = {
        "v_template": (verts, 3),
        "shapedirs": (verts, 3, None),
        "posedirs": (verts, 3, (joints - 1) * 9),
        "J_regressor": (joints, verts),
        "weights": (verts, joints),
        "kintree_table": (2, joints),
        "f": (None, 3),
    }
    for key, want in expect.items():
        got = shapes.get(key)
        if got is not None and any(w is not None and w != g for w, g in zip(want, got)):
            raise ValueError(f"{path}: {key} has shape {tuple(got)}, expected {tuple('*' if w is None else w for w in want)}")
    if shapes["shapedirs"][2] > _MAX_SHAPE_DIRS:
        raise ValueError(f"{path}: shapedirs has {shapes['shapedirs'][2]} directions; SMPL-family files have at most {_MAX_SHAPE_DIRS}")


def _joint_names(count: int, path: Path) -> tuple[str, ...]:
    if count == len(SMPL_JOINT_NAMES):
        return SMPL_JOINT_NAMES
    body = SMPL_JOINT_NAMES[:NUM_BODY_JOINTS]
    if count == NUM_BODY_JOINTS + len(_HAND_JOINTS):
        return body + _HAND_JOINTS
    if count == NUM_BODY_JOINTS + 3 + len(_HAND_JOINTS):
        return body + ("jaw", "left_eye", "right_eye") + _HAND_JOINTS
    raise ValueError(f"{path}: {count} joints; SMPL has 24, SMPL+H 52, SMPL-X 55")


def _array(data: dict, key: str, path: Path) -> np.ndarray:
    """`data[key]` as a finite numeric array (a sparse matrix made dense: its shape is checked)."""
    value = data[key]
    if sp.issparse(value):
        value = value.toarray()
    if not isinstance(value, np.ndarray) or value.dtype.kind not in _NUMERIC_KINDS:
        got = value if isinstance(value, Unreadable) else f"{type(value).__name__} {getattr(value, 'dtype', '')}"
        raise ValueError(f"{path}: {key} must be a numeric array, got {got}")
    if value.dtype.kind in "fc" and not np.isfinite(value).all():
        raise ValueError(f"{path}: {key} holds NaN or infinite values")
    return value


def _describe(value: object) -> object:
    """A loaded value's shape if it is an array of model data, else what it is instead."""
    if sp.issparse(value) or isinstance(value, np.ndarray) and value.dtype.kind in _NUMERIC_KINDS:
        return tuple(value.shape)
    return value.reason if isinstance(value, Unreadable) else f"a {type(value).__name__}"


def _layout(found: dict[str, object], path: Path, max_vertices: int) -> None:
    """Check the arrays `found` (key -> shape tuple, or what the value is instead) against SMPL's layout
    (`_check_layout`)."""
    missing = [k for k in _REQUIRED if k not in found]
    if missing:
        raise ValueError(f"{path}: not an SMPL-family model, missing {', '.join(missing)}")
    for key in _REQUIRED + ("posedirs",):
        if key in found and not isinstance(found[key], tuple):
            raise ValueError(f"{path}: {key} must be a numeric array, got {found[key]}")
    _check_layout({k: v for k, v in found.items() if isinstance(v, tuple)}, path, max_vertices)


def load_smpl(path: str | os.PathLike, gender: str | None = None, max_vertices: int = MAX_VERTICES) -> BodyModel:
    """Load an SMPL, SMPL+H or SMPL-X model file as a Z-up `BodyModel`.

    `gender` labels the model (default: guessed from the file name, else 'neutral').  `max_vertices`
    bounds the mesh the file may declare; an `.npz` is checked from its headers, before any array is
    decompressed."""
    path = Path(path)
    if _is_npz(path):
        headers = npz_headers(path)
        found = {k: shape if dtype.kind in _NUMERIC_KINDS else f"an array of dtype {dtype}"
                 for k, (shape, dtype) in headers.items()}
        _layout(found, path, max_vertices)
        data = read_model_file(path, _REQUIRED + ("posedirs",))
    else:
        data = read_model_file(path)
        _layout({k: _describe(v) for k, v in data.items()}, path, max_vertices)
    c = Y_UP_TO_Z_UP
    template = _array(data, "v_template", path).astype(np.float64)
    shapedirs = _array(data, "shapedirs", path).astype(np.float64)
    regressor = _array(data, "J_regressor", path).astype(np.float64)
    weights = _array(data, "weights", path).astype(np.float64)
    parents = _array(data, "kintree_table", path)[0].astype(np.int64)
    faces = _array(data, "f", path).astype(np.int64)
    verts, joints = len(template), len(parents)
    names = _joint_names(joints, path)
    if joints == NUM_BODY_JOINTS + 3 + len(_HAND_JOINTS):
        shapedirs = shapedirs[:, :, :_SMPLX_SHAPE_DIRS]
    parents[0] = -1  # files store the root's parent as -1 or as 2**32 - 1

    template_z = template @ c.T
    shape_dirs = np.einsum("ab,vbs->sva", c, shapedirs)  # (S, V, 3)
    pose_dirs = None
    if "posedirs" in data:
        posedirs = _array(data, "posedirs", path).astype(np.float64)
        p = posedirs.reshape(verts, 3, joints - 1, 3, 3)
        # Offsets turn with C; the feature (R - I) = C^T (R' - I) C re-indexes the directions.
        pose_dirs = np.einsum("xy,vykcd,ac,bd->kabvx", c, p, c, c).reshape((joints - 1) * 9, verts, 3)
        pose_dirs = pose_dirs.astype(np.float32)
    if gender is None:
        stem = path.stem.lower()
        gender = "female" if "female" in stem else "male" if "male" in stem else "neutral"
    kind = {24: "smpl", 52: "smplh", 55: "smplx"}[joints]
    try:
        return BodyModel(
            name=f"{kind}-{gender}",
            shape_space=kind,
            faces=faces,
            parents=parents,
            joint_names=names,
            weights=weights,
            template=template_z,
            shape_dirs=shape_dirs,
            joint_template=regressor @ template_z,
            joint_shape_dirs=np.einsum("jv,svk->sjk", regressor, shape_dirs),
            pose_dirs=pose_dirs,
            shape_names=tuple(f"beta{i}" for i in range(shape_dirs.shape[0])),
            default_betas=np.zeros(shape_dirs.shape[0]),
            gender=gender,
        )
    except ValueError as exc:  # the model's own checks (parents' order, faces' range) name no file
        raise ValueError(f"{path}: {exc}") from exc
