
import numpy as np
import pytest

from assets.pattern import PatternSpec


def test_defaults_are_the_reference_numbers():
    spec = PatternSpec()
    assert spec.pitch_mm == 2.0 and spec.crosspoints_per_side == 25
    assert spec.marker_size == pytest.approx(0.048)
    assert spec.num_ids >= 4096


def test_uv_xy_round_trip(small_table):
    spec = small_table.spec
    uv = np.random.default_rng(0).uniform(0, 48, (100, 2))
    assert np.allclose(spec.xy_to_uv(spec.uv_to_xy(uv)), uv)
    # crosspoint (0, 0) is the top-left: smallest x, largest y
    x0, y0, x1, y1 = spec.fabric_bounds
    assert np.allclose(spec.uv_to_xy([0, 0]), [x0, y1])


def test_covering_and_json_round_trip(tmp_path):
    spec = PatternSpec.covering(1.5, 0.5, pitch_mm=2.5, seed=3)
    assert (spec.rows, spec.cols) == (9, 25)  # 60 mm markers
    spec.save(tmp_path / "spec.json")
    assert PatternSpec.load(tmp_path / "spec.json") == spec


@pytest.mark.parametrize(
    "content, message",
    [
        ('{"pitch_mm": -1}', "pitch_mm"),
        ('{"rows": 100, "cols": 100}', "num_ids"),
        ('{"colour": 1}', "unknown field"),
        ('{"code_rgb": [1, 2]}', "code_rgb"),
        ('{"rows": 4,', "invalid JSON"),
    ],
)
def test_bad_spec_file_names_file_and_field(tmp_path, content, message):
    path = tmp_path / "bad_spec.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as info:
        PatternSpec.load(path)
    assert "bad_spec.json" in str(info.value)
