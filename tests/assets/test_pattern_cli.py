import errno
import json
import math

import numpy as np
import pytest
from PIL import Image

from assets.pattern import MarkerTable
from assets.pattern.__main__ import main

ARGS = ["--rows", "2", "--cols", "3", "--dpi", "120", "--preview-px", "200"]


def test_cli_writes_everything_deterministically(tmp_path):
    for name in ("a", "b"):
        assert main(["--out", str(tmp_path / name), *ARGS, "--reference-textures"]) == 0
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == ["marker_table.json", "marker_table.npz", "pattern.png", "preview.png",
                     "reference_textures.npz", "spec.json"]
    for name in files:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    summary = json.loads((tmp_path / "a" / "marker_table.json").read_text())
    assert summary["markers"] == 6 and summary["min_code_distance"] >= 32
    table = MarkerTable.load(tmp_path / "a" / "marker_table.npz")
    assert table.spec.rows == 2 and table.spec.cols == 3
    with Image.open(tmp_path / "a" / "pattern.png") as png:
        assert png.size == (math.ceil(3 * 0.048 / 0.0254 * 120), math.ceil(2 * 0.048 / 0.0254 * 120))  # whole pixels, scale exact
        assert png.info["dpi"][0] == pytest.approx(120, abs=0.02)  # PNG stores whole pixels per metre
    with Image.open(tmp_path / "a" / "preview.png") as png:
        assert max(png.size) <= 200
    refs = np.load(tmp_path / "a" / "reference_textures.npz")
    assert refs["recognizer"].shape == (6, 96, 96, 3) and refs["crosspoint"].shape == (6, 112, 112, 3)


def test_cli_fabric_size(tmp_path):
    assert main(["--out", str(tmp_path), "--fabric-m", "0.1", "0.05", "--dpi", "50", "--pitch-mm", "2.5"]) == 0
    assert MarkerTable.load(tmp_path / "marker_table.npz").spec.rows == 1  # 60 mm markers
    assert MarkerTable.load(tmp_path / "marker_table.npz").spec.cols == 2
    assert main(["--out", str(tmp_path), "--fabric-m", "0.1", "0.05", "--rows", "2"]) == 2


def test_cli_panels(tmp_path):
    panels = tmp_path / "panels.json"
    panels.write_text(json.dumps({"polygons": [[[0.01, 0.01], [0.1, 0.01], [0.05, 0.08]]]}))
    assert main(["--out", str(tmp_path / "out"), *ARGS, "--panels", str(panels)]) == 0
    with Image.open(tmp_path / "out" / "pattern.png") as png:
        # bounding box of the panel plus the 10 mm margin
        assert png.size == (math.ceil(0.11 / 0.0254 * 120), math.ceil(0.09 / 0.0254 * 120))


def test_bad_input_is_reported_and_keeps_earlier_output(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["--out", str(out), *ARGS]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    broken = tmp_path / "panels.json"
    broken.write_text('{"polygons": [[[0, 0], [1, 0]')
    assert main(["--out", str(out), *ARGS, "--panels", str(broken)]) == 2
    assert "panels.json" in capsys.readouterr().err
    outside = tmp_path / "outside.json"
    outside.write_text(json.dumps([[[0, 0], [5, 0], [0, 5]]]))
    assert main(["--out", str(out), *ARGS, "--panels", str(outside)]) == 2
    assert "outside" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_run_stopped_midway_leaves_the_earlier_folder_whole(tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert main(["--out", str(out), *ARGS]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    def full_disk(*args):  # written after the new pattern.png
        raise OSError(errno.ENOSPC, "marker_table.npz: disk full while writing")

    monkeypatch.setattr(MarkerTable, "save", full_disk)
    assert main(["--out", str(out), *ARGS, "--seed", "5"]) == 2
    assert "marker_table.npz" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    monkeypatch.undo()
    assert main(["--out", str(out), *ARGS, "--seed", "5"]) == 0
    assert json.loads((out / "spec.json").read_text())["seed"] == 5
    assert MarkerTable.load(out / "marker_table.npz").spec.seed == 5
