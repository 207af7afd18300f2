import numpy as np
import pytest
from PIL import Image

from assets.pattern import PatternSpec, render_region, write_png, xy_to_pixel
from assets.pattern.raster import box_weights, composite


def _line_centre(profile: np.ndarray) -> float:
    """Sub-pixel centre (index coordinates) of a dark line in a 1D luminance profile."""
    darkness = profile.max() - profile
    darkness[darkness < 0.5 * darkness.max()] = 0
    return float((darkness * np.arange(len(profile))).sum() / darkness.sum())


def test_crosspoints_land_at_the_expected_pixel_at_300_dpi(small_table):
    spec = small_table.spec
    xmin, ymin, xmax, ymax = spec.fabric_bounds
    # an awkward region: not aligned to the grid or to whole pixels
    bounds = (xmin + 0.01031, ymin + 0.00777, xmin + 0.09, ymin + 0.08)
    dpi = 300.0
    image = render_region(small_table, bounds, dpi).astype(np.float64).mean(axis=2)
    cell_px = spec.pitch * dpi / 0.0254
    inside = [g for g in range(spec.num_crosspoints)
              if bounds[0] + spec.pitch < small_table.crosspoint_xy[g, 0] < bounds[2] - spec.pitch
              and bounds[1] + spec.pitch < small_table.crosspoint_xy[g, 1] < bounds[3] - spec.pitch]
    assert len(inside) > 200
    errors = []
    for g in inside[::7]:
        expected = xy_to_pixel(small_table.crosspoint_xy[g], bounds, dpi) - 0.5  # index coordinates
        ex, ey = np.round(expected).astype(int)
        half = int(cell_px // 2) - 1
        # a vertical line's centre from a row just above the crosspoint, and vice versa
        row = image[ey - half + 2, ex - half : ex + half + 1]
        col = image[ey - half : ey + half + 1, ex - half + 2]
        found = np.array([ex - half + _line_centre(row), ey - half + _line_centre(col)])
        errors.append(np.abs(found - expected).max())
    assert max(errors) < 0.5, max(errors)
    assert np.median(errors) < 0.1


def test_box_filter_is_exact_across_resolutions(small_table):
    spec = small_table.spec
    fine = render_region(small_table, spec.fabric_bounds, 254.0).astype(np.float64)
    coarse = render_region(small_table, spec.fabric_bounds, 127.0).astype(np.float64)
    h, w = coarse.shape[:2]
    pooled = fine[: 2 * h, : 2 * w].reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
    assert np.abs(pooled - coarse).max() <= 1.0  # only 8-bit rounding differs


def test_box_weights_partition_of_unity():
    edges = np.linspace(-0.3, 7.7, 23)
    lo = np.arange(-1, 9, dtype=float)
    weights = box_weights(edges, lo, lo + 1).toarray()
    assert np.allclose(weights.sum(axis=1), 1.0)
    assert (weights >= 0).all()


def test_png_carries_dpi_and_is_byte_deterministic(small_table, tmp_path):
    image = render_region(small_table, dpi=100)
    write_png(tmp_path / "a.png", image, 100)
    write_png(tmp_path / "b.png", render_region(small_table, dpi=100), 100)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    with Image.open(tmp_path / "a.png") as png:
        assert png.info["dpi"] == pytest.approx((100, 100), abs=0.01)
        assert np.array_equal(np.asarray(png), image)
    # physical size: the whole fabric is rows x 48 mm tall
    spec = small_table.spec
    assert image.shape[0] == pytest.approx(spec.rows * spec.marker_size / 0.0254 * 100, abs=1)


def test_panels_print_inside_only(small_table):
    spec = small_table.spec
    x0, y0, x1, y1 = spec.fabric_bounds
    triangle = np.array([[x0 + 0.01, y0 + 0.01], [x1 - 0.01, y0 + 0.01], [x0 + 0.01, y1 - 0.01]])
    dpi = 100.0
    image = render_region(small_table, spec.fabric_bounds, dpi, [triangle]).astype(int)
    bg = np.array(spec.background_rgb)
    px = lambda xy: tuple(np.floor(xy_to_pixel(np.array(xy), spec.fabric_bounds, dpi)).astype(int))
    far_x, far_y = px([x1 - 0.012, y1 - 0.012])  # beyond the hypotenuse
    assert (image[far_y, far_x] == bg).all()
    full = render_region(small_table, spec.fabric_bounds, dpi).astype(int)
    ix, iy = px([x0 + 0.03, y0 + 0.03])
    assert np.array_equal(image[iy - 3 : iy + 3, ix - 3 : ix + 3], full[iy - 3 : iy + 3, ix - 3 : ix + 3])


def test_panel_outside_fabric_is_an_error(small_table):
    x0, y0, x1, y1 = small_table.spec.fabric_bounds
    good = np.array([[x0, y0], [x0 + 0.01, y0], [x0, y0 + 0.01]])
    bad = np.array([[x0, y0], [x1 + 0.05, y0], [x0, y1]])
    with pytest.raises(ValueError, match=r"polygons\[1\].*outside"):
        render_region(small_table, dpi=50, polygons_xy=[good, bad])


def test_composite_is_the_code_colour_then_the_lines_over_it():
    """The one-pass affine map gives, byte for byte, the two steps computed in the inputs' precision."""
    spec = PatternSpec()
    rng = np.random.default_rng(0)
    bg, code, line = (np.asarray(c) for c in (spec.background_rgb, spec.code_rgb, spec.line_rgb))
    for dtype in (np.float32, np.float64):
        fill = np.round(rng.random((2, 9, 11)) * 16).astype(dtype) / dtype(16)  # dyadic: halves are exact
        lines = rng.choice(np.array([0.0, 0.3, 0.5, 1.0], dtype), (9, 11))
        rgb = bg.astype(dtype) + fill[..., None] * (code - bg).astype(dtype)
        rgb = rgb + lines[None, ..., None] * (line.astype(dtype) - rgb)
        expected = np.clip(rgb + dtype(0.5), 0, 255).astype(np.uint8)
        out = composite(spec, fill, np.broadcast_to(lines, fill.shape))
        assert out.shape == (2, 9, 11, 3) and out.dtype == np.uint8
        assert np.array_equal(out, expected), dtype
    assert np.array_equal(composite(spec, np.zeros(3), np.zeros(3)), np.broadcast_to(bg, (3, 3)))
    assert composite(spec, np.zeros((0, 5)), np.zeros((0, 5))).shape == (0, 5, 3)
