"""Garment templates: sewing patterns -> hybrid multi-resolution meshes that know where every vertex
sits on the printed fabric.

    pattern = default_pattern("shirt")              # or SewingPattern.load(path), load_garmentcode(path)
    template = Template.build(pattern)              # marker tilings + printable sheet layout
    template = load_template("shirt")               # by name, pattern JSON or saved template .npz
    level = template.level(4)                       # 4 mm mesh: pattern_xy, faces, uv, flags, seams
    fine = template.upsample(coarse_positions, 12, 4)
"""

from assets.garments.loading import load_pattern, load_template
from assets.garments.sewing import PatternError, SewingPattern
from assets.garments.template import LEVELS_MM, Level, Prolongation, Template

__all__ = ["LEVELS_MM", "Level", "PatternError", "Prolongation", "SewingPattern", "Template", "load_pattern",
           "load_template"]
