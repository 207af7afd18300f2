"""The ground-truth garment of a capture on any template level, and a reconstruction's per-vertex error
against it: on the cylinder, whose exact shape is known at every level without simulation."""

import numpy as np
import pytest

from assets.cameras import Camera, save_cameras
from assets.fileio import save_npz
from assets.pattern.observation import ImageGroundTruth
from reconstruction.groundtruth import GroundTruthCapture, vertex_errors
from tests.reconstruction.cylinder import RADIUS, cylinder_template, wrapped

FRAMES = [5, 6]
SHIFT = np.array([0.02, -0.01, 0.03])  # frame 6 is frame 5 moved


def _capture(folder, template, level_mm):
    """A capture folder of one camera that sees no marker (the garment's files are what is measured):
    the cylinder on level `level_mm` at frame 5 and moved by `SHIFT` at frame 6."""
    camera = Camera.look_at((0.0, -2.0, 1.2), (0.0, 0.0, 1.15), width=64, height=48, name="cam00")
    save_cameras(folder / "cameras.json", [camera])
    nothing = ImageGroundTruth(64, 48, np.zeros(0, np.int32), np.zeros((0, 5, 2), np.float32),
                               np.zeros((0, 5), np.float32), np.zeros((0, 5), bool),
                               np.zeros((0, 25, 25, 2), np.float32), np.zeros((0, 25, 25), bool),
                               np.zeros(0, np.int8))
    for frame in FRAMES:
        nothing.save(folder / "cam00" / f"f{frame:06d}_gt.npz")
    shape = wrapped(template, level_mm)
    level = template.level(level_mm)
    save_npz(folder / "garment.npz", {"positions": np.stack([shape, shape + SHIFT]).astype(np.float32),
                                      "faces": level.sewn_faces, "frames": np.array(FRAMES),
                                      "level_mm": np.array(level_mm)})
    template.save(folder / "template.npz", levels=(level_mm,))
    return GroundTruthCapture(folder)


@pytest.fixture(scope="module")
def template():
    return cylinder_template()


def test_the_ground_truth_on_its_own_level_is_the_garment(tmp_path, template):
    capture = _capture(tmp_path, template, 12)
    truth = capture.garment_positions([6, 5])
    np.testing.assert_allclose(truth[1], wrapped(template, 12), atol=1e-6)
    np.testing.assert_allclose(truth[0] - truth[1], np.broadcast_to(SHIFT, truth[0].shape), atol=1e-6)
    np.testing.assert_array_equal(capture.garment_positions([5], 12), truth[1:])
    with pytest.raises(ValueError, match=r"garment.npz: no positions for frames \[7\]"):
        capture.garment_positions([5, 7])


def test_a_finer_level_lies_on_the_ground_truth_mesh(tmp_path, template):
    capture = _capture(tmp_path, template, 12)
    fine = capture.garment_positions(FRAMES, 4)
    exact = wrapped(template, 4)
    assert fine.shape == (2,) + exact.shape
    # every 4 mm vertex on the 12 mm chords of the circle: within their sagitta of it, at its own height
    sagitta = 0.012 ** 2 / (8 * RADIUS)
    radial = np.linalg.norm(fine[0, :, :2], axis=1)
    assert np.all(radial <= RADIUS + 1e-6) and np.all(radial >= RADIUS - 1.01 * sagitta - 1e-6)
    np.testing.assert_allclose(fine[0, :, 2], exact[:, 2], atol=1e-6)
    np.testing.assert_allclose(fine[1] - fine[0], np.broadcast_to(SHIFT, exact.shape), atol=1e-6)


def test_a_coarser_level_is_sampled_from_the_ground_truth_mesh(tmp_path, template):
    capture = _capture(tmp_path, template, 4)
    coarse = capture.garment_positions(FRAMES, 12)
    exact = wrapped(template, 12)
    assert coarse.shape == (2,) + exact.shape
    sagitta = 0.004 ** 2 / (8 * RADIUS)  # the 12 mm vertices are on the circle, the 4 mm chords within this
    np.testing.assert_allclose(coarse[0], exact, atol=1.01 * sagitta + 1e-6)
    np.testing.assert_allclose(coarse[1], exact + SHIFT, atol=1.01 * sagitta + 1e-6)


def test_vertex_errors_are_distances_to_the_ground_truth_on_the_reconstructions_level(tmp_path, template):
    capture = _capture(tmp_path, template, 12)
    truth = capture.garment_positions(FRAMES, 4)
    rng = np.random.default_rng(0)
    error = rng.uniform(0.0, 0.01, truth.shape[:2])
    direction = rng.normal(size=truth.shape)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    reconstruction = truth + error[..., None] * direction
    np.testing.assert_allclose(vertex_errors(capture, reconstruction.astype(np.float32), FRAMES, 4), error,
                               atol=1e-6)
    np.testing.assert_allclose(vertex_errors(capture, truth[:1], [5], 4), 0.0, atol=1e-12)
    with pytest.raises(ValueError, match="not a reconstruction of this capture's garment at that level"):
        vertex_errors(capture, truth, FRAMES, 12)
