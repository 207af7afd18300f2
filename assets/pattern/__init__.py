"""The two-level pattern printed on garments: markers with IDs, crosspoints inside them.

Public API::

    spec = PatternSpec(rows=8, cols=8)              # numbers, defaults from the reference
    table = MarkerTable.build(spec)                 # where every marker and crosspoint is
    image = render_region(table, dpi=300)           # the printable fabric, exact scale
    refs = reference_textures(spec, table.codes, CROSSPOINT_CROP)   # canonical crops
    crops = unwarp(image, spec, RECOGNIZER_CROP, localization_px)   # image -> crops

Design of the appearance (why it looks the way it does)
-------------------------------------------------------
* Crosspoints are intersections of thin dark lines through every crosspoint row and column (0.3 mm
  wide at 2 mm pitch).  A line intersection is a sharp X-junction whose centre is the intersection of
  two line centres, each recoverable to sub-pixel precision from the symmetric line profile even when
  blurred; lines are drawn over both fill colours, so every crosspoint looks the same everywhere.
* Identity is a 12 x 12 grid of 4 mm code modules (2 x 2 cells) filled with a mid-tone code colour or
  left white: binary luminance contrast (robust to colour shifts), coarse enough to survive blur and
  folds (8 px per module in a 96 px recognizer crop), with 107 free bits giving a codebook whose
  members are at least 32 modules apart under every rotation (`codebook`).
* Coarse features for the five localization points: marker borders are thicker lines (0.8 mm), so
  each marker is a visible square whose corners are TL, TR, BL, BR; the marker's central 16 mm is a
  2 x 2 checker of code colour and white whose saddle is the centre point, visible at 1/8 resolution
  and unchanged by blur; and an 8 mm code-coloured finder, ringed by 4 mm of white, fills the inside
  of the TL corner while the three other corners are always white, so orientation is unambiguous
  from coarse appearance alone (and the checker's phase flips under a 90-degree rotation, a second
  cue).  Around every marker corner of the fabric there is thus exactly one finder square.
"""

from assets.pattern.codebook import codebook_min_distance, generate_codebook, hamming_to_rotations
from assets.pattern.crops import (
    CROSSPOINT_CROP,
    MAX_CROP_JITTER_PX,
    RECOGNIZER_CROP,
    CropGeometry,
    CropSpec,
    crop_crosspoints_px,
    crop_homography,
    crop_localization_px,
    reference_textures,
    unwarp,
)
from assets.pattern.raster import render_region, write_png, xy_to_pixel
from assets.pattern.spec import PatternSpec, fixed_modules
from assets.pattern.table import LOCALIZATION_POINTS, MarkerTable, localization_rc

__all__ = [
    "CROSSPOINT_CROP",
    "LOCALIZATION_POINTS",
    "MAX_CROP_JITTER_PX",
    "RECOGNIZER_CROP",
    "CropGeometry",
    "CropSpec",
    "MarkerTable",
    "PatternSpec",
    "codebook_min_distance",
    "crop_crosspoints_px",
    "crop_homography",
    "crop_localization_px",
    "fixed_modules",
    "generate_codebook",
    "hamming_to_rotations",
    "localization_rc",
    "reference_textures",
    "render_region",
    "unwarp",
    "write_png",
    "xy_to_pixel",
]
