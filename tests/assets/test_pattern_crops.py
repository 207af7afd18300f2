import json

import cv2
import numpy as np
import pytest

from assets.geometry import apply_homography, fit_homography
from assets.pattern import (
    CROSSPOINT_CROP,
    CropGeometry,
    CropSpec,
    PatternSpec,
    RECOGNIZER_CROP,
    crop_crosspoints_px,
    crop_homography,
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
        patch = unwarp(seen, spec, RECOGNIZER_CROP, loc_seen).astype(np.float64)
        errors = np.abs(patch[None, 4:-4, 4:-4] - refs[:, 4:-4, 4:-4]).mean(axis=(1, 2, 3))
        assert errors.argmin() == m
        assert errors[m] < 20 and errors[m] < 0.5 * np.delete(errors, m).min()


def test_a_crop_geometry_round_trips_through_json_and_names_what_is_wrong():
    geometry = CropGeometry(jitter_px=1.0)
    assert geometry.recognizer == RECOGNIZER_CROP and geometry.crosspoints == CROSSPOINT_CROP
    assert CropGeometry.from_dict(json.loads(json.dumps(geometry.to_dict()))) == geometry
    assert geometry.differences(CropGeometry()) == ["jitter_px: 1.0 vs 0.0"]
    wider = CropGeometry(crosspoints=CropSpec(128, 4))
    assert wider.differences(CropGeometry()) == [f"crosspoints: {CropSpec(128, 4)} vs {CROSSPOINT_CROP}"]
    for data, message in (({**geometry.to_dict(), "bend": True}, r"x: unknown field\(s\) bend"),
                          ({**geometry.to_dict(), "jitter_px": 9.0}, r"x: invalid CropGeometry: jitter_px must be in \[0, 8\]"),
                          ({**geometry.to_dict(), "recognizer": {"size_px": 4, "margin_cells": 0}},
                           r"x\.recognizer: invalid CropSpec"),
                          ({**geometry.to_dict(), "crosspoints": {"size_px": "112", "margin_cells": 2}},
                           r"x\.crosspoints: size_px must be an integer")):
        with pytest.raises(ValueError, match=message):
            CropGeometry.from_dict(data, source="x")
