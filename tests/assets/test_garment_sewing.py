import copy
import json

import numpy as np
import pytest

from assets.garments.sewing import PatternError, SewingPattern, sample_curve, Curve
from tests.assets.garment_fixtures import TUBE, tube


def test_json_round_trip(tmp_path):
    pattern = tube()
    pattern.save(tmp_path / "tube.json")
    again = SewingPattern.load(tmp_path / "tube.json")
    assert again.to_dict() == pattern.to_dict()
    assert json.loads((tmp_path / "tube.json").read_text())["seams"][0]["reverse"] is True


def test_arc_sampling_is_circular_and_on_the_left():
    start, end = np.array([0.0, 0.0]), np.array([1.0, 0.0])
    points = sample_curve(start, end, Curve("arc", sagitta=0.2), 64)
    assert np.allclose(points[32], [0.5, 0.2])  # midpoint bulges left of +x, i.e. +y
    radius = (0.25 + 0.04) / 0.4
    assert np.allclose(np.linalg.norm(points - [0.5, 0.2 - radius], axis=1), radius)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert np.allclose(steps, steps.mean())


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d["panels"][0]["edges"][1]["curve"].update(type="spline"), r"panel 'front', edge 'right'"),
        (lambda d: d["panels"][0].update(vertices=[[0, 0], [0, 0.2], [0.15, 0.2], [0.15, 0]],
                                         edges=[{"name": n} for n in ("hem", "right", "top", "left")]), "clockwise"),
        (lambda d: d["seams"][0]["b"].update(edge="nope"), "no edge 'nope'"),
        (lambda d: d["seams"][1]["a"].update(edge="right"), "already sewn"),
        (lambda d: d["panels"][1]["edges"][0].update(name="top"), "duplicate edge"),
        (lambda d: d["panels"][0]["placement"].update(body_part="tail"), "body_part"),
        (lambda d: d["panels"][0]["vertices"].__setitem__(2, [0.15, 0.0]), "edge 'right': zero length"),
        (lambda d: d["panels"][0].update(vertices=[[0, 0], [0.15, 0], [0, 0.2], [0.15, 0.2]],
                                         edges=[{"name": n} for n in ("hem", "right", "top", "left")]),
         r"panel 'front': outline crosses or touches itself \(near \[0\.07"),  # a bow tie crossing at (0.075, 0.1)
        (lambda d: d["panels"][0].update(vertices=[[0, 0], [0.15, 0], [0.15, 0.2], [0.075, 0], [0, 0.2]],
                                         edges=[{"name": n} for n in ("hem", "right", "top_r", "top_l", "left")]),
         r"panel 'front': outline crosses or touches itself"),  # two triangles meeting on the hem
    ],
)
def test_broken_patterns_name_panel_and_edge(mutate, message):
    data = copy.deepcopy(TUBE)
    mutate(data)
    with pytest.raises(PatternError, match=message):
        SewingPattern.from_dict(data, "broken.json")


def test_pieces_of_one_straight_edge_do_not_cross():
    """The wide skirt's front drafted for a 1.08 m waist: its straight sides are sampled into collinear
    pieces whose orientations against each other are float rounding (+-3e-20), not a crossing."""
    front = {"name": "front", "vertices": [[-0.425185, 0.065442], [0.425185, 0.065442], [0.238747, 0.656747],
                                           [-0.238747, 0.656747]],
             "edges": [{"name": "hem", "curve": {"type": "arc", "sagitta": -0.065442}}, {"name": "side_left"},
                       {"name": "waist", "curve": {"type": "arc", "sagitta": 0.036747}}, {"name": "side_right"}]}
    assert SewingPattern.from_dict({"name": "skirt", "panels": [front]}).panel("front").area() > 0.3
