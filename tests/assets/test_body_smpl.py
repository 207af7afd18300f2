"""SMPL-family model files: exact LBS against a hand-written reference, .npz and .pkl, and refusal of
pickles that try to run code."""

import os
import pickle
import sys

import numpy as np
import pytest
import scipy.sparse as sp

from assets.body import load_smpl
from assets.body.smpl import read_model_file
from tests.assets.body_fixtures import chumpy_module  # noqa: F401 (a fixture)
from assets.rotations import Y_UP_TO_Z_UP, conjugate_rotvec
from tests.assets.body_fixtures import reference_lbs, smpl_arrays

C = Y_UP_TO_Z_UP


@pytest.fixture
def arrays():
    return smpl_arrays(np.random.default_rng(4))


def check_against_reference(model_path, arrays):
    body = load_smpl(model_path)
    rng = np.random.default_rng(9)
    poses = rng.normal(0.0, 0.5, (3, 24, 3))
    betas = rng.normal(0.0, 1.0, 10)
    transl = rng.normal(0.0, 0.5, (3, 3))
    # The project's frame is the file's turned by C: same motion = every rotation conjugated by C,
    # and trans is where the root joint lands (SMPL's transl plus the shaped pelvis), turned by C.
    j0 = arrays["J_regressor"] @ (arrays["v_template"] + arrays["shapedirs"] @ betas)
    posed = body.pose(conjugate_rotvec(poses, C), (j0[0] + transl) @ C.T, betas)
    for t in range(3):
        ref_v, ref_j = reference_lbs(arrays, poses[t], betas, transl[t])
        np.testing.assert_allclose(posed.vertices[t], ref_v @ C.T, atol=2e-5)
        np.testing.assert_allclose(posed.joints[t], ref_j @ C.T, atol=1e-9)
    return body


def test_npz_model_matches_published_lbs(tmp_path, arrays):
    path = tmp_path / "SMPL_FEMALE.npz"
    np.savez(path, **arrays)
    body = check_against_reference(path, arrays)
    assert body.gender == "female" and body.shape_space == "smpl" and body.num_joints == 24
    assert body.faces.shape == (60, 3)


def test_zero_pose_is_the_rest_mesh(tmp_path, arrays):
    np.savez(tmp_path / "m.npz", **arrays)
    body = load_smpl(tmp_path / "m.npz")
    betas = np.linspace(-1, 1, 10)
    rest_v, rest_j = body.rest(betas)
    posed = body.pose(body.zero_pose(2), np.tile(rest_j[0], (2, 1)), betas)
    np.testing.assert_allclose(posed.vertices, np.broadcast_to(rest_v, posed.vertices.shape), atol=1e-5)
    np.testing.assert_allclose(rest_v, (arrays["v_template"] + arrays["shapedirs"] @ betas) @ C.T, atol=1e-12)


def test_pkl_model_with_chumpy_and_sparse_regressor(tmp_path, arrays, chumpy_module):
    shapedirs = chumpy_module()
    shapedirs.__dict__.update(x=arrays["shapedirs"], _dirty_vars=set(), label="shapedirs")
    data = dict(arrays, shapedirs=shapedirs, J_regressor=sp.csc_matrix(arrays["J_regressor"]), bs_style="lbs")
    path = tmp_path / "basicModel_neutral_lbs_10_207_0_v1.0.0.pkl"
    path.write_bytes(pickle.dumps(data, protocol=2))
    del sys.modules["chumpy.ch"], sys.modules["chumpy"]  # reading must not need chumpy
    check_against_reference(path, arrays)


class _RunsCode:
    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_pkl_that_runs_code_is_refused(tmp_path, arrays):
    evil = _RunsCode()
    evil.marker = tmp_path / "pwned"
    path = tmp_path / "SMPL_MALE.pkl"
    path.write_bytes(pickle.dumps(dict(arrays, v_template=evil), protocol=2))
    with pytest.raises(ValueError, match=r"SMPL_MALE\.pkl: refusing to load (posix|os)\.system"):
        load_smpl(path)
    assert not evil.marker.exists()


def test_bad_files_name_the_file_and_field(tmp_path, arrays):
    bad = dict(arrays)
    del bad["weights"]
    np.savez(tmp_path / "noweights.npz", **bad)
    with pytest.raises(ValueError, match=r"noweights\.npz: not an SMPL-family model, missing weights"):
        load_smpl(tmp_path / "noweights.npz")
    np.savez(tmp_path / "shape.npz", **dict(arrays, weights=arrays["weights"][:, :10]))
    with pytest.raises(ValueError, match=r"shape\.npz: weights has shape \(40, 10\)"):
        load_smpl(tmp_path / "shape.npz")
    (tmp_path / "junk.pkl").write_bytes(b"not a pickle")
    with pytest.raises(ValueError, match=r"junk\.pkl"):
        read_model_file(tmp_path / "junk.pkl")
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        load_smpl(tmp_path / "missing.npz")
