"""GarmentCode importer: shipped real specifications, an exact hand-made one, geometry kept in 3D."""

import copy
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.garments.garmentcode import garmentcode_from_dict, load_garmentcode, main
from assets.garments.sewing import PatternError, SewingPattern, arc_geometry

DATA = Path(__file__).resolve().parents[2] / "assets" / "data" / "garmentcode"
SHIRT = DATA / "shirt_mean_specification.json"
SKIRT = DATA / "flare_skirt_specification.json"
C = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # GarmentCode Y up, front +Z -> ours Z up, front -Y


def _axis(angle_deg, axis):
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def gc_world(raw_panel, points_gc, units):
    """GarmentCode's own placement (pattern/core.py): R = Rz Ry Rx, p = R [x, y, 0] + t, then to ours."""
    a, b, c = raw_panel["rotation"]
    r = _axis(c, 2) @ _axis(b, 1) @ _axis(a, 0)
    p3 = np.c_[np.asarray(points_gc, float), np.zeros(len(points_gc))] @ r.T + raw_panel["translation"]
    return p3 @ C.T / units


def our_world(panel, points):
    r = Rotation.from_euler("xyz", panel.placement.rotation_deg, degrees=True).as_matrix()
    return np.asarray(points) @ r[:, :2].T + panel.placement.translation


def edge_ends(pattern, side):
    panel = pattern.panel(side.panel)
    k = panel.edge_index(side.edge)
    return our_world(panel, panel.vertices[[k, (k + 1) % len(panel.vertices)]])


def tube_spec():
    """Two 20 x 30 cm panels 20 cm apart, sewn at both sides; front CCW (normal +Z), back CW (normal -Z)."""
    front = {
        "translation": [0.0, 100.0, 10.0], "rotation": [0.0, 0.0, 0.0],
        "vertices": [[0, 0], [20, 0], [20, 30], [0, 30]],
        "edges": [
            {"endpoints": [0, 1], "curvature": {"type": "quadratic", "params": [[0.5, -0.1]]}},
            {"endpoints": [1, 2]},
            {"endpoints": [2, 3], "curvature": {"type": "circle", "params": [20.0, 0, 1]}, "label": "neck"},
            {"endpoints": [3, 0]},
        ],
    }
    back = {
        "translation": [0.0, 100.0, -10.0], "rotation": [0.0, 0.0, 0.0],
        "vertices": [[0, 0], [0, 30], [20, 30], [20, 0]],
        "edges": [
            {"endpoints": [0, 1]},
            {"endpoints": [1, 2], "curvature": [0.5, 0.2]},  # legacy bare list: quadratic, relative
            {"endpoints": [2, 3]},
            {"endpoints": [3, 0], "curvature": {"type": "cubic", "params": [[0.25, 0.1], [0.75, 0.1]]}},
        ],
    }
    return {
        "pattern": {
            "panels": {"front": front, "back": back},
            "stitches": [[{"panel": "front", "edge": 1}, {"panel": "back", "edge": 2}],
                         [{"panel": "front", "edge": 3}, {"panel": "back", "edge": 0}]],
            "panel_order": ["front", "back"],
        },
        "properties": {"curvature_coords": "relative", "units_in_meter": 100},
    }


def reverse_gc_loop(spec, name):
    """The same garment with one GarmentCode panel traversed the other way (its normal flips): edges
    get labels so that names survive the re-indexing, and the panel's stitches become 'right_wrong'
    (GarmentCode's Seam.swap) so that they still join the same ends."""
    spec = copy.deepcopy(spec)
    panel = spec["pattern"]["panels"][name]
    for k, edge in enumerate(panel["edges"]):
        edge.setdefault("label", f"gc{k}")
    plain = copy.deepcopy(spec)
    n = len(panel["vertices"])
    panel["vertices"] = [panel["vertices"][(-i) % n] for i in range(n)]
    old = panel["edges"]
    panel["edges"] = []
    for j in range(n):
        edge = dict(old[n - 1 - j], endpoints=[j, (j + 1) % n])
        curvature = edge.get("curvature")
        if isinstance(curvature, dict) and curvature["type"] == "circle":
            radius, large, right = curvature["params"]
            edge["curvature"] = {"type": "circle", "params": [radius, large, 1 - right]}
        elif isinstance(curvature, dict):
            params = [[1 - u, -v] for u, v in curvature["params"][::-1]]
            edge["curvature"] = {"type": curvature["type"], "params": params}
        elif curvature is not None:  # legacy bare quadratic control point
            edge["curvature"] = [1 - curvature[0], -curvature[1]]
        panel["edges"].append(edge)
    for i, stitch in enumerate(spec["pattern"]["stitches"]):
        touched = [side["panel"] == name for side in stitch[:2]]
        for side in stitch[:2]:
            if side["panel"] == name:
                side["edge"] = n - 1 - side["edge"]
        if sum(touched) == 1:
            spec["pattern"]["stitches"][i] = stitch[:2] + ([] if len(stitch) == 3 else ["right_wrong"])
    return plain, spec


def assert_same_pattern(a, b):
    assert a.seams == b.seams
    for p, q in zip(a.panels, b.panels, strict=True):
        assert (p.name, p.placement.body_part) == (q.name, q.placement.body_part)
        assert [(e.name, e.curve.type) for e in p.edges] == [(e.name, e.curve.type) for e in q.edges]
        np.testing.assert_allclose(p.vertices, q.vertices, atol=1e-12)
        np.testing.assert_allclose(p.placement.rotation_deg, q.placement.rotation_deg, atol=1e-9)
        np.testing.assert_allclose(p.placement.translation, q.placement.translation, atol=1e-12)
        for e, f in zip(p.edges, q.edges):
            assert e.curve.sagitta == pytest.approx(f.curve.sagitta, abs=1e-12)
            np.testing.assert_allclose(np.reshape(e.curve.control, -1), np.reshape(f.curve.control, -1), atol=1e-12)


# ---- the shipped specifications ----------------------------------------------------------------
@pytest.mark.parametrize("path, panels, seams", [(SHIRT, 8, 18), (SKIRT, 4, 6)])
def test_shipped_files_import_and_validate(path, panels, seams):
    pattern = load_garmentcode(path)
    assert (len(pattern.panels), len(pattern.seams)) == (panels, seams)
    assert pattern.name == path.stem.removesuffix("_specification")
    raw = json.loads(path.read_text())["pattern"]
    assert [p.name for p in pattern.panels] == raw["panel_order"]
    again = SewingPattern.from_dict(pattern.to_dict(), source="round trip")  # our own validator, via JSON
    assert again.to_dict() == pattern.to_dict()
    # panels oriented consistently from outside: GarmentCode's right-to-right stitches are all reversed
    assert all(seam.reverse for seam in pattern.seams)
    assert all(p.area() > 0 for p in pattern.panels)


def test_body_parts_from_names_and_position():
    parts = {p.name: p.placement.body_part for p in load_garmentcode(SHIRT).panels}
    assert parts == {
        "left_ftorso": "torso_front", "right_ftorso": "torso_front",
        "left_btorso": "torso_back", "right_btorso": "torso_back",
        "left_sleeve_f": "arm_left", "left_sleeve_b": "arm_left",
        "right_sleeve_f": "arm_right", "right_sleeve_b": "arm_right",
    }
    parts = {p.name: p.placement.body_part for p in load_garmentcode(SKIRT).panels}
    assert parts == {"wb_front": "waist_front", "wb_back": "waist_back",
                     "skirt_front": "waist_front", "skirt_back": "waist_back"}


def test_edges_named_from_unique_labels():
    skirt = load_garmentcode(SKIRT)
    assert [e.name for e in skirt.panel("wb_front").edges] == ["e0", "e1", "e2", "lower_interface"]
    assert [e.name for e in skirt.panel("wb_back").edges] == ["lower_interface", "e1", "e2", "e3"]


@pytest.mark.parametrize("path", [SHIRT, SKIRT])
def test_outline_stays_where_garmentcode_puts_it(path):
    spec = json.loads(path.read_text())
    units = spec["properties"]["units_in_meter"]
    pattern = load_garmentcode(path)
    for name, raw in spec["pattern"]["panels"].items():
        panel = pattern.panel(name)
        assert [e.name for e in panel.edges] == [e.get("label", f"e{k}") for k, e in enumerate(raw["edges"])]
        if panel.placement.body_part.startswith("arm"):  # turned into the T-pose (test_sleeves_...)
            continue
        expected = gc_world(raw, raw["vertices"], units)
        assert np.abs(our_world(panel, panel.vertices) - expected).max() < 1e-9, name
        for k, raw_edge in enumerate(raw["edges"]):
            curvature = raw_edge.get("curvature")
            if not isinstance(curvature, dict) or curvature["type"] == "circle":
                continue
            # GarmentCode's curve (relative control points, pattern/utils.py rel_to_abs_2d) densely sampled
            start, end = (np.asarray(raw["vertices"][i], float) for i in raw_edge["endpoints"])
            d = end - start
            control = [start + u * d + v * np.array([-d[1], d[0]]) for u, v in curvature["params"]]
            nodes = np.array([start, *control, end])
            t = np.linspace(0, 1, 4001)[:, None]
            deg = len(nodes) - 1
            dense = sum(math.comb(deg, i) * t**i * (1 - t) ** (deg - i) * nodes[i] for i in range(deg + 1))
            dense = gc_world(raw, dense, units)
            ours = our_world(panel, panel.edge_points(k, 32))  # no shipped loop is reversed: same index
            gap = np.linalg.norm(ours[:, None] - dense[None], axis=2).min(axis=1).max()
            assert gap < 2e-4, (name, k, gap)


def test_sleeves_turn_from_garmentcodes_a_pose_into_the_t_pose():
    """shirt_mean's sleeves hang 50.48 degrees down (GarmentCode's A-pose body); ours lie along +-X,
    each side's two panels turned together as one rigid piece, their cap end where the armhole is."""
    spec = json.loads(SHIRT.read_text())
    pattern = load_garmentcode(SHIRT)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        names = [f"{side}_sleeve_f", f"{side}_sleeve_b"]
        for n in names:  # each panel's x axis (the sleeve's length) is horizontal now, facing front or back
            r = Rotation.from_euler("xyz", pattern.panel(n).placement.rotation_deg, degrees=True).as_matrix()
            assert abs(r[2, 0]) < 1e-12 and abs(r[1, 2]) == pytest.approx(1.0)
        ours = np.concatenate([our_world(pattern.panel(n), pattern.panel(n).vertices) for n in names])
        theirs = np.concatenate([gc_world(spec["pattern"]["panels"][n], spec["pattern"]["panels"][n]["vertices"], 100)
                                 for n in names])
        turn = _axis(sign * -50.483, 1)  # undo GarmentCode's turn about its front axis (our Y)
        moved = (theirs - theirs.mean(0)) @ turn.T + ours.mean(0)
        assert np.linalg.norm(moved[:, None] - ours[None], axis=2).min(axis=1).max() < 1e-9
        assert np.ptp(ours[:, 0]) == pytest.approx(0.312, abs=1e-3)  # the sleeve's length, along X
        # the cap end stays near GarmentCode's (5 cm outside the torso panels' 28.7 cm half width)
        assert (sign * ours[:, 0]).min() == pytest.approx(0.262, abs=0.01)


def test_circle_edges_keep_radius_and_side():
    spec = json.loads(SKIRT.read_text())
    pattern = load_garmentcode(SKIRT)
    for name, raw in spec["pattern"]["panels"].items():
        panel = pattern.panel(name)
        for k, raw_edge in enumerate(raw["edges"]):
            curvature = raw_edge.get("curvature")
            if not curvature:
                continue
            radius, large, right = curvature["params"]
            start, end = panel.vertices[k], panel.vertices[(k + 1) % len(panel.vertices)]
            centre, r, _, _ = arc_geometry(start, end, panel.edges[k].curve.sagitta)
            points = panel.edge_points(k, 64)
            assert r == pytest.approx(radius / 100, rel=1e-9)
            assert np.abs(np.linalg.norm(points - centre, axis=1) - radius / 100).max() < 1e-9
            # the bulge side in 3D is GarmentCode's: compare the arc midpoint with GarmentCode's frame
            raw_start, raw_end = (np.asarray(raw["vertices"][i], float) for i in raw_edge["endpoints"])
            d = raw_end - raw_start
            left = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            mid3d = our_world(panel, points[32:33])
            mid_gc = gc_world(raw, [(raw_start + raw_end) / 2], 100)
            left3d = gc_world(raw, [(raw_start + raw_end) / 2 + left], 100) - mid_gc
            assert np.sign(np.dot(mid3d - mid_gc, left3d.T).item()) == (-1 if right else 1)
            assert not large


def test_seam_pairing_is_the_nearer_one_in_3d():
    for path in (SHIRT, SKIRT):
        pattern = load_garmentcode(path)
        for seam in pattern.seams:
            (a0, a1), (b0, b1) = edge_ends(pattern, seam.a), edge_ends(pattern, seam.b)
            crossed = np.linalg.norm(a0 - b1) + np.linalg.norm(a1 - b0)
            straight = np.linalg.norm(a0 - b0) + np.linalg.norm(a1 - b1)
            chosen, other = (crossed, straight) if seam.reverse else (straight, crossed)
            assert chosen < other + 1e-4, (path.name, seam)  # short edges: either pairing within 0.1 mm
            assert chosen < 2 * 0.46  # GarmentCode's initial placement keeps sewn edges within ~45 cm


# ---- a hand-made specification with exact numbers ----------------------------------------------
def test_tube_exact_numbers():
    pattern = garmentcode_from_dict(tube_spec(), source="tube.json")
    front, back = pattern.panel("front"), pattern.panel("back")
    np.testing.assert_allclose(front.vertices, [[0, 0], [0.2, 0], [0.2, 0.3], [0, 0.3]], atol=1e-15)
    assert [e.name for e in front.edges] == ["e0", "e1", "neck", "e3"]
    assert front.edges[0].curve.type == "quadratic"
    np.testing.assert_allclose(front.edges[0].curve.control, [[0.1, -0.02]], atol=1e-15)
    # radius 0.2 m over a 0.2 m chord bulging right of (0.2, 0.3) -> (0, 0.3): up, out of the panel
    assert front.edges[2].curve.type == "arc"
    assert front.edges[2].curve.sagitta == pytest.approx(-(0.2 - math.sqrt(0.03)), abs=1e-15)
    assert front.edges[2].curve.sagitta == pytest.approx(-0.0267949192, abs=1e-10)
    assert front.placement.body_part == "torso_front"
    np.testing.assert_allclose(front.placement.translation, [0, -0.1, 1.0], atol=1e-15)
    np.testing.assert_allclose(Rotation.from_euler("xyz", front.placement.rotation_deg, degrees=True).as_matrix(),
                               C, atol=1e-12)
    # the back panel runs clockwise in GarmentCode's frame: mirrored, turned 180 degrees about local Y
    np.testing.assert_allclose(back.vertices, [[0, 0], [0, 0.3], [-0.2, 0.3], [-0.2, 0]], atol=1e-15)
    np.testing.assert_allclose(back.edges[1].curve.control, [[-0.1, 0.34]], atol=1e-15)
    assert back.edges[3].curve.type == "cubic"
    np.testing.assert_allclose(back.edges[3].curve.control, [[-0.15, -0.02], [-0.05, -0.02]], atol=1e-15)
    assert back.placement.body_part == "torso_back"
    np.testing.assert_allclose(back.placement.translation, [0, 0.1, 1.0], atol=1e-15)
    np.testing.assert_allclose(Rotation.from_euler("xyz", back.placement.rotation_deg, degrees=True).as_matrix(),
                               C @ np.diag([-1.0, 1, -1]), atol=1e-12)
    assert [(s.a.edge, s.b.edge, s.reverse) for s in pattern.seams] == [("e1", "e2", True), ("e3", "e0", True)]
    for seam in pattern.seams:  # side seams: the two edges lie 0.2 m apart along Y, ends aligned
        (a0, a1), (b0, b1) = edge_ends(pattern, seam.a), edge_ends(pattern, seam.b)
        np.testing.assert_allclose([a0 - b1, a1 - b0], [[0, -0.2, 0]] * 2, atol=1e-12)


def test_arc_samples_have_constant_radius():
    front = garmentcode_from_dict(tube_spec(), source="tube.json").panel("front")
    k = front.edge_index("neck")
    points = front.edge_points(k, 50)
    centre, radius, _, _ = arc_geometry(front.vertices[k], front.vertices[k + 1], front.edges[k].curve.sagitta)
    assert radius == pytest.approx(0.2, abs=1e-12)
    assert np.abs(np.linalg.norm(points - centre, axis=1) - 0.2).max() < 1e-12
    assert points[25, 1] > 0.3  # bulges out of the panel, up
    assert np.linalg.norm(np.diff(points, axis=0), axis=1).std() < 1e-9  # equal arc-length steps


def test_major_arc_and_absolute_coordinates():
    spec = tube_spec()
    spec["pattern"]["panels"]["front"]["edges"][2]["curvature"]["params"] = [12.5, 1, 1]
    for edge in spec["pattern"]["panels"]["back"]["edges"]:
        edge.pop("curvature", None)
    spec["properties"]["curvature_coords"] = "absolute"
    spec["pattern"]["panels"]["front"]["edges"][0]["curvature"]["params"] = [[10.0, -2.0]]
    spec["pattern"]["stitches"] = []
    front = garmentcode_from_dict(spec, "tube.json").panel("front")
    assert front.edges[2].curve.sagitta == pytest.approx(-(0.125 + 0.075), abs=1e-15)  # r + sqrt(r^2 - 0.1^2)
    np.testing.assert_allclose(front.edges[0].curve.control, [[0.1, -0.02]], atol=1e-15)


@pytest.mark.parametrize("path, panel", [(None, "back"), (None, "front"), (SHIRT, "left_btorso"),
                                         (SHIRT, "right_sleeve_f"), (SKIRT, "wb_front")])
def test_inward_facing_panel_gets_its_loop_reversed(path, panel, caplog):
    spec = tube_spec() if path is None else json.loads(path.read_text())
    plain, turned = reverse_gc_loop(spec, panel)
    assert_same_pattern(garmentcode_from_dict(turned, "x.json"), garmentcode_from_dict(plain, "x.json"))
    assert "3D placement does not suggest" not in caplog.text


def test_twisted_stitch_is_kept_but_reported(caplog):
    spec = tube_spec()
    spec["pattern"]["stitches"][0].append("right_wrong")
    pattern = garmentcode_from_dict(spec, "tube.json")
    assert [s.reverse for s in pattern.seams] == [False, True]
    assert "tube.json: stitch #0: front.e1 and back.e2 are sewn the way" in caplog.text


# ---- bad input ---------------------------------------------------------------------------------
def _write(tmp_path, spec):
    path = tmp_path / "bad_specification.json"
    path.write_text(json.dumps(spec))
    return path


def test_missing_pattern(tmp_path):
    path = _write(tmp_path, {"properties": {"units_in_meter": 100}})
    with pytest.raises(PatternError, match=r"bad_specification\.json.*'pattern'"):
        load_garmentcode(path)


def test_unknown_curvature_type(tmp_path):
    spec = tube_spec()
    spec["pattern"]["panels"]["back"]["edges"][3]["curvature"] = {"type": "spline", "params": [[0.5, 0.1]]}
    with pytest.raises(PatternError, match=r"bad_specification\.json: panel 'back', edge #3: unknown curvature"):
        load_garmentcode(_write(tmp_path, spec))


def test_stitch_to_unknown_panel(tmp_path):
    spec = tube_spec()
    spec["pattern"]["stitches"][1][1]["panel"] = "sleeve"
    with pytest.raises(PatternError, match=r"bad_specification\.json: stitch #1: no panel 'sleeve'"):
        load_garmentcode(_write(tmp_path, spec))
    spec["pattern"]["stitches"][1][1] = {"panel": "back", "edge": 7}
    with pytest.raises(PatternError, match=r"stitch #1: panel 'back' has no edge 7"):
        load_garmentcode(_write(tmp_path, spec))


def test_broken_loop_and_impossible_circle(tmp_path):
    spec = tube_spec()
    spec["pattern"]["panels"]["front"]["edges"][2]["endpoints"] = [3, 2]
    with pytest.raises(PatternError, match=r"bad_specification\.json: panel 'front', edge #2: endpoints \[3, 2\]"):
        load_garmentcode(_write(tmp_path, spec))
    spec = tube_spec()
    spec["pattern"]["panels"]["front"]["edges"][2]["curvature"]["params"] = [5.0, 0, 0]
    with pytest.raises(PatternError, match=r"panel 'front', edge #2: circle radius"):
        load_garmentcode(_write(tmp_path, spec))


def test_our_validator_errors_name_file_panel_and_edge(tmp_path):
    spec = tube_spec()
    spec["pattern"]["panels"]["back"]["vertices"][2] = [20, 80]  # back's right side now 80 cm long
    with pytest.raises(PatternError, match=r"bad_specification\.json: seam #0 \(front\.e1 .*back\.e2"):
        load_garmentcode(_write(tmp_path, spec))


# ---- CLI ---------------------------------------------------------------------------------------
def test_cli_converts(tmp_path, capsys):
    out = tmp_path / "skirt.json"
    assert main([str(SKIRT), str(out)]) == 0
    assert SewingPattern.load(out).to_dict() == load_garmentcode(SKIRT).to_dict()
    assert "4 panels, 6 seams" in capsys.readouterr().out


def test_cli_bad_input(tmp_path, capsys):
    assert main([str(_write(tmp_path, {"pattern": {}})), str(tmp_path / "out.json")]) == 2
    assert capsys.readouterr().err.startswith("error: ")
    assert main([str(tmp_path / "missing.json"), str(tmp_path / "out.json")]) == 2
    assert not (tmp_path / "out.json").exists()


def test_cli_help_runs_as_module():
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run([sys.executable, "-m", "assets.garments.garmentcode", "--help"], cwd=root,
                            capture_output=True, text=True, check=True)
    assert "GarmentCode" in result.stdout and "OUT.json" in result.stdout


@pytest.mark.parametrize("height, warned", [(35.0, True), (31.5, False)])
def test_seams_gathered_over_ten_percent_are_reported(height, warned, caplog):
    """The tube's back side edge lengthened from 30 cm: 35 cm gathers its seam 14 %, 31.5 cm 5 %."""
    spec = tube_spec()
    spec["pattern"]["panels"]["back"]["vertices"][2] = [20, height]
    with caplog.at_level("WARNING", logger="assets.garments.garmentcode"):
        garmentcode_from_dict(spec, source="tube.json")
    gathered = [r.getMessage() for r in caplog.records if "gathers" in r.getMessage()]
    assert gathered == (["tube.json: stitch #0 (front.e1 0.300 m, back.e2 0.350 m) gathers 14%, more than 10%: "
                         "dressing spreads the gathers evenly along the seam"] if warned else [])
