"""Augmentation: photometric steps change appearance only, reproducibly; the view warp moves pixels as
it moves points."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from assets.geometry import apply_homography
from assets.pattern import PatternSpec
from networks.augment import Augment, ViewWarp, augment, warp_image

SPEC = PatternSpec(rows=8, cols=8, num_ids=512)
OFF = Augment(blur_probability=0, motion_blur_probability=0, colour_probability=0, noise_probability=0,
              gamma_probability=0, jpeg_probability=0)


def _image(seed: int = 0) -> np.ndarray:
    """A 64 x 80 test image with edges, gradients and colour."""
    rng = np.random.default_rng(seed)
    image = np.zeros((64, 80, 3), np.uint8)
    image[:] = np.linspace(40, 220, 80, dtype=np.uint8)[None, :, None]
    image[16:48, 20:60] = rng.integers(0, 256, 3)
    cv2.line(image, (0, 5), (79, 60), (0, 0, 0), 1)
    return image


def _sharpness(image: np.ndarray) -> float:
    return float(cv2.Laplacian(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.CV_64F).var())


def test_everything_on_changes_the_image_but_not_its_shape_and_is_reproducible():
    config = Augment(blur_probability=1, colour_probability=1, noise_probability=1, gamma_probability=1,
                     jpeg_probability=1)
    image = _image()
    out = augment(image, np.random.default_rng(3), config)
    assert out.shape == image.shape and out.dtype == np.uint8 and out.flags.c_contiguous
    assert np.abs(out.astype(int) - image).mean() > 2
    assert np.array_equal(out, config(image, np.random.default_rng(3)))
    assert not np.array_equal(out, config(image, np.random.default_rng(4)))
    assert np.array_equal(image, _image())  # the input is left alone


def test_all_off_is_the_identity():
    image = _image(1)
    assert np.array_equal(augment(image, np.random.default_rng(0), OFF), image)


def test_each_effect_does_what_it_says():
    gray = np.full((64, 64, 3), 100, np.uint8)
    doubled = replace(OFF, colour_probability=1, brightness=(2.0, 2.0), contrast=(1.0, 1.0), saturation=(1.0, 1.0),
                      channel_gain=0.0)
    brighter = augment(gray, np.random.default_rng(0), doubled)
    assert np.all(brighter == 200)
    gamma = augment(np.full((8, 8, 3), 128, np.uint8), np.random.default_rng(0),
                    replace(OFF, gamma_probability=1, gamma=(2.0, 2.0)))
    assert np.all(gamma == round(255 * (128 / 255) ** 2))
    noisy = augment(np.full((128, 128, 3), 128, np.uint8), np.random.default_rng(0),
                    replace(OFF, noise_probability=1, noise_sigma=(5.0, 5.0), shot_noise=(0.0, 0.0)))
    assert abs(noisy.astype(float).std() - 5.0) < 0.3
    sharp = _image(2)
    for blur in ({"blur_probability": 1, "blur_sigma": (1.5, 1.5)}, {"motion_blur_probability": 1}):
        blurred = augment(sharp, np.random.default_rng(0), replace(OFF, **blur))
        assert _sharpness(blurred) < 0.8 * _sharpness(sharp), blur
    jpeg = augment(_image(3), np.random.default_rng(0), replace(OFF, jpeg_probability=1, jpeg_quality=(10, 10)))
    assert 0.5 < np.abs(jpeg.astype(int) - _image(3)).mean() < 20


def test_bad_input_and_config_are_refused():
    with pytest.raises(ValueError, match="uint8"):
        augment(np.zeros((8, 8, 3), np.float32), np.random.default_rng(0))
    with pytest.raises(ValueError, match="uint8 RGB"):
        augment(np.zeros((8, 8), np.uint8), np.random.default_rng(0))
    with pytest.raises(ValueError, match="noise_probability"):
        Augment(noise_probability=1.5)
    with pytest.raises(ValueError, match="gamma"):
        Augment(gamma=(1.5, 0.7))


def test_the_colour_transform_is_gain_then_contrast_then_saturation():
    """The one affine map equals the three steps done one after another (same draws)."""
    config = replace(OFF, colour_probability=1)
    image = _image(4)
    out = augment(image, np.random.default_rng(7), config)
    rng = np.random.default_rng(7)
    rng.uniform(), rng.uniform()  # motion blur and blur not drawn: their probabilities are 0
    assert rng.uniform() < 1  # the colour draw
    x = image.astype(np.float64) * (rng.uniform(*config.brightness)
                                    * (1 + rng.uniform(-config.channel_gain, config.channel_gain, 3)))
    mean = x.mean(axis=(0, 1))
    x = (x - mean) * rng.uniform(*config.contrast) + mean
    gray = (x @ np.array([0.299, 0.587, 0.114]))[..., None]
    x = gray + rng.uniform(*config.saturation) * (x - gray)
    expected = np.clip(x + 0.5, 0, 255).astype(np.uint8)
    assert np.abs(out.astype(int) - expected).max() <= 1  # float32 against float64 rounding


def test_noise_differs_between_images_and_keeps_its_statistics():
    config = replace(OFF, noise_probability=1, noise_sigma=(6.0, 6.0), shot_noise=(0.0, 0.0))
    flat = np.full((96, 96, 3), 128, np.uint8)
    a = augment(flat, np.random.default_rng(1), config).astype(float) - 128
    b = augment(flat, np.random.default_rng(2), config).astype(float) - 128
    assert abs(a.std() - 6.0) < 0.3 and abs(a.mean()) < 0.2
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.05  # two images, two noises
    big = np.full((600, 600, 3), 128, np.uint8)  # larger than half the bank: drawn afresh
    c = augment(big, np.random.default_rng(3), config).astype(float) - 128
    assert abs(c.std() - 6.0) < 0.2


def test_a_view_warp_moves_pixels_as_it_moves_points():
    # a smooth blob's centroid in the warped image is the blob's centre mapped by the homography:
    # warp_image and apply_homography share the pixel convention (centres at integer + 0.5)
    rng = np.random.default_rng(0)
    warp = ViewWarp(probability=1.0, scale=(0.8, 1.25), rotation_deg=30.0, squeeze=0.5)
    yy, xx = np.mgrid[0:200, 0:300] + 0.5
    checked = 0
    while checked < 6:
        centre = rng.uniform([60, 50], [240, 150])
        blob = 255 * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * 6.0**2))
        view = warp.homography(rng, (300, 200), (160, 120))
        expected = apply_homography(view, centre[None])[0]
        if not (25 < expected[0] < 135 and 25 < expected[1] < 95):
            continue
        out = warp_image(np.repeat(blob[..., None], 3, axis=2).astype(np.float32), view, (160, 120))[..., 0]
        oy, ox = np.mgrid[0:120, 0:160] + 0.5
        found = np.array([(out * ox).sum(), (out * oy).sum()]) / out.sum()
        np.testing.assert_allclose(found, expected, atol=0.05)
        checked += 1


def test_a_view_warp_stays_inside_its_source_and_draws_its_ranges():
    warp = ViewWarp(probability=1.0)
    rng = np.random.default_rng(1)
    scales, squeezes = [], []
    for _ in range(200):
        view = warp.homography(rng, (512, 512), (256, 256))
        corners = np.array([[0, 0], [256, 0], [0, 256], [256, 256]], float)
        source = apply_homography(np.linalg.inv(view), corners)
        low, high = source.min(axis=0), source.max(axis=0)
        for axis in range(2):  # inside the source where the output's footprint fits, else centred on it
            if high[axis] - low[axis] <= 512:
                assert low[axis] >= -1e-6 and high[axis] <= 512 + 1e-6
            else:
                assert (low[axis] + high[axis]) / 2 == pytest.approx(256)
        singular = np.linalg.svd(view[:2, :2], compute_uv=False)
        scales.append(singular[0])
        squeezes.append(singular[1] / singular[0])
    assert 0.75 - 1e-9 <= min(scales) and max(scales) <= 1.4 + 1e-9 and max(scales) > 1.3
    assert min(squeezes) >= 0.6 - 1e-9 and min(squeezes) < 0.65
    assert ViewWarp(probability=0.0).homography(rng, (512, 512), (256, 256)) is None
    with pytest.raises(ValueError, match="squeeze"):
        ViewWarp(squeeze=0.0)
    with pytest.raises(ValueError, match="scale"):
        ViewWarp(scale=(1.4, 0.75))


