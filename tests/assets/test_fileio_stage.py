"""`assets.fileio.record_stage`: the one record of what a stage's outputs were made with."""

import json

import pytest

from assets.fileio import check_settings, record_stage


def test_first_run_records_and_same_settings_reuse(tmp_path):
    path = tmp_path / "stage.json"
    assert record_stage(path, {"level_mm": 12, "noise": 0.5}) is False
    assert json.loads(path.read_text()) == {"level_mm": 12, "noise": 0.5}
    assert record_stage(path, {"noise": 0.5, "level_mm": 12}) is True


def test_other_settings_are_refused_by_name_and_record_kept(tmp_path):
    path = tmp_path / "stage.json"
    record_stage(path, {"level_mm": 12, "noise": 0.5, "seed": 0})
    with pytest.raises(ValueError, match=r"stage.json: .*level_mm: 12 -> 4; noise: 0.5 -> \(none\)"):
        record_stage(path, {"level_mm": 4, "seed": 0})
    assert json.loads(path.read_text()) == {"level_mm": 12, "noise": 0.5, "seed": 0}
    with pytest.raises(ValueError, match="level_mm: 12 -> 4"):
        check_settings(path, {"level_mm": 4, "noise": 0.5, "seed": 0})


def test_recompute_replaces_the_record(tmp_path):
    path = tmp_path / "stage.json"
    record_stage(path, {"level_mm": 12})
    assert record_stage(path, {"level_mm": 4}, recompute=True) is False
    assert json.loads(path.read_text()) == {"level_mm": 4}
    assert record_stage(path, {"level_mm": 4}) is True


def test_changeable_settings_update_without_refusal(tmp_path):
    path = tmp_path / "stage.json"
    record_stage(path, {"steps": 100, "time_limit": 60})
    assert record_stage(path, {"steps": 100, "time_limit": 540}, changeable=("time_limit",)) is True
    assert json.loads(path.read_text())["time_limit"] == 540
    with pytest.raises(ValueError, match="steps: 100 -> 200"):
        record_stage(path, {"steps": 200, "time_limit": 540}, changeable=("time_limit",))


def test_a_record_that_is_not_an_object_is_named(tmp_path):
    path = tmp_path / "stage.json"
    path.write_text("[1, 2]\n")
    with pytest.raises(ValueError, match="stage.json: expected a JSON object"):
        record_stage(path, {"a": 1})


def test_check_only_writes_nothing(tmp_path):
    path = tmp_path / "stage.json"
    check_settings(path, {"a": 1})
    assert not path.exists()


def test_a_nested_setting_is_named_by_its_dotted_key(tmp_path):
    path = tmp_path / "stage.json"
    record_stage(path, {"synth": {"seed": 3, "image_size": 256}, "steps": 10})
    with pytest.raises(ValueError, match=r"\(synth.seed: 3 -> 4\)"):
        record_stage(path, {"synth": {"seed": 4, "image_size": 256}, "steps": 10})
    with pytest.raises(ValueError, match=r"\(synth: \{\"seed\": 3, \"image_size\": 256\} -> \(none\)\)"):
        record_stage(path, {"synth": None, "steps": 10})
