"""SMPL-family model files (SMPL, SMPL+H, SMPL-X body) that users hold under their own licence.

`load_smpl(path)` reads the published `.npz` or `.pkl` files (keys ``v_template``, ``shapedirs``,
``posedirs``, ``J_regressor``, ``weights``, ``kintree_table``, ``f``) into a `BodyModel` that poses
exactly as the published model defines linear blend skinning (shape blend shapes, pose blend shapes on
``R_k - I`` of every non-root joint, the joint regressor applied to the shaped template), converted
once from the files' Y-up frame to the project's Z-up frame:

- geometry and every blend shape direction are rotated by ``C = Y_UP_TO_Z_UP``;
- a pose in the project's frame is ``R' = C R C^T`` of the file's; the pose blend shapes are re-indexed
  so that ``(R' - I)`` features give the same offsets as the file's ``(R - I)`` features.

`.pkl` files are untrusted: `SafeUnpickler` resolves only numpy array reconstruction, scipy sparse
matrices and chumpy arrays (as plain data, without chumpy installed) and refuses every other global,
so a crafted file cannot run code.
"""

from __future__ import annotations

import codecs
import copyreg
import importlib
import io
import logging
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from assets.body.model import NUM_BODY_JOINTS, SMPL_JOINT_NAMES, BodyModel
from assets.rotations import Y_UP_TO_Z_UP

log = logging.getLogger(__name__)

_REQUIRED = ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table", "f")
_HAND_JOINTS = tuple(
    f"{side}_{finger}{i}" for side in ("left", "right")
    for finger in ("index", "middle", "pinky", "ring", "thumb") for i in (1, 2, 3)
)  # fmt: skip
#: SMPL-X's shape directions: 300 shape components, then 100 expression components (not used here).
_SMPLX_SHAPE_DIRS = 300


class _Captured:
    """Plain stand-in for the pickled objects we accept but do not import (chumpy arrays, scipy
    sparse matrices of any scipy version): it only records its pickled state."""

    state: dict = {}

    def __setstate__(self, state):
        self.state = state if isinstance(state, dict) else {"state": state}


class _Chumpy(_Captured):
    pass


class _Sparse(_Captured):
    format = "csc"


def _numpy_attr(module: str, name: str):
    """numpy's array-rebuilding helpers live in numpy.core (1.x) or numpy._core (2.x)."""
    try:
        return getattr(importlib.import_module(f"numpy._core.{module}"), name)
    except ImportError:
        return getattr(importlib.import_module(f"numpy.core.{module}"), name)


_ALLOWED = {
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("copy_reg", "_reconstructor"): copyreg._reconstructor,
    ("copyreg", "_reconstructor"): copyreg._reconstructor,
}
# Python 3 writes bytes into protocol-2 pickles as _codecs.encode(text, "latin1").
_ALLOWED[("_codecs", "encode")] = codecs.encode
# Plain containers (chumpy's pickled state holds sets); building them runs no code of the file's choosing.
for _builtins in ("__builtin__", "builtins"):
    for _type in (object, set, frozenset, slice, complex):
        _ALLOWED[(_builtins, _type.__name__)] = _type
for _core in ("numpy.core", "numpy._core"):
    _ALLOWED[(f"{_core}.multiarray", "_reconstruct")] = _numpy_attr("multiarray", "_reconstruct")
    _ALLOWED[(f"{_core}.multiarray", "scalar")] = _numpy_attr("multiarray", "scalar")
    _ALLOWED[(f"{_core}.numeric", "_frombuffer")] = _numpy_attr("numeric", "_frombuffer")  # protocol 5


class SafeUnpickler(pickle.Unpickler):
    """Unpickler that can build arrays, sparse matrices and chumpy data, and nothing else."""

    def find_class(self, module: str, name: str):
        if (module, name) in _ALLOWED:
            return _ALLOWED[(module, name)]
        if module.startswith("chumpy"):
            return _Chumpy
        if module.startswith("scipy.sparse") and name in ("csc_matrix", "csr_matrix", "coo_matrix"):
            return type(name, (_Sparse,), {"format": name[:3]})
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: model files may contain only arrays")


def _plain(value, path: Path, key: str):
    """Turn a captured object into a numpy array or scipy sparse matrix."""
    if isinstance(value, _Chumpy):
        if "x" not in value.state:
            raise ValueError(f"{path}: {key} is a chumpy expression, not stored data; re-export it as an array")
        return np.asarray(value.state["x"])
    if isinstance(value, _Sparse):
        s = value.state
        shape = s.get("_shape", s.get("shape"))
        try:
            cls = {"csc": sp.csc_matrix, "csr": sp.csr_matrix}[value.format]
            return cls((s["data"], s["indices"], s["indptr"]), shape=shape)
        except KeyError as exc:
            raise ValueError(f"{path}: {key} is a sparse matrix without {exc}") from exc
    return value


def read_model_file(path: str | os.PathLike) -> dict[str, object]:
    """The arrays of an SMPL-family `.npz` or `.pkl` file, without executing anything in it."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such body model file")
    raw = path.read_bytes()
    if path.suffix == ".npz" or raw[:2] == b"PK":
        try:
            with np.load(io.BytesIO(raw), allow_pickle=False) as data:
                out = {}
                for key in data.files:
                    try:
                        out[key] = data[key]
                    except ValueError:  # object arrays (need pickle): never needed for posing
                        log.debug("%s: skipping object array %s", path, key)
                return out
        except (OSError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{path}: not a readable .npz file ({exc})") from exc
    try:
        data = SafeUnpickler(io.BytesIO(raw), encoding="latin1").load()
    except pickle.UnpicklingError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    except (EOFError, TypeError, AttributeError, IndexError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable model pickle ({exc})") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a model pickle holds a dict, found {type(data).__name__}")
    return {str(k): _plain(v, path, str(k)) for k, v in data.items()}


def _joint_names(count: int, path: Path) -> tuple[str, ...]:
    if count == len(SMPL_JOINT_NAMES):
        return SMPL_JOINT_NAMES
    body = SMPL_JOINT_NAMES[:NUM_BODY_JOINTS]
    if count == NUM_BODY_JOINTS + len(_HAND_JOINTS):
        return body + _HAND_JOINTS
    if count == NUM_BODY_JOINTS + 3 + len(_HAND_JOINTS):
        return body + ("jaw", "left_eye", "right_eye") + _HAND_JOINTS
    raise ValueError(f"{path}: {count} joints; SMPL has 24, SMPL+H 52, SMPL-X 55")


def _array(data: dict, key: str, path: Path, ndim: int) -> np.ndarray:
    value = data[key]
    if sp.issparse(value):
        value = value.toarray()
    value = np.asarray(value)
    if value.ndim != ndim or not np.issubdtype(value.dtype, np.number):
        raise ValueError(f"{path}: {key} must be a {ndim}-D numeric array, got shape {value.shape} {value.dtype}")
    return value


def load_smpl(path: str | os.PathLike, gender: str | None = None) -> BodyModel:
    """Load an SMPL, SMPL+H or SMPL-X model file as a Z-up `BodyModel`.

    `gender` labels the model (default: guessed from the file name, else 'neutral')."""
    path = Path(path)
    data = read_model_file(path)
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise ValueError(f"{path}: not an SMPL-family model, missing {', '.join(missing)}")
    c = Y_UP_TO_Z_UP
    template = _array(data, "v_template", path, 2).astype(np.float64)
    verts = len(template)
    shapedirs = _array(data, "shapedirs", path, 3).astype(np.float64)
    regressor = data["J_regressor"]
    regressor = regressor.toarray() if sp.issparse(regressor) else np.asarray(regressor, dtype=np.float64)
    weights = _array(data, "weights", path, 2).astype(np.float64)
    parents = _array(data, "kintree_table", path, 2)[0].astype(np.int64)
    faces = _array(data, "f", path, 2).astype(np.int64)
    joints = len(parents)
    names = _joint_names(joints, path)
    if joints == NUM_BODY_JOINTS + 3 + len(_HAND_JOINTS):
        shapedirs = shapedirs[:, :, :_SMPLX_SHAPE_DIRS]
    checks = {
        "v_template": (template.shape, (verts, 3)),
        "shapedirs": (shapedirs.shape[:2], (verts, 3)),
        "J_regressor": (regressor.shape, (joints, verts)),
        "weights": (weights.shape, (verts, joints)),
    }
    for key, (got, want) in checks.items():
        if tuple(got) != want:
            raise ValueError(f"{path}: {key} has shape {got}, expected {want}")
    parents[0] = -1  # files store the root's parent as -1 or as 2**32 - 1

    template_z = template @ c.T
    shape_dirs = np.einsum("ab,vbs->sva", c, shapedirs)  # (S, V, 3)
    pose_dirs = None
    if "posedirs" in data:
        posedirs = _array(data, "posedirs", path, 3).astype(np.float64)
        if posedirs.shape != (verts, 3, (joints - 1) * 9):
            raise ValueError(f"{path}: posedirs has shape {posedirs.shape}, expected {(verts, 3, (joints - 1) * 9)}")
        p = posedirs.reshape(verts, 3, joints - 1, 3, 3)
        # Offsets turn with C; the feature (R - I) = C^T (R' - I) C re-indexes the directions.
        pose_dirs = np.einsum("xy,vykcd,ac,bd->kabvx", c, p, c, c).reshape((joints - 1) * 9, verts, 3)
        pose_dirs = pose_dirs.astype(np.float32)
    if gender is None:
        stem = path.stem.lower()
        gender = "female" if "female" in stem else "male" if "male" in stem else "neutral"
    kind = {24: "smpl", 52: "smplh", 55: "smplx"}[joints]
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
