"""The multi-resolution hierarchy of the post-processing: template levels, coarse to fine, and the
barycentric maps that carry a solved shape from one level to the next.

Levels are the template's (`assets.garments.template`: 12, 4, 2, 1 mm by default); a shape is always
given on a level's sewn mesh (V sewn vertices, `Level.sewn_faces`), world metres.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from assets.garments.template import Level, Prolongation, Template


class Hierarchy:
    """The levels `levels_mm` of `template`, coarsest first, with cached level-to-level maps."""

    def __init__(self, template: Template, levels_mm: Sequence[int]):
        levels = [int(mm) for mm in levels_mm]
        if not levels or len(set(levels)) != len(levels) or min(levels) <= 0:
            raise ValueError(f"levels_mm: expected distinct positive level spacings (mm), got {tuple(levels_mm)}")
        self.template = template
        self.levels_mm = tuple(sorted(levels, reverse=True))
        self._maps: dict[tuple[int, int], Prolongation] = {}

    @property
    def coarsest_mm(self) -> int:
        return self.levels_mm[0]

    @property
    def finest_mm(self) -> int:
        return self.levels_mm[-1]

    def level(self, mm: int) -> Level:
        return self.template.level(mm)

    def transfer(self, positions: np.ndarray, from_mm: int, to_mm: int) -> np.ndarray:
        """A shape on level `from_mm`'s sewn mesh (..., Vs, 3) -> on level `to_mm`'s (..., Vt, 3): every
        vertex of the target level interpolated barycentrically in the source level's face that holds it
        in the sewing pattern; the copies of a seam vertex (one per panel) are averaged.  Coarse to fine
        is the hierarchy's upsampling; any other pair (an initial shape given at another level, a fine
        shape sampled at a coarse level's vertices) works too."""
        source, target = self.level(from_mm), self.level(to_mm)
        positions = np.asarray(positions, dtype=np.float64)
        if positions.ndim < 2 or positions.shape[-2:] != (source.num_sewn_vertices, 3):
            raise ValueError(f"positions: expected (..., {source.num_sewn_vertices}, 3) (the sewn {from_mm} mm "
                             f"level), got {positions.shape}")
        if from_mm == to_mm:
            return positions.copy()
        key = (from_mm, to_mm)
        if key not in self._maps:
            self._maps[key] = self.template.prolongation(from_mm, to_mm)
        unsewn = self._maps[key](source.faces, positions[..., source.sewn_index, :])
        return target.sew(unsewn)
