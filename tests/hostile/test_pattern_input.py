"""Hostile and careless input to `python -m assets.pattern`: a failed run leaves a finished folder as it
was, sizes are bounded before anything is allocated, and bad specs and panel outlines are named."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest

from assets.fileio import atomic_path
from assets.pattern import __main__ as pattern_cli
from tests.hostile.conftest import assert_refused, files_under, run_cli

SMALL = ["--rows", "2", "--cols", "2", "--dpi", "30", "--preview-px", "64"]


@pytest.fixture
def finished(tmp_path) -> Path:
    out = tmp_path / "out"
    assert pattern_cli.main(["--out", str(out), *SMALL]) == 0
    return out


# ---- a failed rerun leaves a finished folder as it was -------------------------------------------
@pytest.mark.hostile("half")
def test_huge_dpi_leaves_a_finished_folder_as_it_was(finished):
    before = files_under(finished)
    result = run_cli("assets.pattern", "--out", finished, *SMALL, "--dpi", "1e6", mem_gib=3, timeout=60)
    assert_refused(result, "--dpi", "--max-pixels")
    assert files_under(finished) == before


@pytest.mark.hostile("half")
@pytest.mark.parametrize("bad, needle", [
    (["--margin-mm", "nan"], "--margin-mm"),
    (["--seed", "-1"], "seed"),
])
def test_bad_argument_changes_nothing(finished, capsys, bad, needle):
    before = files_under(finished)
    assert pattern_cli.main(["--out", str(finished), *SMALL, "--rows", "3", *bad]) == 2
    assert needle in capsys.readouterr().err
    assert files_under(finished) == before


@pytest.mark.hostile("half")
def test_full_disk_part_way_changes_nothing(finished, capsys, monkeypatch):
    before = files_under(finished)
    real = pattern_cli.write_png

    def full_disk(path, image, dpi):
        if Path(path).name == "preview.png":  # after the new pattern.png
            with atomic_path(path):
                raise OSError(errno.ENOSPC, "No space left on device")
        real(path, image, dpi)

    monkeypatch.setattr(pattern_cli, "write_png", full_disk)
    assert pattern_cli.main(["--out", str(finished), *SMALL, "--seed", "5"]) == 2
    assert "preview.png: disk full" in capsys.readouterr().err
    assert files_under(finished) == before
    assert sorted(p.name for p in finished.iterdir()) == sorted(before)  # no staging folder left behind


# ---- sizes bounded before allocating -----------------------------------------------------------
@pytest.mark.hostile("memory")
@pytest.mark.parametrize("spec, args, needles", [
    ({"num_ids": 1_000_000}, [], ("spec.json", "num_ids", "--max-ids")),
    ({"crosspoints_per_side": 100_001}, [], ("spec.json", "crosspoints_per_side")),
    ({}, ["--pitch-mm", "1e6"], ("--pitch-mm", "pitch_mm")),
    ({}, ["--dpi", "1e6"], ("--dpi", "--max-pixels")),
    ({}, ["--fabric-m", "1e5", "1e5"], ("--fabric-m", "num_ids")),
])
def test_memory_bombs_are_refused_before_allocating(tmp_path, spec, args, needles):
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    out = tmp_path / "out"
    result = run_cli("assets.pattern", "--out", out, "--spec", path, *args, mem_gib=3, timeout=60)
    assert_refused(result, *needles)
    assert not out.exists() or files_under(out) == {}


# ---- silently wrong results and tracebacks -----------------------------------------------------
@pytest.mark.hostile("silent")
@pytest.mark.parametrize("polygon, needle", [
    ([[0.01, 0.01], [0.08, 0.08], [0.08, 0.01], [0.01, 0.08]], "crosses"),  # a bow tie
    ([["0.01", "0.01"], ["0.08", "0.01"], ["0.05", "0.08"]], "numbers"),
])
def test_bad_panel_outlines_are_refused(tmp_path, capsys, polygon, needle):
    panels = tmp_path / "panels.json"
    panels.write_text(json.dumps({"polygons": [polygon]}))
    assert pattern_cli.main(["--out", str(tmp_path / "out"), *SMALL, "--panels", str(panels)]) == 2
    err = capsys.readouterr().err
    assert "panels.json" in err and needle in err, err
    assert not (tmp_path / "out").exists() or files_under(tmp_path / "out") == {}


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("spec, needle", [
    ({"background_rgb": ["a", "b", "c"]}, "background_rgb"),
    ({"code_rgb": [1.5, 2, 3]}, "code_rgb"),
    ({"origin_xy": ["0", 0]}, "origin_xy"),
    ({"rows": 2.5}, "rows"),
    ({"seed": 1.5}, "seed"),
    ({"rows": True}, "rows"),
    ({"pitch_mm": float("inf")}, "pitch_mm"),
])
def test_specs_of_wrong_types_are_refused(tmp_path, capsys, spec, needle):
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    assert pattern_cli.main(["--out", str(tmp_path / "out"), "--spec", str(path), "--dpi", "30"]) == 2
    err = capsys.readouterr().err
    assert "spec.json" in err and needle in err, err
    assert not (tmp_path / "out").exists() or files_under(tmp_path / "out") == {}
