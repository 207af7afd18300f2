import numpy as np
import pytest

from assets.pattern import MarkerTable, localization_rc, render_region, xy_to_pixel


def test_crosspoint_spacing_equals_pitch(small_table):
    spec = small_table.spec
    xy = small_table.marker_crosspoint_xy  # (M, 25, 25, 2)
    assert xy.shape == (small_table.num_markers, 25, 25, 2)
    step_col = np.diff(xy, axis=2)
    step_row = np.diff(xy, axis=1)
    assert np.allclose(step_col, [spec.pitch, 0.0], atol=1e-12)
    assert np.allclose(step_row, [0.0, -spec.pitch], atol=1e-12)


def test_neighbours_share_border_crosspoints(small_table):
    spec = small_table.spec
    index = small_table.crosspoint_index.reshape(spec.rows, spec.cols, 25, 25)
    assert np.array_equal(index[:, :-1, :, -1], index[:, 1:, :, 0])
    assert np.array_equal(index[:-1, :, -1, :], index[1:, :, 0, :])
    assert len(np.unique(index)) == spec.num_crosspoints


def test_inverse_lookup(small_table):
    spec = small_table.spec
    lookup = small_table.crosspoint_markers
    count = (lookup[:, :, 0] >= 0).sum(axis=1)
    # marker corners inside the fabric are shared by 4 markers, other border points by 2
    assert (count == 4).sum() == (spec.rows - 1) * (spec.cols - 1)
    assert count.min() == 1
    for marker_id in (0, 5, small_table.num_markers - 1):
        for r, c in [(0, 0), (7, 13), (24, 24), (12, 0)]:
            g = small_table.crosspoint_index[marker_id, r, c]
            assert (marker_id, r, c) in small_table.markers_of_crosspoint(g)
            for other_id, rr, cc in small_table.markers_of_crosspoint(g):
                assert small_table.crosspoint_index[other_id, rr, cc] == g


def test_localization_points_are_where_documented(small_table):
    loc = small_table.localization_xy  # (M, 5, 2): centre, TL, TR, BL, BR
    xy = small_table.crosspoint_xy[small_table.crosspoint_index]
    lo, hi = xy.min(axis=(1, 2)), xy.max(axis=(1, 2))
    assert np.allclose(loc[:, 1], np.stack([lo[:, 0], hi[:, 1]], 1))  # TL: left, top
    assert np.allclose(loc[:, 2], hi)  # TR: right, top
    assert np.allclose(loc[:, 3], lo)  # BL: left, bottom
    assert np.allclose(loc[:, 4], np.stack([hi[:, 0], lo[:, 1]], 1))  # BR: right, bottom
    assert np.allclose(loc[:, 0], loc[:, 1:].mean(axis=1))
    assert localization_rc(small_table.spec).tolist() == [[12, 12], [0, 0], [0, 24], [24, 0], [24, 24]]


def test_finder_and_centre_checker_are_printed_where_the_points_are(small_table):
    spec = small_table.spec
    dpi = 200.0
    image = render_region(small_table, dpi=dpi).astype(int)
    code, bg = np.array(spec.code_rgb), np.array(spec.background_rgb)
    d = 1.5 * spec.pitch  # 1.5 cells inside the marker, between lines
    offsets = {"TL": (d, -d), "TR": (-d, -d), "BL": (d, d), "BR": (-d, d)}
    for m in range(small_table.num_markers):
        for k, name in enumerate(("TL", "TR", "BL", "BR"), start=1):
            x, y = xy_to_pixel(small_table.localization_xy[m, k] + offsets[name], spec.fabric_bounds, dpi)
            colour = image[int(y), int(x)]
            expected = code if name == "TL" else bg
            assert np.abs(colour - expected).max() <= 2, (m, name, colour)
        # centre checker: code colour up-left and down-right of the centre, background elsewhere
        for (dx, dy), expected in [((-d, d), code), ((d, -d), code), ((d, d), bg), ((-d, -d), bg)]:
            x, y = xy_to_pixel(small_table.localization_xy[m, 0] + (dx, dy), spec.fabric_bounds, dpi)
            assert np.abs(image[int(y), int(x)] - expected).max() <= 2


def test_save_load_round_trip(small_table, tmp_path):
    small_table.save(tmp_path / "t.npz", tmp_path / "t.json")
    loaded = MarkerTable.load(tmp_path / "t.npz")
    assert loaded.spec == small_table.spec
    assert np.array_equal(loaded.codes, small_table.codes)
    assert np.array_equal(loaded.crosspoint_markers, small_table.crosspoint_markers)


def test_load_broken_table_names_the_file(tmp_path):
    path = tmp_path / "broken.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="broken.npz"):
        MarkerTable.load(path)
