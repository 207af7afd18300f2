"""The default garments on the default body's shapes: where they are known to fit
(`assets.garments.defaults.DEFAULT_BODY_FIT`, measured by `benchmarks/body_range.py`), and what a
dressing outside it says."""

import re

import numpy as np
import pytest

from assets.body import default_body
from assets.garments.defaults import DEFAULT_BODY_FIT, BodyMeasurements, default_body_misfit, default_pattern


def test_a_default_garment_outside_its_fit_is_named_with_the_range_and_the_remedy():
    body = default_body()
    lo, hi = DEFAULT_BODY_FIT["pants"]["height"]
    misfit = default_body_misfit(default_pattern("pants"), body.name, body.shape_names, np.array([0.0, 1.0, 0.9]))
    assert re.fullmatch(rf"the default pants is drafted for the default body's default shape and known to dress on "
                        rf"gender 0\.5 \.\. 1, weight 0 \.\. 0\.75, height {lo:g} \.\. {hi:g} "
                        r"\(benchmarks/body_range\.py\), not on gender=0, weight=1, height=0\.9; draft it for this "
                        r"body's measurements \(python -m assets\.garments\.defaults --measurements FILE\) or "
                        r"choose a shape inside that range", misfit)


@pytest.mark.parametrize("garment", ["shirt", "skirt", "pants", "suit"])
def test_the_fit_holds_only_for_the_default_drafts_on_the_default_body(garment):
    body = default_body()
    pattern = default_pattern(garment)
    fit = DEFAULT_BODY_FIT[garment]
    below = np.array([0.5, 0.5, fit["height"][0] - 0.05])
    assert "not on height=" in default_body_misfit(pattern, body.name, body.shape_names, below)
    low, high = np.array(list(fit.values())).T
    for inside in ([0.5, 0.5, 0.65], low, high):  # the default shape, the box's corners
        assert default_body_misfit(pattern, body.name, body.shape_names, np.array(inside)) is None
    issue = default_body_misfit(pattern, body.name, body.shape_names, np.array([0.3, 0.65, 0.7]))
    assert (issue is None) == (garment != "pants")  # the issue's shape: the shirt dressed on it
    # drafted for other measurements, or on another body, the garment is the user's to judge
    redrafted = default_pattern(garment, BodyMeasurements(chest_girth=1.04, hip_girth=1.06, waist_girth=0.8))
    assert default_body_misfit(redrafted, body.name, body.shape_names, below) is None
    assert default_body_misfit(pattern, "SMPL_NEUTRAL", body.shape_names, below) is None
