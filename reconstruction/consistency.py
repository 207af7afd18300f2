"""Pattern-neighbour consistency: triangulated crosspoints must agree with their neighbours on the garment.

A marker read with a wrong ID in one view lends its crosspoints to another marker's; where that
marker is seen (rightly) in one other view only, the two rays meet near the epipolar line and the
point reprojects well at a wrong depth, centimetres to metres off (RANSAC over views cannot tell with
two views).  Cloth barely stretches, so the 3D points of two crosspoints of one panel are at most
about their rest distance (on the flat sewing pattern) apart; a wrong marker's points are far from
the rightly placed points of its neighbours on the pattern.

The check (`consistent_points`), per frame, vectorised:

1. Pairs: every two triangulated crosspoints `stride` grid steps apart along a row or a column of a
   panel's crosspoint grid, for each of `NeighbourConfig.strides`, whose 3D distance is at most
   `max_stretch` x their rest distance (`CrosspointMap.pattern_xy`), are joined.
2. Connected components of that graph (`scipy.sparse.csgraph`).
3. A component is kept when it has at least `min_points` points and no single marker holds all its
   crosspoints.  All crosspoints of a wrong marker land together and agree with each other, but they
   are crosspoints of one marker (the one whose ID was read): they cannot vouch for themselves.  A
   right region spans marker borders and joins its neighbours; the right points beside a wrong
   marker stay, joined to the rest.

So a correct region that lies within one marker, or has fewer than `min_points` points, is dropped
too: nothing on the pattern confirms it (a small patch seen through a gap; on the demo capture, 0.5%
of the points at no ID errors).  The defaults are chosen on that capture (4 cameras at 640 x 360,
0.3 px noise, 12 mm level, pitch 2 mm, with 0-26% of the IDs replaced: `GroundTruthConfig.id_error`),
see `NeighbourConfig`.

P triangulated points, G garment-wide crosspoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from reconstruction.correspondence import CrosspointMap


@dataclass(frozen=True)
class NeighbourConfig:
    """Settings of the pattern-neighbour check (module docstring).

    max_stretch: two crosspoints are consistent when their 3D distance is at most this times their
        rest distance.  1.5: on the demo capture the right pairs 4 steps (8 mm) apart are within 1.35x
        for 99.9% (at most 1.94x); 1-step (2 mm) pairs are noise-dominated (99.9% within 2.49x: about
        1 mm of triangulation error each) and only help where they pass.  1.3 keeps as many points
        at 0.3 px of detection noise but drops 1.7% (1.5: 0.9%) at 1 px and 27% (1.5: 10%) at 2 px.
    strides: the grid steps between the crosspoints of a pair.  (1, 2, 4): the longer pairs keep the
        right regions connected despite the noise of the 1-step ones (1 alone drops 4% of the points
        at no ID errors, (1, 2, 4) 0.5%); with 8 as well (16 mm, tolerance 24 mm) points 14-17 mm off
        join their neighbours.
    min_points: fewest points of a kept component.  100: a component of 58 points spanning two
        markers, 15 of them 5-14 mm off (a sleeve, also without ID errors), stays at 50; a marker's
        worth (625) would drop 5% more of the points at 26% wrong IDs."""

    max_stretch: float = 1.5
    strides: tuple[int, ...] = (1, 2, 4)
    min_points: int = 100

    def __post_init__(self) -> None:
        object.__setattr__(self, "strides", tuple(int(s) for s in self.strides))
        if not self.max_stretch >= 1:
            raise ValueError(f"NeighbourConfig.max_stretch must be >= 1, got {self.max_stretch}")
        if not self.strides or min(self.strides) < 1:
            raise ValueError(f"NeighbourConfig.strides must be positive grid steps, got {self.strides}")
        if self.min_points < 1:
            raise ValueError(f"NeighbourConfig.min_points must be >= 1, got {self.min_points}")


@dataclass(frozen=True, eq=False)
class NeighbourCheck:
    """The check of P points.

      component (P,) int64   connected component of the consistent-pair graph
      kept (P,) bool         in a component of at least min_points spanning more than one marker
    """

    component: np.ndarray
    kept: np.ndarray


def consistent_points(crosspoints: CrosspointMap, flat: np.ndarray, xyz: np.ndarray,
                      config: NeighbourConfig = NeighbourConfig()) -> NeighbourCheck:
    """Check the points `xyz` (P, 3) world metres of the crosspoints `flat` (P,) (garment-wide
    numbers, `CrosspointMap.flat`, distinct) against their pattern neighbours (module docstring)."""
    flat = np.asarray(flat, dtype=np.int64)
    xyz = np.asarray(xyz, dtype=np.float64)
    if flat.ndim != 1 or xyz.shape != (len(flat), 3):
        raise ValueError(f"consistent_points: flat must be (P,) and xyz (P, 3), got {flat.shape} and {xyz.shape}")
    n = len(flat)
    row = np.full(crosspoints.num_crosspoints, -1, dtype=np.int64)
    row[flat] = np.arange(n)
    if (row[flat] != np.arange(n)).any():
        raise ValueError("consistent_points: a crosspoint appears twice in flat")
    pairs = np.concatenate([crosspoints.grid_pairs(s) for s in config.strides])
    a, b = row[pairs[:, 0]], row[pairs[:, 1]]
    both = (a >= 0) & (b >= 0)
    pairs, a, b = pairs[both], a[both], b[both]
    rest = np.linalg.norm(crosspoints.pattern_xy[pairs[:, 0]] - crosspoints.pattern_xy[pairs[:, 1]], axis=1)
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(xyz[a] - xyz[b], axis=1) <= config.max_stretch * rest
    graph = coo_matrix((np.ones(int(near.sum()), dtype=np.int8), (a[near], b[near])), shape=(n, n))
    count, component = connected_components(graph, directed=False)
    size = np.bincount(component, minlength=count)
    # the most points of a component that one marker holds (border crosspoints belong to 2 or 4)
    markers = crosspoints.marker_flat.reshape(len(crosspoints.marker_id), -1)
    member = row[markers]
    held = member >= 0
    code = component[member[held]] * len(markers) + np.nonzero(held)[0]
    pair, together = np.unique(code, return_counts=True)
    most = np.zeros(count, dtype=np.int64)
    np.maximum.at(most, pair // len(markers), together)
    good = (size >= config.min_points) & (most < size)
    return NeighbourCheck(component=component.astype(np.int64), kept=good[component])
