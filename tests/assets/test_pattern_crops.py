import cv2
import numpy as np
import pytest

from assets.geometry import apply_homography, fit_homography
from assets.pattern import (
    CROSSPOINT_CROP,
    RECOGNIZER_CROP,
    crop_crosspoints_px,
    crop_homography,
    crosspoint_crop,
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


def test_wider_crosspoint_crops_keep_4_px_per_cell(small_table):
    spec = small_table.spec
    assert crosspoint_crop() == crosspoint_crop(2) == CROSSPOINT_CROP
    wide = crosspoint_crop(4)
    assert wide.size_px == 128 and wide.px_per_cell(spec) == CROSSPOINT_CROP.px_per_cell(spec) == 4
    grid = crop_crosspoints_px(spec, wide)
    assert np.allclose(grid[0, 0], [16, 16]) and np.allclose(grid[24, 24], [112, 112])
    for bad in (1, 9, 2.5, True, "4"):
        with pytest.raises(ValueError, match="whole number of cells in \\[2, 8\\]"):
            crosspoint_crop(bad)


def test_a_wider_crop_shows_the_reference_crop_in_its_middle(small_table):
    """The same marker unwarped into the 112 and 128 px crops: the 128 px one holds the 112 px one
    8 px in from each side, and its reference texture likewise."""
    spec = small_table.spec
    dpi = 4 / spec.pitch_mm * 25.4
    image = render_region(small_table, dpi=dpi)
    m = small_table.num_markers // 2
    loc = xy_to_pixel(small_table.localization_xy[m], spec.fabric_bounds, dpi)
    narrow, wide = (unwarp(image, spec, crop, loc).astype(int) for crop in (CROSSPOINT_CROP, crosspoint_crop(4)))
    assert np.abs(wide[8:120, 8:120] - narrow).max() <= 1
    refs = [reference_textures(spec, small_table.codes[m][None], crop)[0].astype(int)
            for crop in (CROSSPOINT_CROP, crosspoint_crop(4))]
    assert np.abs(refs[1][8:120, 8:120] - refs[0]).max() <= 1


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
        patch = unwarp(seen, spec, RECOGNIZER_CROP, loc_seen).astype(np.float64)
        errors = np.abs(patch[None, 4:-4, 4:-4] - refs[:, 4:-4, 4:-4]).mean(axis=(1, 2, 3))
        assert errors.argmin() == m
        assert errors[m] < 20 and errors[m] < 0.5 * np.delete(errors, m).min()
