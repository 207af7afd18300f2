"""`benchmarks/close_up.py` at tiny size, all real: a 5 x 5 marker panel printed at 100 DPI, rendered
flat by Blender (Cycles, 256 x 256, 16 samples) with markers 25 px across, its ground truth from the
render's depth, and the repository's stored networks finding, identifying and locating its markers
on the CPU; then a rerun finds the render in the folder and renders nothing."""

import numpy as np
import pytest

from networks.weights import fetch

pytestmark = pytest.mark.slow  # a Blender render and the stored networks on the CPU, about a minute


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("close_up")


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    return fetch(tmp_path_factory.mktemp("weights"), names=("localizer", "recognizer", "crosspoints"))


def test_a_flat_panel_close_up_is_found_and_identified(bench, weights, tmp_path, capsys):
    config = bench.CloseUp(sizes_px=(25.0,), folds_mm=(0.0,), resolution=256, panel_markers=5, texture_dpi=100.0)
    (shot,) = bench.shots(config)  # the whole panel (125 px) in one image
    rows = bench.measure(config, tmp_path, weights["localizer"], weights["recognizer"], weights["crosspoints"])
    assert bench.table_row(rows[0]) in capsys.readouterr().out  # each row as soon as it is measured
    row = bench.summary(rows[0])
    assert row["images"] == 1 and row["full"] == 25  # every marker fully visible, none cut
    assert row["marker_px"] == pytest.approx(25.0, rel=0.02)  # the camera's distance gives the asked size
    assert row["recall"] >= 0.9 and row["precision"] >= 0.8
    assert row["id_top1"] >= 0.9
    assert row["centre_px"] < 1.5 and row["crosspoint_px"] < 1.0
    assert 0 < row["scales"][0] <= 1 and row["render_seconds"] > 0
    assert "| 0 | 25 |" in bench.table(rows)

    record = tmp_path / "256px_16spp" / f"{shot.name}.json"
    before = record.stat().st_mtime_ns
    _, planned = bench.render(config, tmp_path, progress=False)
    assert [s.name for s in planned] == [shot.name] and record.stat().st_mtime_ns == before


def test_bad_input_is_refused_by_name(bench, tmp_path):
    with pytest.raises(ValueError, match="sizes must be"):
        bench.CloseUp(sizes_px=(600.0,))
    with pytest.raises(ValueError, match="folds must be"):
        bench.CloseUp(folds_mm=(-1.0,))
    with pytest.raises(SystemExit):
        bench.main(["--sizes", "25,abc", "--out", str(tmp_path)])
    missing = tmp_path / "none.pt"
    assert bench.main(["--sizes", "25", "--folds", "0", "--out", str(tmp_path), "--localizer", str(missing)]) == 2


def test_a_fold_keeps_the_print_s_length_along_the_curve(bench):
    u = np.linspace(-0.3, 0.3, 601)
    x, depth = bench.fold_curve(u, 0.02, 0.07)
    along = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(depth)))]) - 0.3
    assert np.abs(along - u).max() < 2e-4  # arc length = pattern length (chords a little shorter)
    assert np.abs(depth).max() == pytest.approx(0.02, abs=1e-4) and x[-1] < 0.2
    flat_x, flat_depth = bench.fold_curve(u, 0.0, 0.07)
    assert np.array_equal(flat_x, u) and not flat_depth.any()
