"""Hostile and careless garment input: sewing patterns and GarmentCode files, `assets.garments build`
and saved templates.  Names never leave --out, a failed build leaves the folder as it was, sizes are
bounded before anything is allocated, and every bad field is named."""

from __future__ import annotations

import copy
import errno
import json
from pathlib import Path

import numpy as np
import pytest

from assets.fileio import load_json, save_npz
from assets.garments import __main__ as garments_cli
from assets.garments.garmentcode import garmentcode_from_dict
from assets.garments.sewing import SewingPattern
from assets.garments.template import Template
from tests.assets.garment_fixtures import TUBE
from tests.hostile.conftest import assert_refused, files_under, run_cli

GARMENTCODE = Path(__file__).resolve().parents[2] / "assets/data/garmentcode/flare_skirt_specification.json"
SMALL = ["--levels", "12", "--dpi", "30", "--formats", "obj,ply"]


def _tube(**changes) -> dict:
    data = copy.deepcopy(TUBE)
    data.update(changes)
    return data


def _write(path: Path, data: object) -> Path:
    path.write_text(json.dumps(data))
    return path


# ---- names that would become paths outside --out ------------------------------------------------
@pytest.mark.hostile("outside")
def test_pattern_name_cannot_write_outside_out(tmp_path):
    pattern = _write(tmp_path / "evil.json", _tube(name="../escaped"))
    out = tmp_path / "sub" / "out"
    result = run_cli("assets.garments", "build", pattern, *SMALL, "--out", out, mem_gib=4, timeout=120)
    assert_refused(result, "evil.json: name", "../escaped")
    assert not list(tmp_path.glob("sub/escaped*")) and not list(tmp_path.rglob("escaped*"))
    assert not out.exists() or files_under(out) == {}


@pytest.mark.hostile("outside")
def test_garmentcode_panel_names_are_single_path_components(tmp_path):
    data = load_json(GARMENTCODE)
    panels = data["pattern"]["panels"]
    panels["../../x"] = panels.pop("skirt_front")
    data["pattern"]["panel_order"] = [("../../x" if n == "skirt_front" else n) for n in data["pattern"]["panel_order"]]
    for stitch in data["pattern"]["stitches"]:
        for side in stitch[:2]:
            side["panel"] = "../../x" if side["panel"] == "skirt_front" else side["panel"]
    spec = _write(tmp_path / "evil_specification.json", data)
    out = tmp_path / "out"
    result = run_cli("assets.garments", "build", spec, *SMALL, "--out", out, mem_gib=4, timeout=120)
    assert_refused(result, "evil_specification.json", "../../x")
    assert not out.exists() or files_under(out) == {}
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["evil_specification.json"]


# ---- a failed rerun leaves a finished folder as it was -------------------------------------------
@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    """A finished build of the small tube (seed 0) and its pattern file."""
    root = tmp_path_factory.mktemp("built")
    pattern = _write(root / "tube.json", TUBE)
    out = root / "out"
    assert garments_cli.main(["build", str(pattern), *SMALL, "--out", str(out)]) == 0
    return pattern, out


@pytest.mark.hostile("half")
@pytest.mark.parametrize("bad, needle", [
    (["--formats", "obj,stl"], "--formats"),
    (["--levels", "12,x"], "--levels"),
    (["--dpi", "-30"], "--dpi"),
])
def test_bad_argument_changes_nothing(built, capsys, bad, needle):
    pattern, out = built
    before = files_under(out)
    assert garments_cli.main(["build", str(pattern), *SMALL, "--seed", "5", *bad, "--out", str(out)]) == 2
    assert needle in capsys.readouterr().err
    assert files_under(out) == before


@pytest.mark.hostile("half")
def test_full_disk_part_way_changes_nothing(built, capsys, monkeypatch):
    pattern, out = built
    before = files_under(out)
    real = garments_cli.save_json

    def full_disk(path, obj):
        if Path(path).name == "summary.json":  # the last file the build writes
            raise OSError(errno.ENOSPC, f"{path}: disk full while writing")
        real(path, obj)

    monkeypatch.setattr(garments_cli, "save_json", full_disk)
    assert garments_cli.main(["build", str(pattern), *SMALL, "--seed", "5", "--out", str(out)]) == 2
    assert "summary.json" in capsys.readouterr().err
    assert files_under(out) == before
    assert sorted(p.name for p in out.iterdir()) == sorted(before)  # no staging folder left behind


# ---- sizes bounded before allocating -----------------------------------------------------------
@pytest.mark.hostile("memory")
def test_arc_sagitta_of_fifty_metres_is_refused(tmp_path):
    data = _tube()
    data["panels"][0]["edges"][1]["curve"]["sagitta"] = -50.0
    pattern = _write(tmp_path / "huge_arc.json", data)
    result = run_cli("assets.garments", "build", pattern, *SMALL, "--out", tmp_path / "out", mem_gib=3, timeout=60)
    assert_refused(result, "huge_arc.json", "'front'", "'right'", "max_panel_m")


@pytest.mark.hostile("memory")
@pytest.mark.parametrize("bad, needles", [
    (["--dpi", "1e6"], ("--dpi", "--max-pixels")),
    (["--pitch-mm", "1e6"], ("pitch_mm",)),
])
def test_huge_sheet_is_refused_before_rendering(tmp_path, bad, needles):
    pattern = _write(tmp_path / "tube.json", TUBE)
    args = ["build", pattern, "--levels", "12", "--formats", "ply", *bad, "--out", tmp_path / "out"]
    assert_refused(run_cli("assets.garments", *args, mem_gib=3, timeout=60), *needles)
    assert not (tmp_path / "out").exists() or files_under(tmp_path / "out") == {}


# ---- silently wrong results --------------------------------------------------------------------
@pytest.mark.hostile("silent")
@pytest.mark.parametrize("where, value, needle", [
    ("seams.0.reverse", "false", "reverse"),
    ("seams.0.reverse", 0, "reverse"),
    ("panels.0.vertices", [["0", 0], [0.15, 0], [0.15, 0.2], [0, 0.2]], "vertices"),
    ("panels.0.edges.1.curve.sagitta", "-0.01", "sagitta"),
    ("panels.0.placement.translation", ["0", "1", "2"], "translation"),
    ("panels.0.edges.2.curve.control", [["0.1", 0.23], [0.05, 0.17]], "control"),
    ("panels.0.placement.rotation_deg", [True, 0, 0], "rotation_deg"),
    ("name", 7, "name"),
])
def test_sewing_fields_must_have_their_json_type(where, value, needle):
    data = _tube()
    *path, last = where.split(".")
    target = data
    for key in path:
        target = target[int(key)] if key.isdigit() else target[key]
    target[int(last) if last.isdigit() else last] = value
    with pytest.raises(ValueError, match=f"pattern.json.*{needle}"):
        SewingPattern.from_dict(data, "pattern.json")


@pytest.mark.hostile("silent")
@pytest.mark.parametrize("units, found", [(1, "too large"), (10000, "too small")])
def test_garmentcode_in_wrong_units_is_refused(units, found):
    data = load_json(GARMENTCODE)
    data["properties"]["units_in_meter"] = units
    with pytest.raises(ValueError, match=f"skirt_specification.json: .*units_in_meter={units}.*{found}"):
        garmentcode_from_dict(data, "skirt_specification.json")


# ---- tracebacks from inside libraries ----------------------------------------------------------
def _gc_case(change) -> dict:
    data = load_json(GARMENTCODE)
    change(data)
    return data


SEWING_CASES = {
    "seams not a list": (_tube(seams=5), "seams"),
}
GC_CASES = {
    "stitch panel a list": (lambda d: d["pattern"]["stitches"][0][0].update(panel=["skirt_front"]), "stitch #0"),
    "panel_order a number": (lambda d: d["pattern"].update(panel_order=5), "panel_order"),
    "circle params strings": (lambda d: d["pattern"]["panels"]["skirt_front"]["edges"][1]["curvature"].update(
        params=["58", 0, 1]), "params"),
}


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("case", list(SEWING_CASES) + [f"garmentcode: {c}" for c in GC_CASES])
def test_bad_pattern_files_are_refused_clearly(tmp_path, case):
    if case.startswith("garmentcode: "):
        change, needle = GC_CASES[case.removeprefix("garmentcode: ")]
        path = _write(tmp_path / "bad_specification.json", _gc_case(change))
    else:
        data, needle = SEWING_CASES[case]
        path = _write(tmp_path / "bad.json", data)
    try:
        garments_cli.load_pattern(str(path))
    except ValueError as exc:
        assert str(path) in str(exc) and needle in str(exc), str(exc)
    else:
        pytest.fail("accepted")


@pytest.fixture(scope="module")
def template_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("template") / "template.npz"
    Template.build(SewingPattern.from_dict(TUBE, "TUBE"), dpi=30).save(path, (12,))
    return path


def _broken_template(source: Path, target: Path, change) -> Path:
    with np.load(source) as data:
        arrays = {k: data[k] for k in data.files}
    change(arrays)
    save_npz(target, arrays)
    return target


TEMPLATE_CASES = {
    "faces past the vertices": (lambda a: a["L12/faces"].__setitem__((0, 0), len(a["L12/pattern_xy"])), "faces"),
    "negative face index": (lambda a: a["L12/faces"].__setitem__((0, 1), -1), "faces"),
    "faces not triangles": (lambda a: a.__setitem__("L12/faces", a["L12/faces"][:, :2].copy()), "faces"),
    "uv of another length": (lambda a: a.__setitem__("L12/uv", a["L12/uv"][:-1]), "uv"),
    "float faces": (lambda a: a.__setitem__("L12/faces", a["L12/faces"].astype(np.float64)), "faces"),
    "seam pairs past the vertices": (lambda a: a["L12/seam_pairs"].__setitem__((0, 0), 10**6), "seam_pairs"),
    "panel index past the panels": (lambda a: a["L12/panel"].__setitem__(0, 99), "panel"),
    "pattern json not JSON": (lambda a: a.__setitem__("pattern_json", np.frombuffer(b"{nope", np.uint8)),
                              "pattern_json"),
    "levels_mm strings": (lambda a: a.__setitem__("levels_mm", np.array(["x"])), "levels_mm"),
    "layout offsets strings": (lambda a: a.__setitem__("layout_json", np.frombuffer(
        bytes(a["layout_json"]).replace(b'"offset_px": [', b'"offset_px": ["a", '), np.uint8)), "layout_json"),
}


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("case", list(TEMPLATE_CASES))
def test_bad_template_files_are_refused_on_load(template_file, tmp_path, case):
    path = tmp_path / "bad_template.npz"
    change, needle = TEMPLATE_CASES[case]
    _broken_template(template_file, path, change)
    with pytest.raises(ValueError) as info:
        Template.load(path).level(12)
    assert str(path) in str(info.value) and needle in str(info.value), str(info.value)
