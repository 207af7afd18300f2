import cv2
import numpy as np
import pytest

from assets.geometry import apply_homography, fit_homography
from assets.pattern import (
    CROSSPOINT_CROP,
    PatternSpec,
    RECOGNIZER_CROP,
    bent_crop_map,
    crop_crosspoints_px,
    crop_homography,
    crop_localization_px,
    reference_textures,
    render_region,
    unwarp,
    xy_to_pixel,
)


def test_crop_geometry_is_as_documented(small_table):
    spec = small_table.spec
    grid = crop_crosspoints_px(spec, CROSSPOINT_CROP)
    assert np.allclose(grid[0, 0], [8, 8]) and np.allclose(grid[24, 24], [104, 104])
    assert np.allclose(grid[0, 24], [104, 8])  # TR: right, top
    grid96 = crop_crosspoints_px(spec, RECOGNIZER_CROP)
    assert np.allclose(grid96[0, 0], [0, 0]) and np.allclose(grid96[24, 24], [96, 96])


def test_fit_homography_recovers_a_projective_map():
    rng = np.random.default_rng(4)
    truth = np.array([[1.1, 0.2, 30.0], [-0.15, 0.9, 12.0], [4e-4, -2e-4, 1.0]])
    src = rng.uniform(0, 200, (3, 5, 2))
    fitted = fit_homography(src, apply_homography(truth, src))
    assert np.allclose(fitted, truth, atol=1e-9)


def test_axis_aligned_unwarp_reproduces_the_reference_texture(small_table):
    spec = small_table.spec
    dpi = 4 / spec.pitch_mm * 25.4  # exactly 4 px per cell, as in the crops
    image = render_region(small_table, dpi=dpi)
    refs = reference_textures(spec, small_table.codes, CROSSPOINT_CROP)
    for m in range(small_table.num_markers):
        loc = xy_to_pixel(small_table.localization_xy[m], spec.fabric_bounds, dpi)
        crop = unwarp(image, spec, CROSSPOINT_CROP, loc)
        # inside the marker the crop must equal the reference (the margin shows the neighbours)
        diff = np.abs(crop[8:104, 8:104].astype(int) - refs[m, 8:104, 8:104])
        assert diff.max() <= 1, (m, diff.max())


def test_perspective_round_trip(small_table):
    """A marker seen in perspective unwarps onto its crop: crosspoints exactly, appearance closely."""
    spec = small_table.spec
    dpi = 8 / spec.pitch_mm * 25.4
    flat = render_region(small_table, dpi=dpi)
    h, w = flat.shape[:2]
    camera = np.array([[0.8, 0.25, 40.0], [-0.1, 0.7, 60.0], [2.5e-4, 4e-4, 1.0]])  # flat -> camera
    to_cv = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]])
    seen = cv2.warpPerspective(flat, to_cv @ camera @ np.linalg.inv(to_cv), (w, h))
    refs = reference_textures(spec, small_table.codes, RECOGNIZER_CROP).astype(np.float64)
    for m in (0, 5, 11):
        loc_flat = xy_to_pixel(small_table.localization_xy[m], spec.fabric_bounds, dpi)
        loc_seen = apply_homography(camera, loc_flat)
        crosspoints_seen = apply_homography(
            camera, xy_to_pixel(small_table.crosspoint_xy[small_table.crosspoint_index[m]], spec.fabric_bounds, dpi)
        )
        for crop in (RECOGNIZER_CROP, CROSSPOINT_CROP):
            mapped = apply_homography(crop_homography(spec, crop, loc_seen), crosspoints_seen)
            assert np.abs(mapped - crop_crosspoints_px(spec, crop)).max() < 1e-6
            # a flat marker's centre lies on its corners' homography: the bent map is that homography
            bent = bent_crop_map(spec, crop, loc_seen, crop_crosspoints_px(spec, crop))
            assert np.abs(bent - crosspoints_seen.reshape(bent.shape)).max() < 1e-6
        patch = unwarp(seen, spec, RECOGNIZER_CROP, loc_seen).astype(np.float64)
        errors = np.abs(patch[None, 4:-4, 4:-4] - refs[:, 4:-4, 4:-4]).mean(axis=(1, 2, 3))
        assert errors.argmin() == m
        assert errors[m] < 20 and errors[m] < 0.5 * np.delete(errors, m).min()


def test_the_bent_crop_map_follows_a_marker_wrapped_round_a_cylinder():
    """Five points on curved cloth fit no homography; the bent map passes through all five and puts
    the crosspoints of a marker on the slope of a cylinder (radius 1.5 marker sides, its axis along
    the marker's left edge, seen from 6 sides away) three times closer to where they are than the
    least-squares homography.  (Seen head-on, a bulge moves the centre along no image axis: five
    points cannot tell it, and both maps are the same.)"""
    spec = PatternSpec()
    crop = RECOGNIZER_CROP

    def project(uv: np.ndarray) -> np.ndarray:  # crop pixels -> image pixels (a marker side is 96 crop px)
        x, y = uv[..., 0] / 96, uv[..., 1] / 96 - 0.5
        angle = x / 1.5
        depth = 6.0 + 1.5 * (1.0 - np.cos(angle))
        return np.stack([400.0 + 600.0 * 1.5 * np.sin(angle) / depth, 300.0 + 600.0 * y / depth], axis=-1)

    grid = crop_crosspoints_px(spec, crop)
    truth, points = project(grid), project(crop_localization_px(spec, crop))
    bent = bent_crop_map(spec, crop, points, grid)
    assert np.abs(bent_crop_map(spec, crop, points, crop_localization_px(spec, crop)) - points).max() < 1e-9
    homography = apply_homography(np.linalg.inv(crop_homography(spec, crop, points)), grid)
    bent_error = np.linalg.norm(bent - truth, axis=-1)
    plane_error = np.linalg.norm(homography - truth, axis=-1)
    assert np.median(plane_error) > 1.0  # image px: a cell is 4
    assert np.median(bent_error) < np.median(plane_error) / 2.5 and bent_error.max() < plane_error.max() * 0.6
    # every pixel of the crop through the map, batched, and the crop cut through it
    maps = bent_crop_map(spec, crop, np.stack([points, points + 3.0]))
    assert maps.shape == (2, 96, 96, 2) and np.allclose(maps[1], maps[0] + 3.0)
    image = np.random.default_rng(0).integers(0, 256, (600, 800, 3), dtype=np.uint8)
    cut = unwarp(image, spec, crop, points, bend=True)
    at = maps[0, 40, 57] - 0.5  # a crop pixel is the image sampled bilinearly where the map puts it
    assert np.abs(cut[40, 57].astype(float) - cv2.getRectSubPix(image, (1, 1), tuple(at))[0, 0]).max() <= 1.5
    with pytest.raises(ValueError, match="shape"):
        bent_crop_map(spec, crop, points[:4])


