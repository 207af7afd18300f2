"""A small synthetic model in SMPL's file layout (Y up, 24 joints) and a hand-written reference of
SMPL's linear blend skinning, loops and all, to check the vectorised `BodyModel.pose` against."""

import sys
import types

import numpy as np
import pytest

from assets.body.model import SMPL_PARENTS


def smpl_arrays(rng: np.random.Generator, vertices: int = 40, betas: int = 10) -> dict[str, np.ndarray]:
    """Arrays as in an SMPL model file: shapes and key names of the published files, random values."""
    joints = len(SMPL_PARENTS)
    regressor = rng.random((joints, vertices)) * (rng.random((joints, vertices)) < 0.3)
    regressor[np.arange(joints), rng.integers(0, vertices, joints)] += 1.0
    regressor /= regressor.sum(axis=1, keepdims=True)
    weights = rng.random((vertices, joints)) ** 4
    weights /= weights.sum(axis=1, keepdims=True)
    parents = np.array(SMPL_PARENTS, dtype=np.int64)
    parents[0] = 4294967295  # as the files store it (uint32 -1)
    return {
        "v_template": rng.normal(0.0, 0.3, (vertices, 3)),
        "shapedirs": rng.normal(0.0, 0.02, (vertices, 3, betas)),
        "posedirs": rng.normal(0.0, 0.01, (vertices, 3, (joints - 1) * 9)),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.stack([parents, np.arange(joints)]),
        "f": rng.integers(0, vertices, (60, 3)).astype(np.uint32),
    }


def rodrigues(r: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(r)
    if theta < 1e-12:
        return np.eye(3)
    k = r / theta
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * skew + (1 - np.cos(theta)) * skew @ skew


def reference_lbs(m, pose, betas, transl):
    """SMPL as published (Y-up frame, SMPL's transl): vertices (V, 3) and joints (24, 3)."""
    v_shaped = m["v_template"] + m["shapedirs"][:, :, : len(betas)] @ betas
    joints = m["J_regressor"] @ v_shaped
    rot = [rodrigues(p) for p in pose]
    feature = np.concatenate([(rot[k] - np.eye(3)).ravel() for k in range(1, 24)])
    v_posed = v_shaped + m["posedirs"] @ feature
    world = []
    for k in range(24):
        local = np.eye(4)
        local[:3, :3] = rot[k]
        parent = SMPL_PARENTS[k]
        local[:3, 3] = joints[k] - (joints[parent] if parent >= 0 else 0)
        world.append(local if parent < 0 else world[parent] @ local)
    posed_joints = np.array([g[:3, 3] for g in world]) + transl
    skinning = []
    for k in range(24):
        g = world[k].copy()
        g[:3, 3] -= g[:3, :3] @ joints[k]
        skinning.append(g)
    out = np.zeros_like(v_posed)
    for v in range(len(v_posed)):
        blended = sum(m["weights"][v, k] * skinning[k] for k in range(24))
        out[v] = blended[:3, :3] @ v_posed[v] + blended[:3, 3] + transl
    return out, posed_joints


@pytest.fixture
def chumpy_module(monkeypatch):
    """Pickles of the published .pkl files name chumpy.ch.Ch: make that name exist while the test
    writes such a file (reading it must not need chumpy)."""
    package = types.ModuleType("chumpy")
    module = types.ModuleType("chumpy.ch")

    class Ch:
        pass

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    module.Ch = Ch
    monkeypatch.setitem(sys.modules, "chumpy", package)
    monkeypatch.setitem(sys.modules, "chumpy.ch", module)
    return Ch
