"""AMASS files: key variants, the once-only axis conversion (checked against SMPL's own formula) and
clear errors."""

import numpy as np
import pytest

from assets.body import load_smpl
from assets.motion import pose_motion
from assets.motion.amass import SMPL_PELVIS_OFFSET, read_amass
from tests.assets.body_fixtures import reference_lbs, smpl_arrays


def amass_file(path, frames=4, width=72, fps_key="mocap_framerate", rng=None, **extra):
    rng = rng or np.random.default_rng(1)
    data = {
        "poses": rng.normal(0.0, 0.4, (frames, width)),
        "trans": rng.normal(0.0, 0.5, (frames, 3)),
        "betas": rng.normal(0.0, 1.0, 16),
        "gender": np.array("female"),
        fps_key: np.array(60.0),
    }
    data.update(extra)
    np.savez(path, **{k: v for k, v in data.items() if v is not None})
    return data


def test_world_motion_matches_smpl_on_its_own_model(tmp_path):
    """The AMASS world is Z up already: posing the converted motion on the converted model must give
    exactly what SMPL's formula gives on the original model, with no extra rotation."""
    arrays = smpl_arrays(np.random.default_rng(2))
    np.savez(tmp_path / "model.npz", **arrays)
    body = load_smpl(tmp_path / "model.npz")
    data = amass_file(tmp_path / "seq.npz")
    motion = read_amass(tmp_path / "seq.npz", body=body)
    posed = pose_motion(body, motion)
    assert motion.shape_space == "smpl" and motion.gender == "female" and motion.fps == 60.0
    for t in range(4):
        ref_v, ref_j = reference_lbs(arrays, data["poses"][t].reshape(24, 3), data["betas"][:10], data["trans"][t])
        np.testing.assert_allclose(posed.vertices[t], ref_v, atol=2e-5)
        np.testing.assert_allclose(posed.joints[t], ref_j, atol=1e-9)


@pytest.mark.parametrize("fps_key", ["mocap_framerate", "mocap_frame_rate", "fps"])
@pytest.mark.parametrize("width,family,hand_start", [(72, "smpl", None), (156, "smplh", 66), (165, "smplx", 75)])
def test_key_variants(tmp_path, fps_key, width, family, hand_start):
    data = amass_file(tmp_path / "seq.npz", width=width, fps_key=fps_key, gender=np.array(b"male"))
    motion = read_amass(tmp_path / "seq.npz")
    assert motion.fps == 60.0 and motion.num_frames == 4 and motion.shape_space == family
    assert motion.gender == "male" and motion.betas.shape == (16,)
    np.testing.assert_allclose(motion.trans, data["trans"] + SMPL_PELVIS_OFFSET)
    # Body joints' angles survive the conversion (only their axes turn).
    np.testing.assert_allclose(
        np.linalg.norm(motion.poses[:, 1:22], axis=2), np.linalg.norm(data["poses"][:, 3:66].reshape(4, 21, 3), axis=2)
    )
    if hand_start is None:
        assert motion.hand_poses is None
    else:
        hands = data["poses"][:, hand_start : hand_start + 90].reshape(4, 30, 3)
        np.testing.assert_allclose(np.linalg.norm(motion.hand_poses, axis=2), np.linalg.norm(hands, axis=2))
        assert np.all(motion.poses[:, 22:] == 0.0)


def test_missing_keys_and_wrong_shapes(tmp_path):
    amass_file(tmp_path / "nofps.npz", fps_key="framerate")
    with pytest.raises(ValueError, match=r"nofps\.npz: not an AMASS motion, missing mocap_framerate or"):
        read_amass(tmp_path / "nofps.npz")
    amass_file(tmp_path / "notrans.npz", trans=None)
    with pytest.raises(ValueError, match=r"notrans\.npz: .*missing trans"):
        read_amass(tmp_path / "notrans.npz")
    amass_file(tmp_path / "width.npz", width=70)
    with pytest.raises(ValueError, match=r"width\.npz: poses must be \(T, 72\), \(T, 156\) or \(T, 165\)"):
        read_amass(tmp_path / "width.npz")
    amass_file(tmp_path / "short.npz", trans=np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"short\.npz: trans must be \(4, 3\)"):
        read_amass(tmp_path / "short.npz")
    amass_file(tmp_path / "zero.npz", mocap_framerate=np.array(0.0))
    with pytest.raises(ValueError, match=r"zero\.npz: mocap_framerate: frame rate 0 Hz is outside 1 to 1000 Hz"):
        read_amass(tmp_path / "zero.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(ValueError, match=r"junk\.npz: not a readable"):
        read_amass(tmp_path / "junk.npz")
