import json

import trimesh

from assets.garments.__main__ import main
from assets.garments.template import Template
from tests.assets.garment_fixtures import TUBE


def test_build_writes_template_texture_meshes_and_summary(tmp_path):
    pattern = tmp_path / "tube.json"
    pattern.write_text(json.dumps(TUBE))
    out = tmp_path / "out"
    assert main(["build", str(pattern), "--levels", "12,4", "--dpi", "60", "--formats", "obj,ply,glb", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [s["spacing_mm"] for s in summary["levels"]] == [12, 4]
    template = Template.load(out / "template.npz")
    for mm in (12, 4):
        level = template.level(mm)
        for fmt in ("obj", "ply", "glb"):
            mesh = trimesh.load(out / f"tube_{mm}mm.{fmt}", process=False, force="mesh")
            assert mesh.faces.shape == level.faces.shape, fmt
            assert mesh.visual.uv.shape == (level.num_vertices, 2), fmt
    assert "map_Kd pattern_texture.png" in (out / "tube_12mm.mtl").read_text()


def test_garmentcode_input_and_bad_input(tmp_path, capsys):
    gc = "assets/data/garmentcode/flare_skirt_specification.json"
    out = tmp_path / "skirt"
    assert main(["build", gc, "--levels", "12", "--dpi", "30", "--formats", "ply", "--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    broken = tmp_path / "broken.json"
    broken.write_text('{"name": "x", "panels": [{"name": "p", "vertices": [[0, 0], [1, 0]]}]}')
    assert main(["build", str(broken), "--out", str(out)]) == 2
    assert "broken.json" in capsys.readouterr().err
    assert main(["build", "hat", "--out", str(out)]) == 2
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
