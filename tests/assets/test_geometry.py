"""assets.geometry on plain arrays: the closed-form 3 x 3 inverse against LAPACK's."""

import numpy as np

from assets.geometry import apply_homography, fit_homography, invert_3x3


def test_invert_3x3_matches_numpy_and_marks_singular_matrices():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(2, 50, 3, 3))
    inverse = invert_3x3(m)
    assert inverse.shape == m.shape
    assert np.allclose(inverse, np.linalg.inv(m), rtol=1e-9, atol=1e-9)
    assert np.allclose(m @ inverse, np.eye(3), atol=1e-8)
    singular = np.array([[1.0, 2, 3], [2, 4, 6], [0, 1, 1]])  # rows 0 and 1 parallel: determinant exactly 0
    assert np.isnan(invert_3x3(singular)).all()
    assert np.isnan(invert_3x3(np.stack([singular, np.eye(3)]))[0]).all()
    assert np.allclose(invert_3x3(np.eye(3)), np.eye(3))


def test_fit_homography_recovers_a_homography_and_its_inverse():
    rng = np.random.default_rng(1)
    truth = np.array([[0.9, -0.2, 15.0], [0.3, 1.1, -4.0], [3e-4, -1e-4, 1.0]])
    src = rng.uniform(-50, 50, (7, 2))
    fitted = fit_homography(src, apply_homography(truth, src))
    assert np.allclose(fitted, truth, atol=1e-9)
    assert np.allclose(apply_homography(invert_3x3(fitted), apply_homography(truth, src)), src, atol=1e-9)
