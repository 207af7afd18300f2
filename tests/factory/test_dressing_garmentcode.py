"""Dressing imported GarmentCode garments on the default body: every shipped example dresses, and a
garment that cannot close stops early, names its widest seams and leaves its stuck shape to look at."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from assets.body import load_body
from assets.garments.garmentcode import load_garmentcode
from assets.garments.sewing import Placement
from assets.garments.template import Template
from factory.dressing import TRAINING_LEVEL_MM, DressedGarment, DressingError, DressingParams, dress, save_stuck

DATA = Path(__file__).resolve().parents[2] / "assets" / "data" / "garmentcode"
#: the coarsest grid (mm) each example meshes at: the waistband of flare_skirt needs 14 mm or finer
COARSE_MM = {"shirt_mean": 30, "hoody_mean": 30, "flare_skirt": 14}


@pytest.mark.slow
@pytest.mark.parametrize("spec", sorted(DATA.glob("*_specification.json")), ids=lambda p: p.stem)
def test_every_shipped_garmentcode_example_dresses(spec):
    template = Template.build(load_garmentcode(spec))
    level = COARSE_MM.get(template.name, TRAINING_LEVEL_MM)
    dressed = dress(template, load_body("default"), params=DressingParams(level_mm=level), progress=False)
    assert dressed.report["seam_gap_mm"] < 1.0
    assert dressed.report["max_penetration_mm"] < 1.0


def _sleeves_down(pattern, degrees):
    """`pattern` with each arm's panels turned `degrees` down about a point near the shoulder, as
    GarmentCode's A-pose placement was before the import turned it into ours."""
    panels = []
    for panel in pattern.panels:
        part = panel.placement.body_part
        if part.startswith("arm"):
            sign = 1.0 if part == "arm_left" else -1.0
            turn = Rotation.from_euler("y", sign * degrees, degrees=True)
            pivot = np.array([sign * 0.26, 0.0, 1.39])
            rotation = turn * Rotation.from_euler("xyz", panel.placement.rotation_deg, degrees=True)
            translation = turn.apply(np.asarray(panel.placement.translation) - pivot) + pivot
            panel = dataclasses.replace(panel, placement=Placement(
                part, tuple(rotation.as_euler("xyz", degrees=True).tolist()), tuple(translation.tolist())))
        panels.append(panel)
    return dataclasses.replace(pattern, panels=tuple(panels))


@pytest.mark.slow
def test_a_dressing_that_stops_closing_gives_up_names_its_widest_seams_and_saves_where_it_stuck(tmp_path):
    """shirt_mean with its sleeves 50 degrees down (dressing turns them 45 more): the gap stops
    shrinking long before the step limit; the error names the widest seams, widest first, with gaps."""
    body = load_body("default")
    template = Template.build(_sleeves_down(load_garmentcode(DATA / "shirt_mean_specification.json"), 50.483))
    params = DressingParams(level_mm=30)
    with pytest.raises(DressingError) as caught:
        dress(template, body, params=params, progress=False)
    message = str(caught.value)
    assert "its widest gap stopped shrinking" in message
    steps = int(message.split("sewing stopped after ")[1].split()[0])
    assert steps < params.max_sew_steps
    worst = message.split("widest open seams: ")[1]
    gaps = [float(part.split(" mm")[0].rsplit(" ", 1)[1]) for part in worst.split(" (and")[0].split(", ")]
    assert len(gaps) == params.worst_seams and gaps == sorted(gaps, reverse=True) and gaps[-1] >= 1.0
    assert "sleeve" in worst.split(",")[0] and "more open)" in worst
    npz, png = save_stuck(caught.value, body, tmp_path)
    stuck = DressedGarment.load(npz)
    assert stuck.positions.shape == (template.level(30).num_vertices, 3)
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
